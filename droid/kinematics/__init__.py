"""droid.kinematics — transforms, D-H forward kinematics, analytic IK, gearing (thesis §4.1.1, §4.1.7).

Imports nothing else of droid.  Entry point::

    from droid.kinematics import load_robot
    reis = load_robot("reis_v15")          # or a path to a .toml robot file
    T = reis.fk([0, 10, 20, 0, 45, 0])     # 4x4, mm
    sols = reis.ik_all(T)                  # 8x6 deg, NaN where none
    q = reis.ik(T, q_prev_deg=[0] * 6)     # the planner's pick, or raises Unreachable
"""
from .gearing import Gearing, extend_counter, extend_counters
from .model import RobotModel, Unreachable
from .robots import RobotFileError, list_robots, load_robot

__all__ = [
    "Gearing",
    "RobotFileError",
    "RobotModel",
    "Unreachable",
    "extend_counter",
    "extend_counters",
    "list_robots",
    "load_robot",
]
