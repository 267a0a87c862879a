"""
The MuJoCo scene of ``physics:=mujoco``: the sim's URDF, a sphere tool, a plane, a wrist sensor.

:func:`build_scene` compiles the robot from the same URDF and ``joints`` as the controller's
model (the other joints deleted: welded at 0, as the reduced pinocchio model locks them), with
``fusestatic`` off so every URDF link stays a body, point masses accepted
(``boundinertia``) and gravity from the model. It adds

* a tool body ``hfc_tool`` on ``end_effector_link`` (same frame) carrying a sphere of
  ``tool_radius`` and ``tool_mass`` centred on the link's origin (``tool_shape`` disc: a
  4 mm thick disc of that radius, its axis the link's z), and a site there with a
  ``force`` + ``torque`` sensor pair: the wrist sensor, in the end-effector frame;
* the surface: a table top ``hfc_surface`` (a 2 m x 2 m box) whose top face passes through the
  surface point, its outward normal ``-n_W`` (``n_W`` points into the surface), mounted on a
  slide joint along that normal with a spring and damper: the surface's stiffness ``k`` (N/m)
  and ``surface_damping`` (N s/m); gravity-compensated, light (:func:`plate_mass`). For
  ``surface_shape`` cylinder or sphere the same sprung mount carries, instead of the box, a
  cylinder (2 m long, along ``surface_axis``) or a sphere of ``surface_radius`` whose surface
  passes through the surface point with its normal ``n_W`` there (centre ``R n_W`` beyond it,
  environment.py's convention). The mount slides along ``n_W`` of the surface point only, so
  where the local normal is an angle ``phi`` away from it the static stiffness along that normal
  is ``1 / (1 / k_c + cos^2 phi / k_spring) = k / (0.2 + 0.8 cos^2 phi)``: ``k`` at the surface
  point, +2.5 % at 10 deg, +10 % at 20 deg; the shape is fixed at start-up, its radius and pose
  may change at run time;
* one explicit contact pair, the tool on the table top (elliptic cone; friction ``mu`` when
  ``surface_friction`` > 0, else frictionless, condim 1). A disc lying flat touches at four
  points (MuJoCo's convex collision), each with the contact's stiffness: its static stiffness is
  then ``1 / (0.8 / k + 0.2 / (4 k)) = 1.18 k``; on its rim (tilted), ``k``;
* the pipeline stages it never needs switched off (``UNUSED_STAGES``: islands, mid-phase,
  parent filtering, actuation; joint friction loss when ``joint_friction`` is 0).

Contact stiffness: MuJoCo's negative ``solref`` is not N/m. With the flat impedance ``solimp =
[d, d, ...]`` the static stiffness of a contact is ``k_c = -solref[0] / ((1 - d) tran)``,
``tran`` the sum of the two bodies' ``body_invweight0`` (known once compiled). The contact is
made ``CONTACT_STIFFNESS_RATIO`` times stiffer than ``k`` and the spring makes up the rest in
series, ``1 / k_spring = 1 / k - 1 / k_c``, so the static stiffness is exactly ``k``.

Why a sprung table top rather than all compliance in the contact: with all of it in a soft
contact (``d`` = 0.01) friction is soft too and MuJoCo's elliptic cone couples the normal to the
tangential drive (the normal force grew while the sliding tool left the surface; the closed loop
chattered), and a hard contact on a light plate rattled. ``d`` = 0.5 with ``impratio`` 100 (the
friction rows 100 times less regularised than the normal) holds a 1 N side push below
``mu f_n`` to a creep of about 0.3 mm/s and slides above it. No-slip iterations changed nothing
measurable (MuJoCo 4.0.0), so none are used.

Link masses ``theta`` (the ``link_masses`` set) scale each pinocchio body's URDF links, keeping
their geometry.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path

from hybrid_force_controller.core.config.params import ParameterValidationError
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.environment import (Surface, SURFACE_SHAPES,
                                                              SurfaceError)
import mujoco
import numpy as np

from .mujoco_params import DISC_HALF_THICKNESS_M, MujocoOptions

__all__ = ['Scene', 'build_scene', 'check_surface', 'plate_mass', 'set_surface',
           'surface_shift']

TOOL_BODY, TOOL_GEOM, SURFACE_GEOM, FT_SITE = 'hfc_tool', 'hfc_tool_sphere', 'hfc_surface', \
    'hfc_ft_site'
SURFACE_BODY, SURFACE_JOINT = 'hfc_surface_plate', 'hfc_surface_spring'
D_IMPEDANCE = 0.5  # flat solimp: the contact's impedance d at every depth
SOLIMP = (D_IMPEDANCE, D_IMPEDANCE, 0.001, 0.5, 2.0)
CONTACT_STIFFNESS_RATIO = 5.0  # contact k_c / surface k; the plate's spring makes up the rest
CONTACT_DAMPING_RATIO = 1.0  # contact damping, fraction of critical (tool against contact)
IMPRATIO = 100.0  # friction regularised this much less than the normal: it holds
PLATE_OMEGA_DT = 0.25  # the plate's sqrt(k / m) dt: its explicit spring stays stable
PLATE_K_RANGE = 4.0  # run-time stiffness changes up to this factor keep it stable
PLATE_OMEGA_DT_MAX = PLATE_OMEGA_DT * math.sqrt(PLATE_K_RANGE) * (1.0 + 1e-9)
PLATE_MASS_MIN = 0.01  # kg
PLATE_HALF_SIZE = (1.0, 1.0, 0.05)  # m: a 2 m x 2 m table top, 10 cm thick
CYLINDER_HALF_LENGTH = 1.0  # m: a 2 m cylinder, as long as the table top is wide
ROUND_GEOMS = {'sphere': mujoco.mjtGeom.mjGEOM_SPHERE, 'cylinder': mujoco.mjtGeom.mjGEOM_CYLINDER}
# the geom in the plate's frame: a cylinder's own axis (z) turned onto the plate's x
ROUND_GEOM_QUAT = {'sphere': (1.0, 0.0, 0.0, 0.0),
                   'cylinder': (math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0)}
# pipeline stages this scene never needs (one explicit contact pair, no actuators, one island):
# skipping them took a 1 ms Panda step from 147 to 134 us with cold caches (the sim's case)
_D = mujoco.mjtDisableBit
UNUSED_STAGES = int(_D.mjDSBL_ISLAND | _D.mjDSBL_MIDPHASE | _D.mjDSBL_FILTERPARENT
                    | _D.mjDSBL_ACTUATION | _D.mjDSBL_CLAMPCTRL)


@dataclass
class Scene:
    """
    A compiled scene and the indices the plant reads.

    ``qpos``/``dof`` are the model's joints (RobotModel order); ``R_root_W`` and ``o_W`` map
    base-frame vectors and points to MuJoCo's world (the URDF root).
    """

    model: mujoco.MjModel
    qpos: np.ndarray
    dof: np.ndarray
    ee_body: int
    tool_body: int
    tool_geom: int
    plate: int
    plate_dof: int
    force_adr: int
    torque_adr: int
    R_W_root: np.ndarray
    rotated: bool
    o_W: np.ndarray
    damping: float
    shape: str = 'plane'
    surface_geom: int = -1


def _urdf_text(urdf: str | Path) -> str:
    text = str(urdf)
    return text if text.lstrip().startswith('<') else Path(text).read_text()


def _delete_locked_joints(spec: mujoco.MjSpec, keep: tuple[str, ...]) -> None:
    """Delete every joint not controlled (welded at 0, so 0 must be in range), their mimics."""
    gone = {j.name for j in spec.joints if j.name not in keep}
    for eq in list(spec.equalities):  # URDF mimic joints become joint equalities
        if {eq.name1, eq.name2} & gone:
            spec.delete(eq)
    for joint in list(spec.joints):
        if joint.name in keep:
            continue
        lo, hi = joint.range
        if joint.limited != mujoco.mjtLimited.mjLIMITED_FALSE and not lo <= 0.0 <= hi:
            raise ParameterValidationError(
                f"physics:=mujoco welds the locked joint '{joint.name}' at 0, outside its "
                f'limits [{lo:g}, {hi:g}]; control it (joints) or use physics:=paper')
        spec.delete(joint)


def _joint_of_body(spec: mujoco.MjSpec) -> dict[str, str]:
    """Body name -> name of the nearest joint that moves it ('' for the fixed base)."""
    out: dict[str, str] = {}

    def walk(body, joint: str) -> None:
        joints = list(body.joints)
        joint = joints[-1].name if joints else joint
        out[body.name] = joint
        for child in body.bodies:
            walk(child, joint)
    walk(spec.worldbody, '')
    return out


def _scale_masses(spec: mujoco.MjSpec, model: RobotModel, theta: np.ndarray | None) -> None:
    """Scale every link moved by joint j by theta_j / m_j (the link_masses set)."""
    if theta is None:
        return
    if model.parameter_set.name != 'link_masses':
        raise ParameterValidationError('physics:=mujoco takes masses for the link_masses '
                                       f'parameter set only, not {model.parameter_set.name}')
    nominal = dict(zip(model.theta_names, model.theta_nominal))
    scale = {name[2:]: float(t) / nominal[name] for name, t in zip(model.theta_names, theta)}
    for body_name, joint in _joint_of_body(spec).items():
        s = scale.get(joint)
        if s is None or body_name == 'world':
            continue
        body = spec.body(body_name)
        body.mass *= s
        if np.isfinite(body.fullinertia[0]):
            body.fullinertia = body.fullinertia * s
        body.inertia = body.inertia * s


def _configure_joints(spec: mujoco.MjSpec, opts: MujocoOptions) -> None:
    for joint in spec.joints:
        joint.damping = [opts.joint_damping, 0.0, 0.0]
        joint.frictionloss = opts.joint_friction
        if not opts.joint_limits:
            joint.limited = mujoco.mjtLimited.mjLIMITED_FALSE
    for geom in spec.geoms:  # the URDF's own geoms collide with nothing
        geom.contype = geom.conaffinity = 0


def _add_tool(spec: mujoco.MjSpec, ee_link: str, opts: MujocoOptions) -> None:
    """Tool body on the end-effector link: sphere or disc, mass, sensor site, F/T sensors."""
    try:
        parent = spec.body(ee_link)
    except Exception:  # noqa: BLE001 - the binding's lookup error type varies
        parent = None
    if parent is None:
        raise ParameterValidationError(f"physics:=mujoco needs end_effector_link '{ee_link}' "
                                       'to be a URDF link')
    r, m, h = opts.tool_radius, opts.tool_mass, DISC_HALF_THICKNESS_M
    tool = parent.add_body(name=TOOL_BODY, pos=[0.0, 0.0, 0.0])
    tool.explicitinertial = True
    tool.mass = m
    if opts.tool_shape == 'disc':  # a cylinder along the link's z (MuJoCo's own axis)
        side = m * (3.0 * r * r + 4.0 * h * h) / 12.0
        tool.inertia = [side, side, 0.5 * m * r * r]
        kind, size = mujoco.mjtGeom.mjGEOM_CYLINDER, [r, h, 0.0]
    else:
        tool.inertia = [0.4 * m * r * r] * 3
        kind, size = mujoco.mjtGeom.mjGEOM_SPHERE, [r, 0.0, 0.0]
    tool.add_geom(name=TOOL_GEOM, type=kind, size=size, mass=0.0, contype=0, conaffinity=0,
                  rgba=[0.9, 0.4, 0.1, 1.0])
    tool.add_site(name=FT_SITE, pos=[0.0, 0.0, 0.0])
    for kind, name in ((mujoco.mjtSensor.mjSENS_FORCE, 'hfc_ft_force'),
                       (mujoco.mjtSensor.mjSENS_TORQUE, 'hfc_ft_torque')):
        spec.add_sensor(name=name, type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=FT_SITE)


def _add_surface(spec: mujoco.MjSpec, opts: MujocoOptions, mass: float, shape: str) -> None:
    """Add the plate on its spring (a slide joint along its +z), the contact pair, options."""
    plate = spec.worldbody.add_body(name=SURFACE_BODY, gravcomp=1.0)
    plate.explicitinertial = True
    plate.mass, plate.inertia = mass, [mass * 1e-2] * 3  # the contact's R uses it: compile
    plate.add_joint(name=SURFACE_JOINT, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0.0, 0.0, 1.0],
                    limited=mujoco.mjtLimited.mjLIMITED_FALSE)
    if shape == 'plane':
        plate.add_geom(name=SURFACE_GEOM, type=mujoco.mjtGeom.mjGEOM_BOX, size=PLATE_HALF_SIZE,
                       pos=[0.0, 0.0, -PLATE_HALF_SIZE[2]], contype=0, conaffinity=0,
                       rgba=[0.5, 0.6, 0.7, 1.0])  # its top face through the body's origin
    else:  # its surface through the body's origin, normal +z there (set_surface sizes it)
        plate.add_geom(name=SURFACE_GEOM, type=ROUND_GEOMS[shape],
                       size=[1.0, CYLINDER_HALF_LENGTH, 0.0], pos=[0.0, 0.0, -1.0],
                       quat=list(ROUND_GEOM_QUAT[shape]), contype=0, conaffinity=0,
                       rgba=[0.5, 0.6, 0.7, 1.0])
    mu = opts.surface_friction
    spec.add_pair(name='hfc_contact', geomname1=SURFACE_GEOM, geomname2=TOOL_GEOM,
                  condim=3 if mu > 0.0 else 1, friction=[mu, mu, 0.0, 0.0, 0.0],
                  solimp=list(SOLIMP), margin=0.0, gap=0.0)
    opt = spec.option
    opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    opt.impratio = IMPRATIO
    opt.disableflags |= UNUSED_STAGES | (0 if opts.joint_friction > 0.0 else
                                         int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS))


def build_scene(urdf: str | Path, model: RobotModel, opts: MujocoOptions, timestep: float,
                k: float, theta: np.ndarray | None = None, shape: str = 'plane') -> Scene:
    """
    Compile the scene (see the module docstring); ParameterValidationError if it cannot.

    ``shape`` is the surface's (environment.py's SURFACE_SHAPES), fixed for the scene's life.
    """
    if shape not in SURFACE_SHAPES:
        raise ParameterValidationError(f'surface_shape must be one of {list(SURFACE_SHAPES)}, '
                                       f'got {shape!r}')
    try:
        spec = mujoco.MjSpec.from_string(_urdf_text(urdf))
    except ValueError as exc:
        raise ParameterValidationError(f'MuJoCo cannot load the URDF: {exc}') from None
    spec.compiler.fusestatic = False
    spec.compiler.boundinertia = 1e-12  # the paper's arm has point masses
    spec.compiler.boundmass = 1e-12  # a tool of zero mass
    spec.option.gravity = model.model.gravity.linear.copy()  # URDF root = MuJoCo world
    spec.option.timestep = timestep
    _delete_locked_joints(spec, tuple(model.joint_names))
    _scale_masses(spec, model, theta)
    _configure_joints(spec, opts)
    _add_tool(spec, model.end_effector_link, opts)
    _add_surface(spec, opts, plate_mass(k, timestep), shape)
    m = spec.compile()
    return _index(m, model, opts, shape)


def _index(m: mujoco.MjModel, model: RobotModel, opts: MujocoOptions, shape: str) -> Scene:
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in model.joint_names]
    R_W_root = model.base_from_root(np.zeros(3), np.eye(3), np.zeros((3, 0)))[1]
    o_W = model.base_from_root(np.zeros(3), np.eye(3), np.zeros((3, 0)))[0]
    tool = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, TOOL_BODY)
    sensor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, 'hfc_ft_force')
    torque = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, 'hfc_ft_torque')
    return Scene(model=m, qpos=m.jnt_qposadr[ids].copy(), dof=m.jnt_dofadr[ids].copy(),
                 ee_body=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY,
                                           model.end_effector_link),
                 tool_body=tool,
                 tool_geom=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, TOOL_GEOM),
                 plate=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, SURFACE_BODY),
                 plate_dof=int(m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT,
                                                              SURFACE_JOINT)]),
                 force_adr=int(m.sensor_adr[sensor]), torque_adr=int(m.sensor_adr[torque]),
                 R_W_root=np.array(R_W_root, dtype=float), o_W=np.array(o_W, dtype=float),
                 rotated=not (np.array_equal(R_W_root, np.eye(3)) and not np.any(o_W)),
                 damping=opts.surface_damping, shape=shape,
                 surface_geom=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, SURFACE_GEOM))


def plate_mass(k: float, timestep: float) -> float:
    """Return the plate's mass, kg: light, yet its spring k stays stable at ``timestep``."""
    return max(PLATE_MASS_MIN, k * (timestep / PLATE_OMEGA_DT) ** 2)


