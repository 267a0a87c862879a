"""
Tilted and curved surfaces of the sim, offline: the paper's physics and MuJoCo's.

* core (environment.py): a cylinder and a sphere push along their local normal with
  ``k depth``, never pull, pass through their point with the normal given there (centre on the
  far side), and bad shapes, radii and axes are refused with the reason; the plane is unchanged
  (``make_surface('plane')`` is ``ElasticSurface.create``, ``normal_at`` is ``n_W``);
* the sim's values (sim_surface.py): the tool's start touches every shape, with and without the
  MuJoCo tool's radius;
* the paper's plant (simulator.py) on a cylinder: the contact force is along the local normal;
* MuJoCo (mujoco_scene.py): a static press on each shape gives the stiffness parameter at the
  surface point; pressed sideways the frictionless contact force is along the plant's contact
  normal, which is the analytic one of the surface moved on its spring; a radius change at run
  time resizes the geom; a shape change is refused.
"""
from __future__ import annotations

import math

from helpers.figures import angle_deg
from helpers.offline import mujoco_arm, mujoco_press, R_TOOL
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.environment import (CylinderSurface, default_axis,
                                                              ElasticSurface, make_surface,
                                                              SphereSurface, SurfaceError)
from hybrid_force_controller.core.offline.simulator import ArmSimulator
import numpy as np
import pytest
from sim_node.sim_surface import surface_from_values


K = 1700.0
N_DOWN = np.array([0.0, 0.0, -1.0])


# ---------------------------------------------------------------- core shapes
def test_plane_of_make_surface_is_the_elastic_surface():
    s = make_surface('plane', K, [1.0, 1.6, 0.0], [0.0, -2.0, 0.0], 0.3, [5.0, 5.0, 5.0])
    assert type(s) is ElasticSurface and s.shape == 'plane'
    ref = ElasticSurface.create(K, [1.0, 1.6, 0.0], [0.0, -2.0, 0.0])
    p = np.array([1.2, 1.598, 0.1])
    np.testing.assert_array_equal(s.force(p), ref.force(p))
    assert s.normal_at(p) is s.n_W


@pytest.mark.parametrize('shape', ['sphere', 'cylinder'])
def test_round_surface_passes_through_its_point_with_its_normal_there(shape):
    x0, n = np.array([0.3, -0.2, 0.5]), np.array([0.0, 0.6, -0.8])
    s = make_surface(shape, K, x0, n, 0.4, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(s.c_W, x0 + 0.4 * n, atol=1e-15)
    assert s.penetration(x0) == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(s.normal_at(x0 - 0.01 * n), n, atol=1e-12)  # outside, above x0
    np.testing.assert_array_equal(s.force(x0 - 1e-6 * n), np.zeros(3))


@pytest.mark.parametrize('shape', ['sphere', 'cylinder'])
def test_round_surface_pushes_k_depth_along_the_local_normal_and_never_pulls(shape):
    rng = np.random.default_rng(3)
    s = make_surface(shape, K, [0.0, 0.0, 0.0], N_DOWN, 0.3, [1.0, 0.0, 0.0])
    inside = 0
    for _ in range(300):
        p = s.c_W + rng.normal(0.0, 0.2, 3)
        rho = p - s.c_W
        if shape == 'cylinder':
            rho -= (rho @ s.axis_W) * s.axis_W
        depth = 0.3 - np.linalg.norm(rho)
        assert s.penetration(p) == pytest.approx(depth, abs=1e-15)
        n_local = -rho / np.linalg.norm(rho)
        np.testing.assert_allclose(s.normal_at(p), n_local, atol=1e-12)
        assert np.linalg.norm(s.normal_at(p)) == pytest.approx(1.0, abs=1e-12)
        f = s.force(p)
        if depth > 0.0:
            inside += 1
            np.testing.assert_allclose(f, K * depth * n_local, rtol=1e-12, atol=1e-12)
        else:
            np.testing.assert_array_equal(f, np.zeros(3))
    assert 30 < inside < 270  # both sides were exercised


def test_cylinder_force_has_no_axial_part_and_does_not_change_along_the_axis():
    s = make_surface('cylinder', K, [0.0, 0.0, 0.0], N_DOWN, 0.3, [1.0, 0.0, 0.0])
    p = np.array([0.0, 0.05, -0.006])  # 1.8 mm deep, 5 cm off the top line
    for x in (-0.7, 0.0, 0.4):
        f = s.force(p + [x, 0.0, 0.0])
        assert f[0] == 0.0
        np.testing.assert_allclose(f, s.force(p), rtol=1e-12)
    assert s.force(p)[1] < 0.0 and s.penetration(p) > 0.0  # off the top: leans to the axis


def test_normal_at_the_centre_is_the_reference_normal():
    s = make_surface('sphere', K, [0.0, 0.0, 0.0], N_DOWN, 0.3)
    np.testing.assert_array_equal(s.normal_at(s.c_W.copy()), N_DOWN)
    assert np.all(np.isfinite(s.force(s.c_W.copy())))


@pytest.mark.parametrize('n, axis', [([0.0, -1.0, 0.0], [0.0, 0.0, 1.0]),
                                     ([0.0, 0.0, -1.0], [1.0, 0.0, 0.0]),
                                     ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0])])
