"""
Shared by every node of the package (the controller, the sim, the programs).

CDR messages, QoS, running a node, parameter declaration, node parameters, meters.
"""
