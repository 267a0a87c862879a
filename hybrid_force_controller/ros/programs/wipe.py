"""
The demo's wiping task (``demo --task wipe``): tare, activate, wipe a square, as a cell would.

The sim's force sensor has a bias (``sensor_offset``); the controller starts unconfigured
(``autostart:=false``) and holds still (no sine). :class:`WipeOperator` then does what an
operator's program does, in order: configure the controller (lifecycle service), tare its sensor
(``~/tare``, the arm held by the sim's brakes, the tool touching with no force) unless
``--no-tare``, activate it, wait until it presses ``f_d``, and start the user's script
(send_path.py, a separate process) that sends a square on ``~/path`` and waits for it to be
done. The recording stops :data:`AFTER_S` after the script ends.
"""
from __future__ import annotations

import subprocess
import sys
from typing import Any, Sequence

__all__ = ['WIPE_CONTROLLER_ARGS', 'WIPE_SIM_ARGS', 'WipeOperator']

CONTROLLER = 'hybrid_force_controller'
SENSOR_BIAS_N = '[1.5, -1.0, 2.5]'  # the sim's sensor reads this much more, N, sensor frame
# a real sensor's noise too (0.02 N, a fixed seed): a noiseless biased reading is bit-identical
# while the sim holds the arm, and the controller's frozen-sensor check rightly took it for a
# dead sensor at every activation
WIPE_SIM_ARGS = ['-p', f'sensor_offset:={SENSOR_BIAS_N}', '-p', 'noise_sigma:=0.02']
# unconfigured until the operator's program says; no sine: hold where the tool is until the path
WIPE_CONTROLLER_ARGS = ['-p', 'autostart:=false', '-p', 'ref_amplitude:=[0.0, 0.0, 0.0]']
SETTLE_S = 1.0  # pressing this long before the path is sent, s
PRESS_TIMEOUT_S = 30.0  # the demo fails when the tool is not pressing this long after activation
TOUCH_TOL = 0.5  # pressing: the true force within this fraction of f_d (an untared bias of 2-3 N)
AFTER_S = 1.0  # recorded after the script is done, s
TARE_RETRY_S = 10.0  # a tare refused for want of a wrench is asked again until then


class WipeOperator:
    """The operator's steps, polled by the demo's recording loop (module docstring)."""

    def __init__(self, node: Any, tare: bool, script: Sequence[str], env: dict[str, str],
                 log_path: Any, f_d: float) -> None:
        from geometry_msgs.msg import WrenchStamped
        from lifecycle_msgs.srv import ChangeState
        from std_srvs.srv import Trigger
        self.node, self.tare, self.script_cmd, self.env = node, tare, list(script), env
        self.touching = False  # the true force is within TOUCH_TOL of f_d
        node.create_subscription(WrenchStamped, 'sim/contact_wrench',
                                 lambda m: self._on_force(m, f_d), 10)
        self.log_path = log_path
        self.change = node.create_client(ChangeState, f'{CONTROLLER}/change_state')
        self.trigger = node.create_client(Trigger, f'{CONTROLLER}/tare')
        self.steps = ['configure', *(['tare'] if tare else []), 'activate', 'settle', 'script',
                      'after']
        self.future = None
        self.t_step = 0.0
        self.script: subprocess.Popen | None = None
        self.t_pressing: float | None = None  # when the settle step began

    def _on_force(self, msg: Any, f_d: float) -> None:
        f = msg.wrench.force
        self.touching = abs((f.x * f.x + f.y * f.y + f.z * f.z) ** 0.5 - f_d) <= TOUCH_TOL * f_d

    def poll(self, elapsed: float) -> bool:
        """Advance the steps at recording time ``elapsed`` (s); True when all are done."""
        if not self.steps:
            return True
        step = self.steps[0]
        done = getattr(self, f'_{step}')(elapsed, self.touching)
        if done:
            self.steps.pop(0)
            self.future, self.t_step = None, elapsed
        return not self.steps

    def stop(self) -> None:
        """Stop the script if it still runs (by pid)."""
        if self.script is not None and self.script.poll() is None:
            self.script.terminate()
            try:
                self.script.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.script.kill()
                self.script.wait()

    # ------------------------------------------------------------------ steps
    def _transition(self, transition_id: int) -> bool:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState
        if self.future is None:
            if not self.change.service_is_ready():
                return False
            req = ChangeState.Request(transition=Transition(id=transition_id))
            self.future = self.change.call_async(req)
        if not self.future.done():
            return False
        if not self.future.result().success:
            raise RuntimeError(f'the controller refused lifecycle transition {transition_id}')
        return True

    def _configure(self, elapsed: float, touching: bool) -> bool:
        from lifecycle_msgs.msg import Transition
        return self._transition(Transition.TRANSITION_CONFIGURE)

    def _activate(self, elapsed: float, touching: bool) -> bool:
        from lifecycle_msgs.msg import Transition
        return self._transition(Transition.TRANSITION_ACTIVATE)

    def _tare(self, elapsed: float, touching: bool) -> bool:
        from std_srvs.srv import Trigger
        if self.future is None:
            if not self.trigger.service_is_ready():
                return False
            self.future = self.trigger.call_async(Trigger.Request())
        if not self.future.done():
            return False
        answer = self.future.result()
        if not answer.success and 'no wrench' in answer.message and elapsed < TARE_RETRY_S:
            self.future = None  # the wrench has not reached the just-configured loop yet: again
            return False
        if not answer.success:
            raise RuntimeError(f'tare: {answer.message}')
        print(f'\n  tare: {answer.message}')
        return True

    def _settle(self, elapsed: float, touching: bool) -> bool:
        if self.t_pressing is None:
            self.t_pressing = elapsed
        if elapsed - self.t_pressing > PRESS_TIMEOUT_S:
            raise RuntimeError(f'the tool did not press f_d within {PRESS_TIMEOUT_S:.0f} s of the '
                               "activation; see the controller's log")
        if not touching:
            self.t_step = elapsed
        return touching and elapsed - self.t_step >= SETTLE_S

    def _script(self, elapsed: float, touching: bool) -> bool:
        if self.script is None:
            with open(self.log_path, 'wb') as log:
                self.script = subprocess.Popen([sys.executable, '-m', *self.script_cmd],
                                               env=self.env, stdout=log,
                                               stderr=subprocess.STDOUT)
        code = self.script.poll()
        if code is None:
            return False
        if code != 0:
            raise RuntimeError(f'the path script ended with {code}; see {self.log_path}')
        return True

    def _after(self, elapsed: float, touching: bool) -> bool:
        return elapsed - self.t_step >= AFTER_S