def check_surface(scene: Scene, surface: Surface) -> None:
    """Raise SurfaceError when the table top sized at start-up cannot take ``surface``."""
    if surface.shape != scene.shape:
        raise SurfaceError(f'physics:=mujoco: the surface shape is fixed at start-up (the scene '
                           f'has a {scene.shape}, not a {surface.shape}); restart the sim with '
                           'it')
    m = scene.model
    omega_dt = math.sqrt(surface.k / m.body_mass[scene.plate]) * m.opt.timestep
    if omega_dt > PLATE_OMEGA_DT_MAX:
        raise SurfaceError(f'physics:=mujoco: stiffness {surface.k:g} N/m is too high for the '
                           f'plate sized at start-up (at most {PLATE_K_RANGE:g} times the '
                           'start-up stiffness; restart the sim with it)')


def set_surface(scene: Scene, d: mujoco.MjData, surface: Surface | None) -> None:
    """
    Place the plate and set its spring (model); None: no contact at all.

    The damping is the scene's ``surface_damping``. Takes effect at the next step; the plate's
    deflection (its joint state) is kept.
    """
    m = scene.model
    disable = int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    if surface is None:
        m.opt.disableflags |= disable
        return
    check_surface(scene, surface)
    m.opt.disableflags &= ~disable
    b, j = scene.plate, m.dof_jntid[scene.plate_dof]
    m.body_pos[b] = scene.R_W_root.T @ (surface.x0_W - scene.o_W)
    quat = np.zeros(4)
    if surface.shape == 'cylinder':  # +z out of the surface, +x along the axis
        _round_geom(scene, surface.radius)
        z = -(scene.R_W_root.T @ surface.n_W)
        x = scene.R_W_root.T @ surface.axis_W
        mujoco.mju_mat2Quat(quat, np.column_stack((x, np.cross(z, x), z)).reshape(-1))
    else:
        if surface.shape == 'sphere':
            _round_geom(scene, surface.radius)
        mujoco.mju_quatZ2Vec(quat, -(scene.R_W_root.T @ surface.n_W))  # +z out of the surface
    m.body_quat[b] = quat
    k_c = CONTACT_STIFFNESS_RATIO * surface.k
    m.jnt_stiffness[j] = 1.0 / (1.0 / surface.k - 1.0 / k_c)  # in series: k in all
    tran = m.body_invweight0[scene.tool_body, 0] + m.body_invweight0[b, 0]
    c_c = 2.0 * CONTACT_DAMPING_RATIO * math.sqrt(k_c / tran)
    m.pair_solref[0] = [-(1.0 - D_IMPEDANCE) * tran * k_c, -(1.0 - D_IMPEDANCE) * tran * c_c]
    m.dof_damping[scene.plate_dof] = scene.damping


def _round_geom(scene: Scene, radius: float) -> None:
    """Size the sphere or cylinder geom: radius R, its surface through the plate's origin."""
    m, g = scene.model, scene.surface_geom
    half = CYLINDER_HALF_LENGTH if scene.shape == 'cylinder' else radius
    m.geom_size[g, :2] = radius, CYLINDER_HALF_LENGTH
    m.geom_pos[g] = 0.0, 0.0, -radius
    m.geom_rbound[g] = math.hypot(radius, CYLINDER_HALF_LENGTH) if scene.shape == 'cylinder' \
        else radius
    m.geom_aabb[g] = 0.0, 0.0, 0.0, radius, radius, half  # local frame: centre, half sizes


def surface_shift(scene: Scene, d: mujoco.MjData) -> np.ndarray:
    """Return how far the sprung surface has moved from its rest pose, base frame, m."""
    b = scene.plate
    return scene.R_W_root @ (d.xpos[b] - scene.model.body_pos[b])
