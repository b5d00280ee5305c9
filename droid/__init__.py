"""DROID — a Distributed Robot of Intelligent Devices, in Python.

Re-creation of the system described in the thesis (../shared/seed/droid-thesis.txt):
a Brain holding a Status/Command database per subunit in POSIX shared memory,
a 60 Hz heartbeat over ZeroMQ, subunit agents, device drivers and task programs.

Import direction (DESIGN §7): kinematics <- brain <- subunits; tasks use brain and
kinematics only; sim may use everything and nothing outside sim imports it.
"""

__version__ = "0.1.0"
