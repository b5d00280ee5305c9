"""DROID — a Distributed Robot of Intelligent Devices, in Python.

Re-creation of the system described in the thesis *A Distributed Robot of Intelligent
Devices (DROID)* (University of Waterloo):
a Brain holding a Status/Command database per subunit in POSIX shared memory,
a 60 Hz heartbeat over ZeroMQ, subunit agents, device drivers and task programs.

Import direction (docs/design.md §7): kinematics <- brain <- subunits; tasks use brain,
kinematics and observe; observe reads brain; sim uses subunits, brain and kinematics;
experiments sits on top; nothing outside sim and experiments imports sim.
"""

import os as _os

# One BLAS thread (issue 28).  DROID's matrices are 3x3 to 6x6 and its programs are many small
# processes: OpenBLAS's default, a thread per core, bought nothing but an 8 MB stack and a
# buffer per thread in every program.  Set here, before any DROID module imports numpy, so
# programs started by hand get it too; a value the user set wins.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
