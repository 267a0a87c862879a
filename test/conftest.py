"""
Keep DDS on this machine for every test, whatever the caller's environment.

Set before any test module imports rclpy; subprocesses inherit it. Modules that need a
domain of their own set ROS_DOMAIN_ID themselves (or pass domain_id to rclpy.init).
"""
import os
import signal


os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# A shell without job control (a script's `cmd &`) starts the suite with SIGINT ignored, and an
# ignored signal stays ignored across exec: the programs test_shutdown sends Ctrl-C to would
# never see it (three failures and their sims and controllers left running, seen here). A
# handler here is reset to the default in every child the suite starts.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
os.environ.setdefault('ROS_DOMAIN_ID', '42')

import ros_helpers  # noqa: E402,F401  (fixes the run's base domain before any test module loads)
