"""The controller parameter schema and build_params (pure Python + numpy)."""
from __future__ import annotations

import math
import re

from hybrid_force_controller.core.config.groups import NormalConfig, OrientationConfig
from hybrid_force_controller.core.config.params import (build_params, CONTROLLER_SCHEMA,
                                                        ControllerParams, LawGains,
                                                        ParameterValidationError, RuntimeConfig,
                                                        schema_defaults)
from hybrid_force_controller.core.config.schema import ORIENTATION_FIELDS
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.runtime.recovery import RecoveryConfig
import numpy as np
import pytest


DOUBLES = [s.name for s in CONTROLLER_SCHEMA if s.kind == 'double']


def build(model: RobotModel, values: dict) -> ControllerParams:
    return build_params(model, values)


def rejects(model: RobotModel, values: dict, name: str) -> str:
    """Assert ``values`` is rejected with a message naming the parameter ``name``."""
    with pytest.raises(ParameterValidationError) as exc:
        build(model, values)
    msg = str(exc.value)
    assert re.search(rf'(?<![\w]){re.escape(name)}(?![\w])', msg), msg
    return msg


# ---------------------------------------------------------------- schema
def test_schema_names_are_unique_and_match_the_dataclasses():
    names = [s.name for s in CONTROLLER_SCHEMA]
    assert len(names) == len(set(names))
    assert set(ControllerParams.__dataclass_fields__) == {'law', 'runtime', 'stiffness',
                                                          'recovery', 'normal', 'orientation'}
    law = {s.name for s in CONTROLLER_SCHEMA if s.group == 'law'}
    runtime = {s.name for s in CONTROLLER_SCHEMA if s.group == 'runtime'}
    recovery = {s.name for s in CONTROLLER_SCHEMA if s.group == 'recovery'}
    assert law - {'gamma'} == set(LawGains.__dataclass_fields__) - {'Gamma'}
    assert runtime == set(RuntimeConfig.__dataclass_fields__)
    assert recovery - {'episode_recovery'} | {'enabled'} == set(
        RecoveryConfig.__dataclass_fields__)
    normal = {s.name for s in CONTROLLER_SCHEMA if s.group == 'normal'}
    assert {n.removeprefix('n_') for n in normal - {'n_estimation'}} | {'enabled'} == set(
        NormalConfig.__dataclass_fields__)
    orientation = {s.name for s in CONTROLLER_SCHEMA if s.group == 'orientation'}
    assert {ORIENTATION_FIELDS[n] for n in orientation} == set(
        OrientationConfig.__dataclass_fields__)


@pytest.mark.parametrize('spec', CONTROLLER_SCHEMA, ids=lambda s: s.name)
def test_every_spec_has_a_description_and_a_valid_default(model, spec):
    assert isinstance(spec.description, str) and spec.description.strip()
    assert spec.kind in ('double', 'integer', 'double_array', 'string_array', 'string', 'bool')
    if spec.kind == 'double':
        assert isinstance(spec.default, float)
        assert spec.lo is None or spec.default >= spec.lo
        assert spec.hi is None or spec.default <= spec.hi
        assert not spec.positive or spec.default > 0
    build(model, {spec.name: spec.default})  # the default alone validates


def test_all_defaults_validate(model):
    p = build(model, schema_defaults())
    assert p.runtime.joints == ('joint1', 'joint2')
    np.testing.assert_array_equal(p.law.theta_hat0, model.theta_nominal)
    np.testing.assert_array_equal(p.law.Gamma, 70.0 * np.eye(2))
    np.testing.assert_array_equal(p.runtime.effort_limits, model.effort_limits)
    np.testing.assert_array_equal(p.law.theta_min, [0.0, 0.0])
    np.testing.assert_allclose(p.law.theta_max, 10 * model.theta_nominal)


# ---------------------------------------------------------------- accepted and normalised
def test_integers_are_accepted_for_doubles(model):
    p = build(model, {'f_d': 2, 'lambda1': 50, 'k_d': 300})
    assert p.law.f_d == 2.0 and isinstance(p.law.f_d, float)
    assert p.law.lambda1 == 50.0 and p.law.k_d == 300.0


def test_normal_is_normalised(model):
    p = build(model, {'n': [0, 2, 0]})
    np.testing.assert_allclose(p.law.n, [0.0, 1.0, 0.0])
    p = build(model, {'n': [3.0, -4.0, 0.0]})
    np.testing.assert_allclose(p.law.n, [0.6, -0.8, 0.0])


def test_scalar_gamma_is_times_identity(model):
    p = build(model, {'gamma': [3.0]})
    np.testing.assert_array_equal(p.law.Gamma, 3.0 * np.eye(2))


def test_full_gamma_matrix_is_accepted(model):
    p = build(model, {'gamma': [2.0, 0.5, 0.5, 1.0]})
    np.testing.assert_array_equal(p.law.Gamma, [[2.0, 0.5], [0.5, 1.0]])


def test_build_params_applies_overrides_and_defaults_joints_to_the_model(model):
    p = build_params(model, {'lambda1': 45.0})
    assert p.law.lambda1 == 45.0 and p.runtime.joints == model.joint_names


