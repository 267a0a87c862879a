"""
Keep DDS on this machine for every test, whatever the caller's environment.

Set before any test module imports rclpy; subprocesses inherit it. Modules that need a
domain of their own set ROS_DOMAIN_ID themselves (or pass domain_id to rclpy.init).
"""
import os
import signal
import tempfile
import warnings

from hybrid_force_controller.ros.programs.launch import use_loopback_dds
import pytest


os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# A shell without job control (a script's `cmd &`) starts the suite with SIGINT ignored, and an
# ignored signal stays ignored across exec: the programs test_shutdown sends Ctrl-C to would
# never see it (three failures and their sims and controllers left running, seen here). A
# handler here is reset to the default in every child the suite starts.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
os.environ.setdefault('ROS_DOMAIN_ID', '42')
# The suite's cells run on ROS_DOMAIN_ID itself (HFC_CELL_DOMAIN_ID=off), as before the gateway:
# their tests inject faults into the 1 kHz topics and count them at the sim, which a plant-side
# tool does on the cell's own domain. test_gateway and test_demo run the default (the cell
# domain behind the gateway) and say so (helpers.ros.ISOLATED).
os.environ['HFC_CELL_DOMAIN_ID'] = 'off'
# The controllers' flight recorder writes under $ROS_HOME (every shutdown whose sim stops first
# looks like a lost input to it): the suite's dumps go to a directory of the run, not ~/.ros
os.environ['ROS_HOME'] = tempfile.mkdtemp(prefix='hfc_suite_ros_home_')
# The test process and the observers it starts (recorders, programs) on UDP loopback, with no
# shared-memory port (config/fastdds_loopback.xml); the sims and controllers keep shared memory
# (helpers.ros.node_env). Fast DDS's port health check stalled the cell 333 ms at random when a
# reader joined it (docs/results.md, section 13), the suite's last flake. A caller's own
# FASTRTPS_DEFAULT_PROFILES_FILE is kept.
use_loopback_dds()

import helpers.ros  # noqa: E402,F401,I100  (fixes the run's base domain before the modules load)
import helpers.witness  # noqa: E402,I100


# The suite runs on two workers (README: ``-n 2 --dist loadgroup``). Modules that start nodes,
# talk DDS or time a real-time loop run one after the other on one worker, as the group 'ros'
# (first, since it is the longest); the offline modules below share the other worker. A module
# not listed here is serial by default: a new real-time test never runs beside another one. An
# offline module's test that starts a node says so with ``@pytest.mark.dds`` (test_any_arm):
# it alone joins the serial group.
OFFLINE_MODULES = {
    'test_analysis', 'test_any_arm', 'test_approach', 'test_bounds_helper', 'test_cdr',
    'test_cell_trial_figures',
    'test_closed_loop_offline', 'test_control_law', 'test_engine',
    'test_filters_env', 'test_flake8', 'test_flight_recorder', 'test_force_target_and_tare',
    'test_fuzz_offline',
    'test_input_plausibility',
    'test_layers', 'test_loop_stats', 'test_margin', 'test_model_construction',
    'test_model_oracle', 'test_moving_normal',
    'test_mujoco_demo_args', 'test_mujoco_plant', 'test_normal_closed_loop',
    'test_normal_estimate', 'test_params', 'test_path', 'test_path_runtime',
    'test_pep257', 'test_pinned_figures', 'test_recovery', 'test_report', 'test_report_normal',
    'test_report_path', 'test_safe_hold', 'test_seated_pad', 'test_singularity', 'test_tick_impl',
    'test_runtime', 'test_runtime_changes', 'test_stalls', 'test_stiffness',
    'test_stiffness_closed_loop', 'test_stiffness_guards', 'test_stiffness_loop',
    'test_stiffness_tools', 'test_surface_shapes', 'test_thread_meter', 'test_tool_gravity',
    'test_tool_identification', 'test_orientation',
}


def pytest_configure(config):
    config.addinivalue_line('markers', 'dds: a test of an offline module that starts nodes or '
                            'talks DDS (it runs in the serial group)')


