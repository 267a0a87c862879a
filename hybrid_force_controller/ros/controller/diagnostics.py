"""``/diagnostics`` status of the controller (diagnostic_msgs, the ROS convention)."""
from __future__ import annotations

import math
import time
from typing import Any, Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from ...core.runtime.controller_runtime import ControllerRuntime, Mode

__all__ = ['CLOCK_OFFSET_WARN_S', 'EVENT_COUNTERS', 'clock_offset_warnings',
           'controller_status', 'loop_report']

_LEVEL = {Mode.RUNNING: DiagnosticStatus.OK, Mode.WAITING: DiagnosticStatus.WARN,
          Mode.APPROACH: DiagnosticStatus.WARN, Mode.NO_SURFACE: DiagnosticStatus.ERROR,
          Mode.SAFE: DiagnosticStatus.ERROR}
# counters whose increase since the last status makes it at least WARN (a fault shorter
# than the 1 s between two statuses is still reported); the first ones count refused inputs
DROP_COUNTERS = ('joint_state_dropped', 'joint_state_implausible',
                 'joint_state_clock_implausible', 'wrench_dropped', 'wrench_implausible',
                 'wrench_clock_implausible')
EVENT_COUNTERS = DROP_COUNTERS + ('safe_mode_entries', 'approach_entries', 'stalls')
CLOCK_OFFSET_WARN_S = 0.05  # a sender's clock this far off: logged once (it is not synced)
EPISODE_WARN_S = 5.0  # an episode this long (adaptation frozen) is reported


def _warnings(runtime: ControllerRuntime, new_events: Mapping[str, int],
              extra: Mapping[str, object]) -> list[str]:
    """
    List the reasons to raise an OK status to WARN.

    They are events since the last status (dropped inputs, safe mode, contact lost), a
    measured delay near the delay margin and a stiffness estimate near k_max.
    """
    out = []
    dropped = sum(new_events.get(k, 0) for k in DROP_COUNTERS)
    if dropped:
        out.append(f'{dropped} inputs dropped: {runtime.last_fault}')
    if new_events.get('safe_mode_entries', 0):
        out.append(f'was in safe mode: {runtime.last_safe_reason}')
    if new_events.get('approach_entries', 0):
        out.append('contact was lost')
    if new_events.get('stalls', 0):
        out.append(f"the loop stalled {new_events['stalls']} times (last "
                   f'{runtime.last_stall_s * 1e3:.0f} ms without a tick)')
    rec = runtime.recovery
    age = runtime.state_stamp - rec.t_begin
    if rec.episode and age > EPISODE_WARN_S:
        held = ('its value before the episode until the arm settles' if rec.provisional else
                'the trusted estimate until calm returns')
        out.append(f'fault episode ({rec.episode}) for {age:.0f} s: theta_hat held at {held}')
    margin_ms = float(extra.get('delay_margin_ms', math.inf))
    delay_ms = float(extra.get('delay_p99_ms', math.nan))
    if math.isfinite(delay_ms) and delay_ms + 1.0 > 0.5 * margin_ms:  # +1 ms: plant side
        out.append(f"loop delay p99 {delay_ms:.1f} ms leaves less than half of the gains' "
                   f'delay margin {margin_ms:.1f} ms')
    k = runtime.stiffness_status()
    if k.enabled and k.near_k_max:
        out.append(f'stiffness estimate {k.k_hat:.0f} N/m near k_max: eq. (29) holds with '
                   'little margin')
    normal = runtime.normal_status()
    if normal.limited:
        out.append(f'the surface normal seems more than {normal.angle_from_n_deg:.0f} deg from '
                   'n: the controller holds it there (is n right?)')
    out.extend(str(w) for w in extra.get('warnings', ()))
    return out