@pytest.mark.parametrize('name', ['theta_min', 'theta_max', 'effort_limits', 'theta_hat0'])
@pytest.mark.parametrize('empty', [None, []])
def test_empty_array_means_default(model, name, empty):
    """What ``ros2 param dump`` writes for these defaults reloads to the defaults."""
    default = build(model, {})
    p = build(model, {name: empty})
    group = 'runtime' if name == 'effort_limits' else 'law'
    np.testing.assert_array_equal(getattr(getattr(p, group), name),
                                  getattr(getattr(default, group), name))


@pytest.mark.parametrize('name,value', [('n', [True, False, False]), ('gamma', [True]),
                                        ('effort_limits', [1.0, True])])
def test_bool_arrays_rejected(model, name, value):
    msg = rejects(model, {name: value}, name)
    assert 'numbers' in msg


@pytest.mark.parametrize('value', [1, 0.0, 'true', None])
def test_bool_parameter_needs_a_bool(model, value):
    msg = rejects(model, {'reject_frozen_wrench': value}, 'reject_frozen_wrench')
    assert 'true or false' in msg


# ---------------------------------------------------------------- rejected
@pytest.mark.parametrize('value', ['abc', None, [40.0], True])
def test_wrong_type_rejected(model, value):
    msg = rejects(model, {'lambda1': value}, 'lambda1')
    assert 'number' in msg


@pytest.mark.parametrize('name', DOUBLES)
@pytest.mark.parametrize('bad', [math.nan, math.inf])
def test_non_finite_double_rejected(model, name, bad):
    msg = rejects(model, {name: bad}, name)
    assert 'finite' in msg


@pytest.mark.parametrize('name', ['lambda1', 'lambda2', 'k_d', 'k_max', 'k_s'])
@pytest.mark.parametrize('bad', [0.0, -1.0])
def test_non_positive_gains_rejected(model, name, bad):
    rejects(model, {name: bad}, name)


@pytest.mark.parametrize('name,bad', [
    ('rate_hz', 0.5), ('rate_hz', 2e4), ('f_d', -0.1), ('f_d', 1e4), ('lambda1', 2e4),
    ('ref_blend_time', 61.0), ('state_timeout', 11.0), ('max_effort_rate', -1.0),
    ('force_filter_hz', -1.0), ('ref_omega', -1.0), ('k_s', 2e8),
])
def test_out_of_range_rejected(model, name, bad):
    msg = rejects(model, {name: bad}, name)
    assert 'outside' in msg


def test_unstable_gains_rejected(model):
    msg = rejects(model, {'lambda1': 10.0}, 'lambda1')
    assert '100' in msg and '1200' in msg


@pytest.mark.parametrize('gamma,why', [
    ([1.0, 2.0, 3.0, 4.0], 'symmetric'),
    ([1.0, -1.0], 'positive definite'),
    ([1.0, 2.0, 2.0, 1.0], 'positive definite'),
    ([0.0, 1.0], 'positive definite'),
    ([1.0, 2.0, 3.0], 'elements'),
    ([], 'elements'),
    ([1.0, math.nan], 'finite'),
    ('abc', 'array'),
])
def test_bad_gamma_rejected(model, gamma, why):
    msg = rejects(model, {'gamma': gamma}, 'gamma')
    assert why in msg


@pytest.mark.parametrize('n,why', [
    ([0.0, 0.0, 0.0], 'zero'),
    ([0.0, -1.0], 'elements'),
    ([0.0, -1.0, 0.0, 0.0], 'elements'),
    ([0.0, math.nan, 0.0], 'finite'),
    ([0.0, 0.0, 1.0], 'task space'),
    ([0.0, -1.0, 0.1], 'task space'),
])
def test_bad_normal_rejected(model, n, why):
    msg = rejects(model, {'n': n}, 'n')
    assert why in msg


@pytest.mark.parametrize('joints', [['joint1'], ['joint1', 'joint2', 'joint3'], []])
def test_wrong_number_of_joints_rejected(model, joints):
    rejects(model, {'joints': joints}, 'joints')


def test_duplicate_joints_rejected(model):
    msg = rejects(model, {'joints': ['joint1', 'joint1']}, 'joints')
    assert 'distinct' in msg


@pytest.mark.parametrize('values', [
    {'theta_hat0': [20.0, 0.9]},                                  # above 10 x nominal
    {'theta_hat0': [-0.1, 0.9]},                                  # below 0
    {'theta_hat0': [1.0, 1.0], 'theta_min': [1.1, 0.0]},
    {'theta_hat0': [1.0, 1.0], 'theta_max': [2.0, 0.9]},
])
def test_theta_hat0_outside_bounds_rejected(model, values):
    rejects(model, values, 'theta_hat0')


def test_theta_hat0_wrong_length_rejected(model):
    rejects(model, {'theta_hat0': [1.0, 1.0, 1.0]}, 'theta_hat0')


@pytest.mark.parametrize('limits', [[100.0], [100.0, 0.0], [100.0, -5.0]])
def test_bad_effort_limits_rejected(model, limits):
    rejects(model, {'effort_limits': limits}, 'effort_limits')


def test_unknown_parameter_rejected(model):
    msg = rejects(model, {'lamda1': 40.0}, 'lamda1')
    assert 'unknown' in msg


def test_rejection_leaves_no_partial_result(model):
    """A failing set raises; a following valid set is unaffected (no shared state)."""
    with pytest.raises(ParameterValidationError):
        build(model, {'lambda1': 'abc'})
    assert build(model, {}).law.lambda1 == 40.0
