"""
The control law of [1] and what shapes its inputs.

References, the approach, the bumpless blends, the stiffness estimate and its loop (all in the
1 kHz tick); the delay margin and set validation (on the node's thread, when a set arrives).
"""
