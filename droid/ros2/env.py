"""The environment the ROS 2 wheels from PyPI need, set by droid-ros2 itself (docs/ros2.md).

The wheels (``ros-rclpy`` and friends, ROS 2 Kilted) put their shared libraries in the venv's
``lib/`` and ``site-packages/ros_*.libs/``, which the dynamic loader only searches when they are on
``LD_LIBRARY_PATH`` at process start.  Their own ``ros_wheels_bootstrapper.pth`` re-executes every
Python of the venv once with that path set; :func:`ensure_library_path` does the same for
droid-ros2 alone when that did not happen (a bootstrapper-marked environment without the path, a
``python -S``), so a user just runs the program.

:func:`ros_environment` is what the middleware reads at ``rclpy.init``: ``RMW_IMPLEMENTATION``
(``rmw_fastrtps_cpp``, the one middleware the extra installs), ``ROS_DOMAIN_ID`` and
``ROS_AUTOMATIC_DISCOVERY_RANGE`` (``LOCALHOST`` unless ``--subnet``: loopback only by default).
"""
from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

from droid.cli import BadInput

EXTRA_HINT = "pip install 'droid[ros2]'"
RMW_DEFAULT = "rmw_fastrtps_cpp"
DOMAIN_MAX = 232  # ROS 2's largest valid domain id (Fast DDS's port formula; docs.ros.org "ROS_DOMAIN_ID")
_REEXEC_GUARD = "_DROID_ROS2_LD_PATH"  # set when droid-ros2 re-executed itself with the wheels' library path
_BOOTSTRAP_GUARD = "_ROS_WHEELS_BOOTSTRAP_COMPLETE"  # the wheels' own bootstrapper's mark


def installed() -> bool:
    """Whether the extra's Python packages are importable (without loading their C libraries)."""
    return all(importlib.util.find_spec(m) is not None for m in
               ("rclpy", "sensor_msgs", "geometry_msgs", "trajectory_msgs", "std_msgs", "std_srvs",
                "diagnostic_msgs", "visualization_msgs"))


def wheel_library_dirs() -> list[str]:
    """The directories holding the wheels' shared libraries: ``<venv>/lib`` and ``ros_*.libs``."""
    site = Path(sys.prefix) / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    dirs = [str(Path(sys.prefix) / "lib")]
    if site.is_dir():
        dirs += sorted(str(p) for p in site.glob("ros_*.libs") if p.is_dir())
    return dirs


def ensure_library_path(argv: list[str] | None = None) -> None:
    """Re-execute this program once with the wheels' library directories on LD_LIBRARY_PATH when
    they are missing from it (the dynamic loader reads it only at process start)."""
    have = [p for p in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep) if p]
    need = [d for d in wheel_library_dirs() if d not in have]
    if not need or os.environ.get(_REEXEC_GUARD):
        return
    env = dict(os.environ, LD_LIBRARY_PATH=os.pathsep.join(need + have), **{_REEXEC_GUARD: "1", _BOOTSTRAP_GUARD: "1"})
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, list(sys.orig_argv if argv is None else argv), env)


def check_domain(domain: int) -> int:
    if not 0 <= domain <= DOMAIN_MAX:
        raise BadInput(f"--domain must be in [0, {DOMAIN_MAX}] (ROS_DOMAIN_ID), got {domain}")
    return domain


def ros_environment(domain: int, subnet: bool = False, environ=os.environ) -> dict[str, str]:
    """Set (in ``environ``) and return what the middleware reads at ``rclpy.init``."""
    vals = {"ROS_DOMAIN_ID": str(check_domain(domain)),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET" if subnet else "LOCALHOST",
            "RMW_IMPLEMENTATION": environ.get("RMW_IMPLEMENTATION") or RMW_DEFAULT}
    if not subnet:
        environ.pop("ROS_STATIC_PEERS", None)  # loopback only: no peer on another host either
    environ.update(vals)
    return vals


def import_rclpy():
    """``rclpy``, or BadInput (exit 2) naming the extra when it is not installed."""
    if not installed():
        raise BadInput(f"the ROS 2 Python packages are not installed: {EXTRA_HINT}")
    try:
        import rclpy
    except ImportError as exc:  # installed, but its C libraries do not load
        raise BadInput(f"rclpy is installed but does not load ({str(exc).splitlines()[0]}): "
                       f"reinstall with {EXTRA_HINT}") from None
    return rclpy