def test_default_axis_is_the_base_axis_most_perpendicular_to_the_normal(n, axis):
    np.testing.assert_array_equal(default_axis(np.array(n)), axis)
    s = make_surface('cylinder', K, [0.0, 0.0, 0.0], n, 0.3)
    np.testing.assert_array_equal(s.axis_W, axis)


def test_axis_slightly_off_the_tangent_plane_is_made_perpendicular():
    tilt = math.radians(0.5)
    s = make_surface('cylinder', K, [0, 0, 0], N_DOWN, 0.3,
                     [math.cos(tilt), 0.0, math.sin(tilt)])
    assert isinstance(s, CylinderSurface)
    assert abs(float(s.axis_W @ N_DOWN)) < 1e-15
    assert np.linalg.norm(s.axis_W) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize('shape, radius, axis, words', [
    ('cone', 0.3, None, "surface shape must be one of ['plane', 'cylinder', 'sphere']"),
    ('sphere', 0.0, None, 'surface radius must be finite and > 0'),
    ('sphere', -0.2, None, 'surface radius'),
    ('cylinder', math.nan, None, 'surface radius'),
    ('cylinder', math.inf, None, 'surface radius'),
    ('sphere', True, None, 'surface radius'),
    ('cylinder', 0.3, [0.0, 0.0, 0.0], 'surface axis must be a non-zero finite 3-vector'),
    ('cylinder', 0.3, [1.0, math.nan, 0.0], 'surface axis'),
    ('cylinder', 0.3, [1.0, 0.0], 'surface axis'),
    ('cylinder', 0.3, [1.0, 0.0, math.tan(math.radians(2.0))],
     'must be perpendicular to the surface normal'),
    ('cylinder', 0.3, [0.0, 0.0, 1.0], '90.00 deg off the tangent plane'),
])
def test_bad_shape_radius_or_axis_is_refused_with_the_reason(shape, radius, axis, words):
    with pytest.raises(SurfaceError) as exc:
        make_surface(shape, K, [0, 0, 0], N_DOWN, radius, axis)
    assert words in str(exc.value), str(exc.value)


# ---------------------------------------------------------------- the sim's values
def _values(**kw):
    v = {'stiffness': K, 'surface_point': [], 'surface_normal': [0.0, 0.0, -1.0],
         'surface_enabled': True, 'surface_shape': 'plane', 'surface_radius': 0.5,
         'surface_axis': [], 'sensor_frozen': False, 'sensor_offset': []}
    return {**v, **kw}


@pytest.mark.parametrize('shape', ['plane', 'cylinder', 'sphere'])
@pytest.mark.parametrize('tool_radius', [0.0, 0.01])
def test_the_tool_start_touches_every_shape(shape, tool_radius):
    p0 = np.array([0.4, 0.1, 0.3])
    surface, (frozen, offset) = surface_from_values(_values(surface_shape=shape), p0,
                                                    lambda n_W: tool_radius)
    assert surface.shape == shape and not frozen and offset is None
    contact = p0 + tool_radius * N_DOWN  # the sphere tool's lowest point
    assert surface.penetration(contact) == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(surface.normal_at(p0), N_DOWN, atol=1e-15)


