"""
Parameter handling of the controller node through the parameter services (real DDS).

The node runs in-process with its own context and domain; the tests talk to it with
:class:`rclpy.parameter_client.AsyncParameterClient`, which is what ``ros2 param set`` uses.
"""
import math
from pathlib import Path

from helpers.ros import domain_id, Spun, wait_for, wait_future
from hybrid_force_controller.ros.controller.controller_node import ControllerNode
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from sim_node.sim_node import SimNode


DOMAIN_ID = domain_id('nodes_params')
TIMEOUT = 30.0
PARAMS_FILE = Path(__file__).resolve().parents[1] / 'config' / 'params.yaml'


def _running(make_nodes, args=None) -> Spun:
    """Nodes made by ``make_nodes(context)``, spun by a background executor (helpers.ros.Spun)."""
    spun = Spun(DOMAIN_ID, args)
    for node in make_nodes(spun.context):
        spun.add(node)
    return spun


@pytest.fixture(scope='module')
def controller():
    bundled = [Parameter('use_bundled_model', value=True)]
    running = _running(lambda ctx: [ControllerNode(context=ctx, parameter_overrides=bundled),
                                    Node('param_tester', context=ctx)])
    node, tester = running.nodes
    client = AsyncParameterClient(tester, 'hybrid_force_controller')
    assert client.wait_for_services(timeout_sec=TIMEOUT)
    yield node, client
    running.close()


def _get(client, name):
    return parameter_value_to_python(wait_future(client.get_parameters([name])).values[0])


def _set(client, **values):
    """Set each value on its own, like ``ros2 param set``; one result per value."""
    params = [Parameter(k, value=v) for k, v in values.items()]
    return wait_future(client.set_parameters(params)).results


def test_integer_is_accepted_as_double(controller):
    node, client = controller
    (result,) = _set(client, f_d=2)
    assert result.successful, result.reason
    value = _get(client, 'f_d')
    assert isinstance(value, float) and value == 2.0
    assert node.params.law.f_d == 2.0
    assert _set(client, f_d=1.0)[0].successful


def test_the_singularity_guard_is_set_live_and_off_with_an_integer_zero(controller):
    """``ros2 param set ... singular_sigma 0`` (an integer) turns the damped inverse off."""
    node, client = controller
    assert _get(client, 'singular_sigma') == 0.1
    (result,) = _set(client, singular_sigma=0)
    assert result.successful, result.reason
    assert node.params.law.singular_sigma == 0.0
    wait_for(lambda: node.runtime.ctrl.gains.singular_sigma == 0.0,  # installed at a tick
             'the law in use to have singular_sigma 0', timeout=TIMEOUT)
    assert _set(client, singular_sigma=0.1)[0].successful
    assert node.params.law.singular_sigma == 0.1


def test_the_spins_damping_is_set_live_with_an_integer(controller):
    """``ros2 param set ... orientation_k_d_spin 1`` (an integer) sets the spin's damping."""
    node, client = controller
    assert _get(client, 'orientation_k_d_spin') == 0.3
    (result,) = _set(client, orientation_k_d_spin=1)
    assert result.successful, result.reason
    assert node.params.orientation.k_w == (3.0, 1.0)  # (the tilt's, the spin's)
    assert _set(client, orientation_k_d_spin=0.3)[0].successful


def test_integer_normal_is_normalised(controller):
    node, client = controller
    (result,) = _set(client, n=[0, 2, 0])
    assert result.successful, result.reason
    assert list(_get(client, 'n')) == [0.0, 1.0, 0.0]
    np.testing.assert_array_equal(node.params.law.n, [0.0, 1.0, 0.0])
    assert _set(client, n=[0.0, -1.0, 0.0])[0].successful


def test_unstable_gains_are_rejected_with_both_sides_of_eq_29(controller):
    node, client = controller
    (result,) = _set(client, lambda1=10.0)
    assert not result.successful
    assert '100' in result.reason and '1200' in result.reason, result.reason
    assert _get(client, 'lambda1') == 40.0
    assert node.params.law.lambda1 == 40.0


