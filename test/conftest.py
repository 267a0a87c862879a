"""Keep DDS on this machine for every test, whatever the caller's environment.

Set before any test module imports rclpy; subprocesses inherit it. Modules that need a
domain of their own set ROS_DOMAIN_ID themselves (or pass domain_id to rclpy.init).
"""
import os

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', '42')

import ros_helpers  # noqa: E402,F401  (fixes the run's base domain before any test module loads)


def pytest_configure(config):
    """Register the markers of the ament linter tests (test_flake8.py, test_pep257.py)."""
    for marker in ('flake8', 'pep257', 'linter'):
        config.addinivalue_line('markers', f'{marker}: ament {marker} check')