def NO_REACH(n_W):  # a point tool: the paper's physics
    return 0.0


def test_sim_values_are_refused_with_the_reason_and_checked_by_the_plant():
    p0 = np.zeros(3)
    with pytest.raises(SurfaceError, match='surface shape must be one of'):
        surface_from_values(_values(surface_shape='torus'), p0, NO_REACH)
    with pytest.raises(SurfaceError, match='perpendicular'):
        surface_from_values(_values(surface_shape='cylinder', surface_axis=[0.0, 0.0, 1.0]),
                            p0, NO_REACH)
    with pytest.raises(SurfaceError, match='surface_radius a number'):
        surface_from_values(_values(surface_shape='sphere', surface_radius='big'), p0, NO_REACH)
    seen = []
    surface, _ = surface_from_values(_values(surface_shape='sphere', surface_enabled=False), p0,
                                     NO_REACH, seen.append)
    assert surface is None and isinstance(seen[0], SphereSurface)  # checked though disabled


# ---------------------------------------------------------------- the paper's plant
def test_paper_plant_on_a_cylinder_pushes_along_the_local_normal():
    model = RobotModel.from_urdf()
    q0 = np.array([0.657, 0.913])
    p0 = model.kinematics(q0, np.zeros(2)).p_W
    n = np.array([0.0, -1.0, 0.0])
    # the top 5 cm aside and 5 mm up: the tool is 0.8 mm inside, where the normal leans 9.6 deg
    s = make_surface('cylinder', K, p0 + [0.05, 0.005, 0.0], n, 0.3)
    assert s.penetration(p0) == pytest.approx(0.3 - math.hypot(0.05, 0.295), abs=1e-12)
    sim = ArmSimulator(model, s, q0, substeps=2)
    meas = sim.measure()
    n_local = s.normal_at(meas.p_W)
    assert angle_deg(n_local, n) == pytest.approx(math.degrees(math.asin(0.05 / 0.3)), abs=0.5)
    np.testing.assert_allclose(meas.f_true_W, K * s.penetration(meas.p_W) * n_local, rtol=1e-12)
    np.testing.assert_array_equal(sim.contact_normal(meas.p_W), n_local)
    sim.surface = None
    assert sim.contact_normal(meas.p_W) is None


# ---------------------------------------------------------------- MuJoCo
def _mujoco(arm, shape, radius, axis=None, k=K):
    """Build a MuJoCo plant whose tool touches ``shape`` at its start (frictionless, damped)."""
    from sim_node.mujoco_params import MujocoOptions
    from sim_node.mujoco_plant import MujocoPlant
    model, urdf, q0, n_W = mujoco_arm(arm)
    p0 = model.kinematics(q0, np.zeros(model.n)).p_W
    surface = make_surface(shape, k, p0 + R_TOOL * n_W, n_W, radius, axis)
    opts = MujocoOptions(tool_radius=R_TOOL, surface_damping=20.0)
    return model, MujocoPlant(model, urdf, opts, surface, q0), n_W


def _offset_depth(surface, p_W, shift_W, r_tool):
    """Return the tool centre's depth in ``surface`` moved by shift, grown by the tool radius."""
    return surface.penetration(p_W - shift_W) + r_tool


@pytest.mark.parametrize('arm', ['paper', 'panda'])
@pytest.mark.parametrize('shape, radius', [('plane', 0.5), ('cylinder', 0.3), ('sphere', 0.5)])
def test_mujoco_press_at_the_surface_point_gives_the_stiffness(arm, shape, radius):
    model, plant, n_W = _mujoco(arm, shape, radius)
    meas = mujoco_press(model, plant, 5.0 * n_W)
    f_n = float(n_W @ meas.f_true_W)
    depth = _offset_depth(plant.surface, meas.p_W, 0.0, R_TOOL)  # the undeflected surface
    print(f'{arm} {shape}: k = {f_n / depth:.1f} N/m')
    assert f_n == pytest.approx(5.0, rel=1e-3)
    assert f_n / depth == pytest.approx(K, rel=0.02)
    assert angle_deg(plant.contact_normal(meas.p_W), n_W) < 0.5


