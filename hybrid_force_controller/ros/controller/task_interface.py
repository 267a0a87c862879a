"""
The user's task inputs of the controller node, on the node's thread (never the control thread).

* ``~/reference`` (geometry_msgs/PointStamped, base frame): hold a point instead of the sine.
* ``~/target_wrench`` (geometry_msgs/WrenchStamped, base frame), as FZI's force controller
  takes it: its force along n (the normal in use: n_hat with ``n_estimation``) is the force
  the tool should exert on the surface, so it sets the ``f_d`` parameter (validated, and
  ramped at ``f_d_rate``, like ``ros2 param set f_d``); its torque (N m, base frame) is the
  target of the tilt moments about the tool's centre with ``orientation_mode`` moment (its
  part along n unused; 0 until a target arrives: the pad seats itself flat).
* ``~/tare`` (std_srvs/Trigger): average the raw force reading over ``tare_time`` with the tool
  still and off the surface, then store the sensor's bias in ``wrench_offset`` (a parameter:
  ``ros2 param dump`` saves it, a restart from the dump keeps it). The call answers when the
  tare is done, or refused, with the reason. Tare before activating (the arm held still by the
  hardware) or while holding off the surface.

Each refusal says why: a warning in the log, a Trigger's message, a parameter's reason.
"""
from __future__ import annotations

import math
import time
from typing import Any

from geometry_msgs.msg import PointStamped, WrenchStamped
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from ..common.qos import DEFAULT_QOS
from ...core.runtime.controller_runtime import InputError
from ...core.runtime.tare import Tare

__all__ = ['TaskInterface']

TARE_WAIT_S = 0.5  # beyond tare_time: the wrench must arrive within this (else refused)
POLL_S = 0.005  # the tare's wait hands the GIL over and keeps the telemetry going


class TaskInterface:
    """The task's topics and service of one configured controller node."""

    def __init__(self, node: Any) -> None:
        self.node = node
        self.last_tare = 'none'
        self._subs = [
            node.create_subscription(PointStamped, '~/reference',
                                     node._guarded('reference', self._on_reference),
                                     DEFAULT_QOS),
            node.create_subscription(WrenchStamped, '~/target_wrench',
                                     node._guarded('target_wrench', self._on_target_wrench),
                                     DEFAULT_QOS)]
        self._tare_srv = node.create_service(Trigger, '~/tare', self._on_tare)

    def destroy(self) -> None:
        """Remove the topics and the service (lifecycle cleanup)."""
        for sub in self._subs:
            self.node.destroy_subscription(sub)
        self.node.destroy_service(self._tare_srv)
        self._subs = []

    def report(self) -> dict[str, str]:
        """Return the offset in use and the last tare's outcome, for /diagnostics."""
        offset = self.node.runtime.params.runtime.wrench_offset
        return {'wrench_offset_n': ', '.join(f'{v:.4g}' for v in offset),
                'last_tare': self.last_tare}

    # ------------------------------------------------------------------ topics
    def _base_frame(self, frame_id: str, what: str) -> None:
        base = self.node.model.base_link
        if frame_id not in ('', base):
            raise InputError(f"{what} frame '{frame_id}' is not '{base}' (no TF here)")

    def _on_reference(self, msg: PointStamped) -> None:
        self._base_frame(msg.header.frame_id, 'reference')
        point = (msg.point.x, msg.point.y, msg.point.z)
        if not all(math.isfinite(x) for x in point):
            raise InputError(f'reference must be 3 finite numbers, got {list(point)}')
        self.node.loop.hold_reference(point)

    def _on_target_wrench(self, msg: WrenchStamped) -> None:
        self._base_frame(msg.header.frame_id, 'target_wrench')
        f, m = msg.wrench.force, msg.wrench.torque
        force, torque = (f.x, f.y, f.z), (m.x, m.y, m.z)
        if not all(math.isfinite(x) for x in force + torque):
            raise InputError(f'target_wrench must be finite, got force {list(force)}, torque '
                             f'{list(torque)}')
        if self.node.loop is not None:  # the tilt moments' target (orientation_mode moment)
            self.node.loop.set_moment_target(torque)
        latest = self.node.loop.latest if self.node.loop is not None else None
        n = latest[0].n_W if latest is not None and latest[0].n_W is not None else None
        n = self.node.params.law.n if n is None else n  # the normal in use: n, or n_hat
        f_d = float(sum(a * b for a, b in zip(n, force)))
        if f_d == self.node.get_parameter('f_d').value:
            return
        result = self.node.set_parameters([Parameter('f_d', value=f_d)])[0]
        if not result.successful:
            raise InputError(f'target_wrench: f_d = {f_d:.4g} N along n refused: '
                             f'{result.reason}')

    # ------------------------------------------------------------------ tare
    def _on_tare(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Tare the sensor (module docstring); answers when done, or why not."""
        node = self.node
        try:
            tare = Tare(node.runtime.params.runtime.tare_time)
            node.loop.start_tare(tare)  # the control thread begins it at its next state
            deadline = time.monotonic() + tare.duration + TARE_WAIT_S
            while tare.running and time.monotonic() < deadline:
                time.sleep(POLL_S)
                node._on_telemetry()
            tare.abort(f'no wrench for {tare.duration + TARE_WAIT_S:g} s')  # if still running
            response.success, response.message = self._finish(tare)
        except Exception as exc:  # noqa: BLE001 - a service callback must answer
            response.success, response.message = False, f'tare failed: {exc!r}'
        self.last_tare = response.message
        if response.success:  # one call site per severity: rclpy refuses to mix them
            node.get_logger().info(f'tare: {response.message}')
        else:
            node.get_logger().warning(f'tare: {response.message}')
        return response

    def _finish(self, tare: Tare) -> tuple[bool, str]:
        """Store a finished tare's offset as ``wrench_offset``; the answer's success, text."""
        if tare.state != 'done':
            return False, f'refused: {tare.reason}'
        offset = [float(v) for v in tare.offset]
        result = self.node.set_parameters([Parameter('wrench_offset', value=offset)])[0]
        if not result.successful:
            return False, f'wrench_offset refused: {result.reason}'
        text = ', '.join(f'{v:.4g}' for v in offset)
        return True, (f'wrench_offset = [{text}] N (sensor frame), the mean of {tare.samples} '
                      f'readings over {tare.t_last - tare.t_first:.3g} s')
