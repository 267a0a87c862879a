"""
The 1 kHz runtime around the law.

Inputs and their checks, modes, recovery episodes, contact, effort limits, loop statistics.
"""