def _hold_aside(model, plant, n_W, t_W, aside, steps=3000):
    """Press 5 N along n_W while a spring (2 kN/m) along t_W holds the tool ``aside`` m away."""
    import pinocchio as pin
    meas = plant.measure()
    x_t = float(t_W @ meas.p_W) + aside
    axes, zero = list(model.task_axes), np.zeros(model.n)
    for _ in range(steps):  # helpers.offline.mujoco_press with the spring along t_W
        kin = model.kinematics(meas.q, meas.qdot)
        J = np.zeros((3, model.n))
        J[axes] = kin.J_ee
        f_W = 5.0 * n_W + 2000.0 * (x_t - float(t_W @ meas.p_W)) * t_W - 30.0 * (J @ meas.qdot)
        tau = pin.rnea(model.model, model.data, meas.q, zero, zero) + J.T @ f_W - 2.0 * meas.qdot
        meas = plant.step(tau, 1e-3)
    return meas


@pytest.mark.parametrize('arm, shape, axis', [
    ('paper', 'cylinder', None), ('paper', 'sphere', None),
    ('panda', 'cylinder', [0.0, 1.0, 0.0]), ('panda', 'sphere', None)])
def test_mujoco_held_aside_the_force_is_along_the_contact_normal(arm, shape, axis):
    """
    Frictionless, held 6 cm aside of the top: the contact force is along the local normal.

    The stiffness along that normal is the mount's (mujoco_scene.py): the contact in series with
    the spring seen at the angle phi from the mount's axis.
    """
    from sim_node.mujoco_scene import CONTACT_STIFFNESS_RATIO, surface_shift
    model, plant, n_W = _mujoco(arm, shape, 0.3, axis)
    t_W = np.array([1.0, 0.0, 0.0])  # across the cylinder's axis (z or y)
    meas = _hold_aside(model, plant, n_W, t_W, 0.06)
    n_c = plant.contact_normal(meas.p_W)
    shift = surface_shift(plant.scene, plant.d)
    phi = math.radians(angle_deg(n_c, n_W))
    print(f'{arm} {shape}: phi {math.degrees(phi):.2f} deg, shift {shift}')
    assert math.sin(phi) == pytest.approx(0.06 / (0.3 + R_TOOL), abs=0.01)
    assert angle_deg(meas.f_true_W, n_c) < 0.05  # along the normal of the moved surface
    np.testing.assert_allclose(n_c, plant.surface.normal_at(meas.p_W - shift), atol=1e-12)
    assert angle_deg(n_c, plant.surface.normal_at(meas.p_W)) < 0.5  # the spring moved it
    k_c = CONTACT_STIFFNESS_RATIO * K
    k_spring = 1.0 / (1.0 / K - 1.0 / k_c)
    k_local = 1.0 / (1.0 / k_c + math.cos(phi) ** 2 / k_spring)
    depth = _offset_depth(plant.surface, meas.p_W, 0.0, R_TOOL)
    assert np.linalg.norm(meas.f_true_W) / depth == pytest.approx(k_local, rel=0.03)


def test_mujoco_radius_changes_at_run_time_and_the_shape_is_refused():
    model, plant, n_W = _mujoco('paper', 'sphere', 0.5)
    s = plant.surface
    plant.surface = make_surface('sphere', K, s.x0_W, n_W, 0.2)
    assert plant.m.geom_size[plant.scene.surface_geom, 0] == 0.2
    meas = _hold_aside(model, plant, n_W, np.array([1.0, 0.0, 0.0]), 0.05)
    n_c = plant.contact_normal(meas.p_W)
    assert angle_deg(n_c, n_W) > 10.0  # the 0.2 m sphere (0.5 m: 5.7 deg)
    assert angle_deg(meas.f_true_W, n_c) < 0.05
    assert angle_deg(n_c, plant.surface.normal_at(meas.p_W)) < 1.0  # the 0.2 m sphere's
    for shape in ('plane', 'cylinder'):
        with pytest.raises(SurfaceError, match='shape is fixed at start-up'):
            plant.surface = make_surface(shape, K, s.x0_W, n_W, 0.3)
        with pytest.raises(SurfaceError, match='restart the sim'):
            plant.check_surface(make_surface(shape, K, s.x0_W, n_W, 0.3))
    assert plant.surface.radius == 0.2
