"""
Keep DDS on this machine for every test, whatever the caller's environment.

Set before any test module imports rclpy; subprocesses inherit it. Modules that need a
domain of their own set ROS_DOMAIN_ID themselves (or pass domain_id to rclpy.init).
"""
import os


os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', '42')

import ros_helpers  # noqa: E402,F401  (fixes the run's base domain before any test module loads)
