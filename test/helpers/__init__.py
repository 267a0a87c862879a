"""
The suite's shared helpers; test modules import these, never each other.

* :mod:`helpers.ros`: processes, domains, spinning, waits, freezes, the nodes' module paths,
  /diagnostics statuses as dicts;
* :mod:`helpers.watch`: the watchers of a running cell (true force, /diagnostics, telemetry),
  what a clean run's statuses say, and the real-time rig;
* :mod:`helpers.fault_rig`, :mod:`helpers.fault_cases`: the lockstep fault-injection rig (a
  proxy between sim and controller) and its cases' hooks and checks;
* :mod:`helpers.figures`: angles, and the figures a real-time test hands on (``HFC_FIGURES``);
* :mod:`helpers.offline`: the runtime's loop, plants and synthetic signals of offline tests;
* :mod:`helpers.bags`: synthetic rosbag2 runs for the tools' tests.

Fixtures shared by modules are conftest.py's (``model``, ``fault_rig``, ``healthy``).
"""
