"""
config/fastdds_loopback.xml, the Fast DDS profile the programs and this suite run with.

* ``use_loopback_dds`` gives the process the shipped profile when the caller chose none, keeps
  the caller's own, and an empty value (Fast DDS's defaults) stays empty; ``cell_env`` (the
  sim's and the controller's environment) drops the profile it chose and keeps the caller's;
* with the profile, two processes exchange data and no shared-memory port of their domain is
  opened (so Fast DDS's port health check, which stalled a publisher 333 ms, cannot run);
  without it, the same two processes open shared-memory ports (the control: the check above
  can fail). docs/results.md, section 13.
"""
from __future__ import annotations

import os
from pathlib import Path
import re
import subprocess
import sys

from helpers.ros import domain_id, node_env, ROOT
from hybrid_force_controller.ros.programs.launch import cell_env, PROFILE_VAR, use_loopback_dds
import pytest

SHM = Path('/dev/shm')
# Fast DDS names a shared-memory port (and its lock files) after its number, the RTPS port of
# the same locator on UDP: 7400 + 250 domain + an offset below 250
PORT_FILE = re.compile(r'fastrtps_port(\d+)')
# a child: 'pub' publishes 100 Hz until killed; 'sub' takes 50 messages, then prints how many
# it took and what /dev/shm holds
CHILD = """
import os, sys, time, rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node('profile_probe_' + sys.argv[1])
if sys.argv[1] == 'pub':
    pub = node.create_publisher(String, 'profile_probe', 10)
    while True:
        pub.publish(String(data='x'))
        time.sleep(0.01)
got = []
node.create_subscription(String, 'profile_probe', got.append, 10)
t0 = time.monotonic()
while len(got) < 50 and time.monotonic() - t0 < 60.0:
    rclpy.spin_once(node, timeout_sec=0.1)
print(len(got))
print(' '.join(os.listdir('/dev/shm')))
"""


def test_use_loopback_dds_keeps_the_callers_choice():
    env: dict[str, str] = {}
    path = use_loopback_dds(env)
    assert env[PROFILE_VAR] == path and Path(path).name == 'fastdds_loopback.xml'
    assert Path(path).is_file()
    own = {PROFILE_VAR: '/etc/my_profile.xml'}
    assert use_loopback_dds(own) == '/etc/my_profile.xml' and own == {
        PROFILE_VAR: '/etc/my_profile.xml'}
    defaults = {PROFILE_VAR: ''}
    assert use_loopback_dds(defaults) is None and defaults == {PROFILE_VAR: ''}
    env['OTHER'] = 'kept'
    assert cell_env(env) == {'OTHER': 'kept'}  # the cell keeps shared memory
    assert cell_env(own) == own and cell_env(defaults) == defaults


def _domain_ports(names: list[str], domain: int) -> list[str]:
    """Return the shared-memory port files among ``names`` that belong to ``domain``."""
    lo = 7400 + 250 * domain
    return sorted(name for name in names
                  if (m := PORT_FILE.search(name)) and lo <= int(m.group(1)) < lo + 250)


def _ports_while_talking(domain: int, profile: str) -> tuple[int, list[str]]:
    """Messages the 'sub' child took, and the shared-memory port files of ``domain`` it saw."""
    for name in _domain_ports(os.listdir(SHM), domain):  # stale ones (a killed run)
        (SHM / name).unlink(missing_ok=True)
    env = node_env(domain)
    env.pop(PROFILE_VAR, None)  # Fast DDS's defaults, whatever the caller or the suite set
    if profile:
        env[PROFILE_VAR] = profile
    pub = subprocess.Popen([sys.executable, '-c', CHILD, 'pub'], env=env, cwd=ROOT,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        out = subprocess.run([sys.executable, '-c', CHILD, 'sub'], env=env, cwd=ROOT,
                             capture_output=True, text=True, timeout=120).stdout.splitlines()
    finally:
        pub.kill()
        pub.wait()
    assert len(out) >= 2, out  # the last two lines (Fast DDS may log before them)
    return int(out[-2]), _domain_ports(out[-1].split(), domain)


@pytest.mark.parametrize('profile', ['loopback', 'none'])
def test_the_loopback_profile_opens_no_shared_memory_port(profile):
    domain = domain_id('dds_profile')
    path = use_loopback_dds({}) if profile == 'loopback' else ''
    taken, ports = _ports_while_talking(domain, path)
    assert taken >= 50, f'{taken} of 50 messages with profile {profile}'
    if profile == 'loopback':
        assert ports == [], ports
    else:  # the control: Fast DDS's defaults put the two processes on shared memory
        assert ports, 'no shared-memory port without the profile'
