"""
The QoS of every topic of the package, in one place (documented in README "Topics and QoS").

* 1 kHz sensor inputs (``joint_states``, the F/T ``wrench``): KEEP_LAST 1, so a late
  subscriber takes the newest sample, not a backlog; BEST_EFFORT by default, which matches
  both reliable publishers (joint_state_broadcaster) and best-effort ones (many F/T
  drivers, ``qos_profile_sensor_data``); ``sensor_qos:=reliable`` asks for reliable.
* Effort command: RELIABLE, KEEP_LAST 1 (matches ros2_control's JointGroupEffortController,
  which subscribes reliable; a slow reader gets the newest command, never a queue).
* Telemetry: RELIABLE, KEEP_LAST 100: the controller node publishes what the control thread
  queued every 10 ms, so at ``telemetry_rate_hz`` 1000 a burst of 10 per topic goes out at once
  (a history of 10 would drop samples a reliable reader has not acknowledged yet).
* ``~/reference``, ``~/path``, ``~/markers`` and ``/diagnostics``: RELIABLE, KEEP_LAST 10 (the
  ROS default).
* ``robot_description``: RELIABLE, TRANSIENT_LOCAL, KEEP_LAST 1 (robot_state_publisher's);
  ``~/path_status`` and ``~/path_progress`` the same (:data:`LATCHED_QOS`), so a script that
  subscribes late still gets the last state.
* ``/clock`` (lockstep sim): RELIABLE, KEEP_LAST 1.
"""
from __future__ import annotations

from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

__all__ = ['CLOCK_QOS', 'COMMAND_QOS', 'DEFAULT_QOS', 'DESCRIPTION_QOS', 'LATCHED_QOS',
           'STATE_OUT_QOS', 'TELEMETRY_QOS', 'sensor_in_qos']

DEFAULT_QOS = QoSProfile(depth=10)
TELEMETRY_QOS = QoSProfile(depth=100)
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE)
STATE_OUT_QOS = COMMAND_QOS  # the sim's joint_states / wrench publishers: reliable, newest
CLOCK_QOS = COMMAND_QOS
DESCRIPTION_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
LATCHED_QOS = DESCRIPTION_QOS  # the last message, for late subscribers too


def sensor_in_qos(reliability: str = 'best_effort', depth: int = 1) -> QoSProfile:
    """Input of a 1 kHz sensor topic: KEEP_LAST ``depth``, ``best_effort`` or ``reliable``."""
    policy = (ReliabilityPolicy.BEST_EFFORT if reliability == 'best_effort'
              else ReliabilityPolicy.RELIABLE)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=policy)
