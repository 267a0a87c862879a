"""``/diagnostics`` status of the controller (diagnostic_msgs, the ROS convention)."""
from __future__ import annotations

from typing import Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from ..core.runtime import ControllerRuntime, Mode

__all__ = ['INPUT_FAULTS', 'controller_status']

_LEVEL = {Mode.RUNNING: DiagnosticStatus.OK, Mode.WAITING: DiagnosticStatus.WARN,
          Mode.APPROACH: DiagnosticStatus.WARN, Mode.NO_SURFACE: DiagnosticStatus.ERROR,
          Mode.SAFE: DiagnosticStatus.ERROR}
# counters whose increase since the last status makes it at least WARN
INPUT_FAULTS = ('joint_state_dropped', 'wrench_dropped', 'wrench_implausible')


def controller_status(stamp, node_name: str, runtime: ControllerRuntime | None,
                      new_faults: int, timing: Mapping[str, float],
                      callback_errors: Mapping[str, int]) -> DiagnosticArray:
    """One DiagnosticStatus: mode, contact, counters, the last input fault, loop timing.

    The level follows the mode (OK running; WARN waiting or approaching; ERROR safe or
    surface not found) and is at least WARN when ``new_faults`` inputs were dropped since
    the last status.
    """
    status = DiagnosticStatus(name=f'{node_name}: hybrid force/motion control',
                              hardware_id=node_name)
    if runtime is None or runtime.counters['ticks'] == 0:
        status.level, status.message = DiagnosticStatus.WARN, 'no tick yet'
        values: dict[str, object] = {}
    else:
        level = _LEVEL[runtime.mode]
        message = runtime.status
        if new_faults and level == DiagnosticStatus.OK:
            level, message = DiagnosticStatus.WARN, f'{message}; inputs dropped: {runtime.last_fault}'
        status.level, status.message = level, message
        values = {'mode': runtime.mode.value, 'in_contact': runtime.in_contact,
                  **runtime.counters, 'last_input_fault': runtime.last_fault,
                  'last_safe_reason': runtime.last_safe_reason,
                  'theta_hat': ', '.join(f'{v:.4g}' for v in runtime.theta_hat)}
    values.update({f'loop_{k}': (f'{v:.4g}' if k != 'samples' else int(v))
                   for k, v in timing.items()})
    values.update({f'callback_errors_{k}': v for k, v in callback_errors.items()})
    status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    return DiagnosticArray(header=Header(stamp=stamp), status=[status])