# Lockstep runs over DDS: the sim owns the time, so what they assert does not depend on the
# wall clock or the machine's load. On two CPUs or more each module is a group of its own that
# the other worker takes, beside the real-time tests, as it takes the offline ones; on one CPU
# they stay in the serial group, as their neighbours' bounds were measured. Each has a domain of
# its own. The demo's lockstep run stays serial: its pins moved once beside the real-time tests
# (s50d, docs/results.md section 27; its sim steps on a wall-clock watchdog when no command
# comes, so its figures are not load-proof).
LOCKSTEP_MODULES = {'test_fault_injection', 'test_fault_inputs', 'test_nodes_closed_loop'}


def _serial(item) -> bool:
    return (item.module.__name__ not in OFFLINE_MODULES
            or item.get_closest_marker('dds') is not None)


def _lockstep(item) -> bool:
    return item.module.__name__ in LOCKSTEP_MODULES


def _group(item) -> str | None:
    """Return the xdist group of ``item``: 'ros', a lockstep group or None (offline)."""
    if not _serial(item):
        return None
    if _lockstep(item) and len(os.sched_getaffinity(0)) > 1:
        return f'lockstep_{item.module.__name__.removeprefix("test_")}'
    return 'ros'


@pytest.hookimpl(tryfirst=True)  # before xdist's worker adds the group to the node ids
def pytest_collection_modifyitems(config, items):
    """Put the serial tests in the group 'ros' and the lockstep ones in theirs, both first."""
    for item in items:
        group = _group(item)
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))
    items.sort(key=lambda item: not _serial(item))  # stable


# On one CPU (``taskset -c 0``, the halved machine) the offline worker yields that CPU to the
# cells of the serial group: it runs at this niceness, as their bounds were measured with the
# cell alone on one CPU. Beside it at the same priority the cell ran at 530 Hz and the force loop
# rang near its delay margin (docs/results.md section 26). Under SCHED_IDLE instead the cells
# stopped for seconds (s49e, section 27; likely a task that hardly ever runs holding what they
# wait for, as a file system's journal). On two CPUs each worker has one and nothing is changed
# (niced there, the offline worker took 50 s longer and the cells 5 s less).
OFFLINE_NICENESS = 10
_BASE_NICENESS = os.getpriority(os.PRIO_PROCESS, 0)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Witness a real-time test's machine; on one CPU, run an offline test niced."""
    if _serial(item) and not _lockstep(item):
        helpers.witness.start_test()
    if len(os.sched_getaffinity(0)) > 1:
        return
    want = _BASE_NICENESS if _serial(item) else max(_BASE_NICENESS, OFFLINE_NICENESS)
    now = os.getpriority(os.PRIO_PROCESS, 0)
    if now != want:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, want)
        except PermissionError:  # back up needs CAP_SYS_NICE: the serial test runs niced
            warnings.warn(f'{item.nodeid} runs at niceness {now}, not {want}: not permitted')


def pytest_runtest_teardown(item):
    """End the real-time test's witnessed window: a later stall is not its own."""
    helpers.witness.end_test()


@pytest.fixture(scope='module')
def model():
    """Give each module the model of the bundled 2-link arm (the paper's)."""
    from hybrid_force_controller.core.model.robot_model import RobotModel
    return RobotModel.from_urdf()


@pytest.fixture(scope='module')
def fault_rig(request, tmp_path_factory):
    """
    Start the lockstep fault-injection rig (helpers.fault_rig) for the module, tracking.

    Its domain is the module's (``domain_id`` of its name without ``test_``).
    """
    from helpers.fault_cases import start_rig
    name = request.module.__name__.removeprefix('test_')
    rig = start_rig(tmp_path_factory.mktemp(name), helpers.ros.domain_id(name))
    try:
        yield rig
    finally:
        rig.close()


@pytest.fixture
def healthy(fault_rig, request):
    """
    Give a case the rig, tracking; after a case that failed, reset it first.

    Nothing is hidden: a case that fails is reported as such, and a rig that is not tracking
    although no case failed fails the next case's set-up (the reset is for a failure already
    reported).
    """
    if fault_rig.broken:
        fault_rig.reset()
    fault_rig.broken = True  # until this case has passed
    # 1 s in the band: a case's strict check (never out of the band after its fault) must
    # not see the end of the last case's recovery
    fault_rig.wait_tracking(3.0, 'before the case', window=1.0, fresh=False)
    failed = request.session.testsfailed
    yield fault_rig
    fault_rig.broken = request.session.testsfailed > failed
