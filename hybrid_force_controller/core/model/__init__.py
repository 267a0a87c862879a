"""
The robot model: URDF -> pinocchio kinematics and dynamics, parameter sets, the tool's weight.

Imports numpy and pinocchio only.
"""