@pytest.mark.parametrize('name, value', [
    ('gamma', [70.0, -1.0]),
    ('n', [0.0, 1.0]),
    ('n', [0.0, 0.0, 0.0]),
    ('n', [0.0, math.nan, 0.0]),
    ('k_d', -5.0),
    ('singular_sigma', -0.1),
    ('singular_sigma', math.inf),
    ('rate_hz', 500.0),
    ('orientation_k_d_spin', -0.3),
    ('tick_impl', 'python'),  # read-only: chosen at configure, never switched under a tick
])
def test_bad_value_is_rejected_and_nothing_changes(controller, name, value):
    node, client = controller
    before = _get(client, name)
    params_before = node.params
    (result,) = _set(client, **{name: value})
    assert not result.successful
    assert result.reason
    assert list(np.atleast_1d(_get(client, name))) == list(np.atleast_1d(before))
    assert node.params is params_before


def test_the_node_ticks_compiled_by_default(controller):
    """tick_impl compiled: the numba kernels were loaded at configure (tick_impl.py)."""
    node, client = controller
    assert _get(client, 'tick_impl') == 'compiled'
    assert node.runtime.ctrl.tick_note.startswith('tick_impl compiled: numba kernels')


def test_atomic_multi_set_with_one_bad_value_changes_nothing(controller):
    node, client = controller
    params_before = node.params
    bad = [Parameter('f_d', value=3.0), Parameter('lambda1', value=50.0),
           Parameter('k_d', value=-1.0)]
    result = wait_future(client.set_parameters_atomically(bad)).result
    assert not result.successful and result.reason
    assert (_get(client, 'f_d'), _get(client, 'lambda1'), _get(client, 'k_d')) == (
        1.0, 40.0, 60.0)
    assert node.params is params_before


def test_atomic_multi_set_is_validated_as_a_whole(controller):
    node, client = controller
    # lambda1 = 20 alone violates eq. (29) (400 <= 1200); with lambda2 = 0.01 it holds (400 > 120)
    good = [Parameter('lambda1', value=20), Parameter('lambda2', value=0.01)]
    result = wait_future(client.set_parameters_atomically(good)).result
    assert result.successful, result.reason
    assert (node.params.law.lambda1, node.params.law.lambda2) == (20.0, 0.01)
    restore = [Parameter('lambda2', value=0.1), Parameter('lambda1', value=40.0)]
    assert wait_future(client.set_parameters_atomically(restore)).result.successful


def test_params_file_configures_both_nodes():
    args = ['--ros-args', '--params-file', str(PARAMS_FILE), '-p', 'f_d:=3']
    running = _running(lambda ctx: [ControllerNode(context=ctx), SimNode(context=ctx)], args)
    try:
        controller, sim = running.nodes
        p = controller.params.law
        assert (p.lambda1, p.lambda2, p.k_d, p.k_a, p.k_max, p.k_s, p.f_d) == (
            40.0, 0.1, 60.0, 1500.0, 6000.0, 6000.0, 3.0)
        np.testing.assert_array_equal(np.diag(p.Gamma), [70.0, 70.0])
        np.testing.assert_array_equal(p.n, [0.0, -1.0, 0.0])
        assert sim.sim.surface.k == 1700.0
        # the start pose (the arm itself may already move: the controller runs)
        np.testing.assert_allclose(sim.get_parameter('q0').value, [0.657, 0.913])
        assert sim.get_parameter('stiffness').value == 1700.0
    finally:
        running.close()


def test_bool_array_is_refused_with_a_reason(controller):
    node, client = controller
    params_before = node.params
    (result,) = _set(client, n=[True, False, False])
    assert not result.successful and 'booleans' in result.reason, result.reason
    assert node.params is params_before


def test_bool_array_at_start_up_is_refused():
    running = _running(lambda ctx: [], ['--ros-args', '-p', 'n:=[true, false, false]'])
    try:
        with pytest.raises(ValueError, match='n must be an array of numbers, got booleans'):
            ControllerNode(context=running.context, parameter_overrides=[
                Parameter('use_bundled_model', value=True)])
    finally:
        running.close()


