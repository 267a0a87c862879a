"""
The suite's shared helpers; test modules import these, never each other.

* :mod:`helpers.ros`: processes, domains, spinning, waits, freezes, /diagnostics;
* :mod:`helpers.fault_rig`: the lockstep fault-injection rig (a proxy between sim and controller).
"""
