"""
The cases' helpers of the fault-injection rig (:mod:`helpers.fault_rig`): hooks, copies, checks.

The rig's settings (``config/params.yaml``, the bundled arm) and its fixtures are in
conftest.py (``fault_rig``, ``healthy``); a case plays its fault through the rig's hooks and
checks what /diagnostics reported and that tracking was not disturbed, on sim time.
"""
from __future__ import annotations

from geometry_msgs.msg import WrenchStamped
from helpers.fault_rig import Rig, set_stamp, stamp_s
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.environment import sensor_wrench_from_f_W
import numpy as np
from sensor_msgs.msg import JointState


N_W = np.array([0.0, -1.0, 0.0])      # config/params.yaml: contact normal, into the surface
LIMITS = np.array([100.0, 100.0])     # URDF effort limits of the bundled arm, N m
F_D, LAMBDA1, APPROACH_SPEED = 1.0, 40.0, 0.025  # config/params.yaml, defaults
COMMAND_TIMEOUT = 0.005               # sim: zero effort 5 ms (sim) after the last command
MODEL = RobotModel.from_urdf(None)


def start_rig(logs, domain: int) -> Rig:
    """Start sim and controller with a proxy between them; return the rig, tracking."""
    rig = Rig(logs, domain, N_W, LIMITS, sim_args=['-p', f'command_timeout:={COMMAND_TIMEOUT}'],
              controller_args=[])
    try:
        rig.start()
        rig.wait_tracking(10.0, 'start-up')
    except BaseException:
        rig.close()
        raise
    return rig


class Every:
    """Hook: every k-th message is replaced by ``make(msg)`` (``keep``: followed by it)."""

    def __init__(self, k: int, make, keep: bool = False) -> None:
        self.k, self.make, self.keep = k, make, keep
        self.seen = self.count = 0

    def __call__(self, msg):
        self.seen += 1
        if self.seen % self.k:
            return [msg]
        self.count += 1
        bad = self.make(msg, self.count)
        return [msg, bad] if self.keep else [bad]


def js_copy(msg: JointState, **fields) -> JointState:
    out = JointState(name=list(msg.name), position=list(msg.position),
                     velocity=list(msg.velocity), effort=list(msg.effort))
    out.header.frame_id = msg.header.frame_id
    set_stamp(out, stamp_s(msg.header.stamp))  # a copy: never alias the original's stamp
    for key, value in fields.items():
        setattr(out, key, value)
    return out


def wrench_copy(msg: WrenchStamped, force=None, frame=None) -> WrenchStamped:
    out = WrenchStamped()
    set_stamp(out, stamp_s(msg.header.stamp))
    out.header.frame_id = msg.header.frame_id if frame is None else frame
    f = msg.wrench.force
    fx, fy, fz = (f.x, f.y, f.z) if force is None else force
    out.wrench.force.x, out.wrench.force.y, out.wrench.force.z = fx, fy, fz
    return out


def sensor_force(rig: Rig, f_n: float) -> tuple[float, float, float]:
    """
    Return what the wrist sensor (tool0) reads when the tool presses with ``f_n`` N along n.

    At the arm's latest raw joint state.
    """
    R = MODEL.frame_rotation(np.array(rig.proxy.js_raw.position), 'tool0')
    return tuple(float(c) for c in sensor_wrench_from_f_W(R, f_n * N_W))


def counters(rig: Rig, t: float, what: str) -> dict:
    """Return the /diagnostics status stamped after ``t`` (a margin for messages in flight)."""
    return rig.diag_after(t + 0.02, what)


def delta(after: dict, before: dict, key: str) -> int:
    return int(after.get(key, 0)) - int(before.get(key, 0))


def assert_unaffected(rig: Rig, t0: float, what: str) -> None:
    """Check that the force never left the band since ``t0`` (tracking unaffected by the fault)."""
    assert rig.proxy.t_force_bad < t0, (
        f'{what}: the force left {F_D} +- 0.05 N at t={rig.proxy.t_force_bad:.3f} s')


def tool_motion(rig: Rig, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return times, tool positions and velocities (base frame) from the raw joint states."""
    rows = [(t, msg) for t, msg in list(rig.proxy.js_log) if t0 <= t <= t1]
    ts, ps, vs = [], [], []
    for t, msg in rows:
        kin = MODEL.kinematics(np.array(msg.position), np.array(msg.velocity))
        v_W = np.zeros(3)
        v_W[list(MODEL.task_axes)] = kin.xdot
        ts.append(t)
        ps.append(np.array(kin.p_W))
        vs.append(v_W)
    return np.array(ts), np.array(ps), np.array(vs)


def largest_step(rig: Rig, t0: float, t1: float) -> float:
    taus = [tau for t, tau in rig.proxy.cmds[rig.proxy.cmds_from:] if t0 <= t <= t1]
    return float(np.abs(np.diff(taus, axis=0)).max())


def input_fault_case(rig: Rig, what: str, js=None, wrench=None, counter: str = '',
                     texts: tuple[str, ...] = (), duration: float = 0.2) -> None:
    """
    Play a fault of counted bad messages.

    They are all dropped, counted and named (the last one's reason on /diagnostics), and tracking
    is not disturbed at all.
    """
    hook = js or wrench
    with rig.case():
        before = rig.last_diag()
        t0, t1 = rig.fault(duration, js=js, wrench=wrench)
        after = counters(rig, t1, what)
        for text in texts:
            assert text in after['last_input_fault'], (text, after['last_input_fault'])
        topic = 'joint_states' if js else 'wrench'
        assert hook.count > 0
        assert delta(after, before, counter) == hook.count, (what, before, after, hook.count)
        assert delta(after, before, f'callback_errors_{topic}') == hook.count
        assert delta(after, before, 'safe_mode_entries') == 0
        assert after['mode'] == 'running' and after['in_contact'] is True, after
        assert_unaffected(rig, t0, what)  # and 'running' after it: tracking never stopped
