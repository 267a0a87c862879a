"""``/diagnostics`` status of the controller (diagnostic_msgs, the ROS convention)."""
from __future__ import annotations

from typing import Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from ..core.runtime import TickOutput

__all__ = ['controller_status']

_LEVEL = {'running': DiagnosticStatus.OK, 'waiting': DiagnosticStatus.WARN,
          'safe': DiagnosticStatus.ERROR}


def controller_status(stamp, node_name: str, out: TickOutput | None,
                      timing: Mapping[str, float], callback_errors: Mapping[str, int],
                      extra: Mapping[str, object] | None = None,
                      qualified_name: str = '') -> DiagnosticArray:
    """
    Build one DiagnosticStatus: mode, contact, counts, loop timing and ``extra``.

    ``extra`` holds the lifecycle state, the delay and the command rate; floats are given
    with 4 significant digits.
    """
    status = DiagnosticStatus(name=f'{qualified_name or node_name}: hybrid force/motion control',
                              hardware_id=node_name)
    if out is None:
        state = (extra or {}).get('lifecycle_state', '')
        status.level, status.message = DiagnosticStatus.WARN, f'no tick yet {state}'.strip()
        values: dict[str, object] = {'mode': 'waiting' if state in ('', 'active') else state}
    else:
        status.level, status.message = _LEVEL.get(out.mode, DiagnosticStatus.ERROR), out.status
        values = {'mode': out.mode, 'in_contact': out.in_contact, **out.counters,
                  'theta_hat': ', '.join(f'{v:.4g}' for v in out.theta_hat)}
    values.update({f'loop_{k}': (f'{v:.4g}' if k != 'samples' else int(v))
                   for k, v in timing.items()})
    values.update({f'callback_errors_{k}': v for k, v in callback_errors.items()})
    values.update({k: (f'{v:.4g}' if isinstance(v, float) else v)
                   for k, v in (extra or {}).items()})
    status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    return DiagnosticArray(header=Header(stamp=stamp), status=[status])
