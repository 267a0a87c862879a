"""
Offline only: never on a robot's control path.

The simulated plant and surface, the loop engine with its timing model, the paper's scenarios.
"""