def test_empty_arrays_at_start_up_mean_default(tmp_path):
    """``-p NAME:=[]`` and ``NAME: []`` in a params file (what ros2 param dump writes)."""
    params = tmp_path / 'empty.yaml'
    params.write_text('hybrid_force_controller:\n  ros__parameters:\n'
                      '    use_bundled_model: true\n    theta_min: []\n    theta_hat0: []\n')
    args = ['--ros-args', '--params-file', str(params), '-p', 'effort_limits:=[]']
    running = _running(lambda ctx: [ControllerNode(context=ctx)], args)
    try:
        (node,) = running.nodes
        np.testing.assert_array_equal(node.params.runtime.effort_limits, [100.0, 100.0])
        np.testing.assert_array_equal(node.params.law.theta_min, [0.0, 0.0])
        assert list(node.get_parameter('effort_limits').value) == []
    finally:
        running.close()


def test_dump_and_reload(controller, tmp_path):
    """
    Dump every parameter as ``ros2 param dump`` does; the dump starts an identical node.

    With a sensor offset that a tare stored (``wrench_offset``): the restart keeps it.
    """
    import yaml
    node, client = controller
    tared = [0.8, -2.5, 0.4]
    result = wait_future(client.set_parameters([Parameter('wrench_offset', value=tared)]))
    assert result.results[0].successful, result.results[0].reason
    names = wait_future(client.list_parameters()).result.names
    values = wait_future(client.get_parameters(names)).values
    dumped = {n: parameter_value_to_python(v) for n, v in zip(names, values)}
    dumped = {n: (list(v) if isinstance(v, (list, tuple)) or hasattr(v, 'tolist') else v)
              for n, v in dumped.items()}
    dumped = {n: ([float(x) for x in v] if n in ('gamma', 'n', 'gravity') else v)
              for n, v in dumped.items()}
    assert dumped['effort_limits'] == [] and dumped['theta_min'] == []
    path = tmp_path / 'dump.yaml'
    path.write_text(yaml.safe_dump({'/hybrid_force_controller': {'ros__parameters': dumped}}))
    running = _running(lambda ctx: [ControllerNode(context=ctx)],
                       ['--ros-args', '--params-file', str(path)])
    try:
        (reloaded,) = running.nodes
        a, b = node.params, reloaded.params
        for group, field in (('law', 'f_d'), ('law', 'lambda1'), ('law', 'lambda2'),
                             ('law', 'k_d'), ('runtime', 'joints')):
            assert getattr(getattr(a, group), field) == getattr(getattr(b, group), field), field
        for group, field in (('runtime', 'effort_limits'), ('law', 'theta_min'),
                             ('law', 'theta_max'), ('law', 'n'), ('law', 'Gamma'),
                             ('runtime', 'wrench_offset')):
            np.testing.assert_array_equal(getattr(getattr(a, group), field),
                                          getattr(getattr(b, group), field))
        np.testing.assert_array_equal(b.runtime.wrench_offset, tared)
    finally:
        running.close()
        wait_future(client.set_parameters([Parameter('wrench_offset', value=[])]))


def test_the_sim_plant_impl_is_read_at_start_and_refused_at_run_time():
    """``plant_impl:=python`` runs pinocchio's plant; a run-time set or a bad value is refused."""
    running = _running(lambda ctx: [
        SimNode(context=ctx, parameter_overrides=[Parameter('plant_impl', value='python')]),
        Node('param_tester', context=ctx)])
    try:
        sim, tester = running.nodes
        client = AsyncParameterClient(tester, 'sim')
        assert client.wait_for_services(timeout_sec=TIMEOUT)
        assert _get(client, 'plant_impl') == 'python' and sim.sim.impl == 'python'
        (result,) = _set(client, plant_impl='compiled')
        assert not result.successful and result.reason
        assert _get(client, 'plant_impl') == 'python' and sim.sim.impl == 'python'
        with pytest.raises(ValueError, match='plant_impl must be one of'):
            SimNode(context=running.context,
                    parameter_overrides=[Parameter('plant_impl', value='fast')])
    finally:
        running.close()
