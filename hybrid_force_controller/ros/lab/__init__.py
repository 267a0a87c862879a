"""
The lab's instruments, not what a user runs on a robot (that is ``ros/programs/``).

Benches (``bench``, ``physics_bench``, ``multi_arm``, the ``bare_node`` yardstick, ``load``),
fault and input injection (``injector``, ``run_faults``, ``wrong_inputs``, ``join_stall``,
``wipe_trials``) and what they measure with (``tracking``, ``cell_processes``). They import
the user's programs (to start a cell as ``demo`` does); the programs never import them.
"""