def controller_status(stamp, node_name: str, runtime: ControllerRuntime | None,
                      new_events: Mapping[str, int], timing: Mapping[str, float],
                      callback_errors: Mapping[str, int],
                      extra: Mapping[str, object] | None = None,
                      qualified_name: str = '') -> DiagnosticArray:
    """
    Build one DiagnosticStatus: mode, contact, counters, the last input fault, loop timing.

    The level follows the mode (OK running; WARN waiting or approaching; ERROR safe or
    surface not found) and is at least WARN when ``new_events`` (increments of
    :data:`EVENT_COUNTERS` since the last status) are not all zero or the measured delay
    (``extra['delay_p99_ms']``) comes near the
    delay margin (``extra['delay_margin_ms']``). ``extra`` also holds the lifecycle state
    and the command rate; floats are given with 4 significant digits.
    """
    extra = extra or {}
    status = DiagnosticStatus(name=f'{qualified_name or node_name}: hybrid force/motion control',
                              hardware_id=node_name)
    if runtime is None or runtime.counters['ticks'] == 0:
        state = extra.get('lifecycle_state', '')
        status.level, status.message = DiagnosticStatus.WARN, f'no tick yet {state}'.strip()
        values: dict[str, object] = {'mode': 'waiting' if state in ('', 'active') else state}
    else:
        level, message = _LEVEL[runtime.mode], runtime.status
        warnings = _warnings(runtime, new_events, extra)
        if warnings and level == DiagnosticStatus.OK:
            level, message = DiagnosticStatus.WARN, '; '.join([message, *warnings])
        status.level, status.message = level, message
        values = {'mode': runtime.mode.value, 'in_contact': runtime.in_contact,
                  **runtime.counters, 'last_input_fault': runtime.last_fault,
                  'last_safe_reason': runtime.last_safe_reason,
                  'theta_hat': ', '.join(f'{v:.4g}' for v in runtime.theta_hat),
                  **{f'{k}_clock_offset_s': f'{v:.6g}'
                     for k, v in runtime.clock_offsets().items()},
                  **{f'{k}_clock_{c}': v for c in ('relearns', 'startup_refusals')
                     for k, v in runtime.clock_counts(c).items()},
                  **_recovery_values(runtime),
                  **{f'stiffness_{k}': (f'{v:.4g}' if isinstance(v, float) else v)
                     for k, v in runtime.stiffness_status()._asdict().items()},
                  **_normal_values(runtime)}
    values.update({f'loop_{k}': (f'{v:.4g}' if k != 'samples' else int(v))
                   for k, v in timing.items()})
    values.update({f'callback_errors_{k}': v for k, v in callback_errors.items()})
    values.update({k: (f'{v:.4g}' if isinstance(v, float) else v)
                   for k, v in extra.items() if k != 'warnings'})
    status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    return DiagnosticArray(header=Header(stamp=stamp), status=[status])


def clock_offset_warnings(offsets: Mapping[str, float], warned: set) -> list[str]:
    """
    Return a warning for each stream whose clock offset first exceeds CLOCK_OFFSET_WARN_S.

    ``offsets`` are :meth:`ControllerRuntime.clock_offsets`; ``warned`` the streams already
    reported (updated), so each is logged once.
    """
    out = []
    for stream, offset in offsets.items():
        if abs(offset) > CLOCK_OFFSET_WARN_S and stream not in warned:
            warned.add(stream)
            out.append(f"{stream.replace('_', ' ')} stamps are {abs(offset):.3f} s "
                       f"{'ahead of' if offset > 0 else 'behind'} the controller's clock: "
                       'the sender is not synced; the controller measures the offset and '
                       'removes it (max_clock_skew; /diagnostics '
                       f'{stream}_clock_offset_s)')
    return out


def _normal_values(runtime: ControllerRuntime) -> dict[str, object]:
    """
    Return the surface normal (core/runtime/surface.py): the one in use and the estimate's state.

    ``normal_n_hat`` is the normal the controller uses (base frame; the ``n`` parameter when
    ``normal_estimation`` is false), ``normal_angle_from_n_deg`` its angle from ``n``,
    ``normal_mu_hat`` the friction coefficient the estimate removes, ``normal_state`` what its
    last sample did (sliding, at_rest, no_contact, low_force, implausible, rejected; off).
    """
    s = runtime.normal_status()
    return {'normal_estimation': s.enabled, 'normal_n_hat': ', '.join(f'{v:.4g}' for v in s.n_hat),
            'normal_angle_from_n_deg': f'{s.angle_from_n_deg:.4g}',
            'normal_mu_hat': f'{s.mu_hat:.4g}', 'normal_state': s.state,
            'normal_samples_used': s.samples_used,
            'normal_samples_rejected': s.samples_rejected, 'normal_limited': s.limited}


def _recovery_values(runtime: ControllerRuntime) -> dict[str, object]:
    """Return the fault episodes (core/runtime/recovery.py): the one under way, counts, trusted."""
    rec = runtime.recovery
    trusted = ', '.join(f'{v:.4g}' for v in rec.trusted) if rec.has_trusted else 'none'
    return {'episode': rec.episode or 'none', 'theta_trusted': trusted,
            'adaptation_frozen': rec.frozen, 'episode_provisional': rec.provisional,
            'last_stall_ms': f'{runtime.last_stall_s * 1e3:.4g}',
            **{f'episodes_{k}': v for k, v in rec.counts.items()}}


def loop_report(loop: Any, extra: dict[str, Any]) -> dict[str, float]:
    """
    Add the control thread's figures to ``extra``; return its timing summary.

    ``loop`` is the :class:`~.control_loop.ControlLoop`: commands/s, the input-to-command
    delay, and how long each callback held the thread (the longest, and where it went).
    """
    extra['commands_per_s'] = loop.commands.rate(time.monotonic())
    extra.update(loop.delay.summary('delay'))
    holds = loop.holds.summary()
    extra['loop_hold_max_ms'] = holds.pop('all_max_ms')
    extra['loop_hold_p999_ms'] = holds.pop('all_p999_ms')
    extra['loop_hold_max_where'] = loop.holds.where()
    extra.update({f'hold_{k}': v for k, v in holds.items() if not k.startswith('all')})
    return loop.timing.summary()
