"""The cell's collision bodies in the global frame [mm] (issue 41; docs/guard.md).

Every arm's links are the capsules ``droid-kin urdf`` writes (:mod:`droid.kinematics.urdf`):
link *i* a capsule between joint *i*'s origin and joint *i+1*'s (link 6: to the flange), as
thick as :func:`~droid.kinematics.urdf.link_capsule_radii_mm` says; the tool a rod of
:data:`~droid.kinematics.urdf.TOOL_RADIUS_M` from ``tool0`` to the tool point; the sensor a box
of :data:`~droid.kinematics.urdf.SENSOR_BOX_M` at the sensor frame (the mounts of the cell's
world devices, :func:`~droid.kinematics.cli.cell_mounts`).  The base disc of the URDF is not a
body (link 1's capsule stands on the base's axis).  A workpiece held by an arm and the cell's
fixtures are boxes declared in the cell file's ``[guard]`` table.

Joint vectors are DROID's joint variables, in rad for :meth:`ArmChain.points` (the URDF's) and
deg at the :class:`CellBodies` interface (as ``droid-kin fk``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from droid.cli import BadInput
from droid.kinematics.transforms import pose_to_T
from droid.kinematics.urdf import SENSOR_BOX_M, TOOL_RADIUS_M, link_capsule_radii_mm, opw_chain_frames

TOOL_RADIUS_MM = TOOL_RADIUS_M * 1000.0
SENSOR_HALF_MM = tuple(0.5 * 1000.0 * v for v in SENSOR_BOX_M)
FIXTURE = "fixture"  # the owner of a fixture body


class ArmChain:
    """One arm's kinematic chain as the URDF writes it: joint origins and signed axes at q = 0
    (ROS-Industrial style), the flange / tool0 frame of link 6, the base in the cell; and what the
    guard needs of the robot file besides: its joint speed limits ``vmax_deg_s`` (a larger step of
    the measured joints in a tick is a re-zero, not motion: droid.guard.core) and the pose homing
    leaves it at, ``home_deg`` (``home_switch_deg``)."""

    def __init__(self, model, base_T: np.ndarray) -> None:
        frames, axes, tip = opw_chain_frames(model)
        pos = np.array([g[:3, 3] for g in frames])  # (6, 3) joint origins at q = 0 [mm]
        self.offsets = np.diff(np.vstack([np.zeros(3), pos]), axis=0)  # joint i's origin in link i-1's frame
        self.axes = np.array(axes, float)  # (6, 3) unit axes
        self.flange = tip[:3, 3] - pos[5]  # flange / tool0 origin in link 6's frame [mm]
        self.tip_R = tip[:3, :3]  # tool0's axes in link 6's frame
        self.base = np.asarray(base_T, float)
        self.vmax_deg_s = np.asarray(model.vmax_deg_s, float)
        self.home_deg = np.asarray(model.home_switch_deg, float)
        u = self.axes
        self._K = np.zeros((6, 3, 3))
        self._K[:, 0, 1], self._K[:, 0, 2], self._K[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
        self._K[:, 1, 0], self._K[:, 2, 0], self._K[:, 2, 1] = u[:, 2], -u[:, 1], u[:, 0]
        self._KK = self._K @ self._K

    def points(self, q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joint origins 1..6 and the flange (B, 7, 3) [mm, global] and tool0's frames (B, 4, 4) of
        joint vectors (B, 6) [rad]."""
        q = np.asarray(q_rad, float)
        B = q.shape[0]
        s, c = np.sin(q), np.cos(q)
        rot = np.eye(3) + s[:, :, None, None] * self._K + (1.0 - c)[:, :, None, None] * self._KK  # (B, 6, 3, 3)
        R = np.broadcast_to(self.base[:3, :3], (B, 3, 3))
        o = np.broadcast_to(self.base[:3, 3], (B, 3))
        pts = np.empty((B, 7, 3))
        for i in range(6):
            o = o + R @ self.offsets[i]
            pts[:, i] = o
            R = R @ rot[:, i]
        pts[:, 6] = o + R @ self.flange
        tool0 = np.zeros((B, 4, 4))
        tool0[:, :3, :3] = R @ self.tip_R
        tool0[:, :3, 3] = pts[:, 6]
        tool0[:, 3, 3] = 1.0
        return pts, tool0


@dataclass
class Body:
    """A collision body: a capsule (``radius_mm``, ends ``ends`` = indices into its arm's points, or a
    fixed ``segment_mm``) or a box (``T`` 4x4 in its arm's tool0 frame or the global frame, ``half_mm``)."""

    owner: str  # an arm's subunit name, or FIXTURE
    name: str  # link_1 .. link_6, tool, sensor, workpiece, or a fixture's name
    kind: str  # "capsule" | "box"
    radius_mm: float = 0.0
    ends: tuple[int, int] | None = None  # capsule: indices into ArmChain.points (+ 7: the tool point)
    T: np.ndarray | None = None  # box pose (on tool0 for an arm's box, global for a fixture)
    half_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def key(self) -> str:
        return f"{self.owner}.{self.name}"

    def label(self) -> str:
        """``arm1 link 4``, ``arm1 tool``, ``fixture floor``."""
        name = self.name.replace("link_", "link ") if self.name.startswith("link_") else self.name
        return f"{self.owner} {name}"


def arm_bodies(name: str, model, mounts: dict, held: dict | None = None) -> list[Body]:
    """The bodies of one arm: six link capsules, the tool rod and sensor box where mounted, a held box."""
    radii = link_capsule_radii_mm(model)
    out = [Body(name, f"link_{i + 1}", "capsule", radius_mm=radii[i], ends=(i, i + 1)) for i in range(6)]
    if "tool" in mounts:
        out.append(Body(name, "tool", "capsule", radius_mm=TOOL_RADIUS_MM, ends=(6, 7), T=np.asarray(mounts["tool"], float)))
    if "sensor" in mounts:
        out.append(Body(name, "sensor", "box", T=np.asarray(mounts["sensor"], float), half_mm=np.array(SENSOR_HALF_MM)))
    if held is not None:
        out.append(Body(name, held["name"], "box", T=held["T"], half_mm=held["half_mm"]))
    return out


def _box_spec(where: str, table) -> tuple[np.ndarray, np.ndarray]:
    """A ``{ pose = [x, y, z, A, B, C], size_mm = [dx, dy, dz] }`` table -> (4x4, half sizes) [mm]."""
    if not isinstance(table, dict):
        raise BadInput(f"{where}: expected a table {{ pose = [x, y, z, A, B, C], size_mm = [dx, dy, dz] }}")
    unknown = sorted(set(table) - {"pose", "size_mm", "name", "arm", "mount"})
    if unknown:
        raise BadInput(f"{where}: unknown key(s): {', '.join(unknown)}")
    pose, size = table.get("pose", [0.0] * 6), table.get("size_mm")
    if not (isinstance(pose, list) and len(pose) == 6 and all(isinstance(v, (int, float)) for v in pose)):
        raise BadInput(f"{where}: pose: expected [x, y, z, A, B, C] (mm, ZYZ deg)")
    if not (isinstance(size, list) and len(size) == 3 and all(isinstance(v, (int, float)) and v > 0 for v in size)):
        raise BadInput(f"{where}: size_mm: expected [dx, dy, dz] > 0 (mm)")
    return pose_to_T(*[float(v) for v in pose]), 0.5 * np.array(size, float)


def _held_mount(raw: dict, arm: str) -> np.ndarray | None:
    """T_wcp_workpiece of the world devices whose ``holder_robot`` is the arm (or its world device)."""
    devices = (raw.get("world") or {}).get("devices") or {}
    names = {arm} | {n for n, d in devices.items() if isinstance(d, dict) and d.get("subunit") == arm}
    for dname in sorted(devices):
        dev = devices[dname]
        if isinstance(dev, dict) and dev.get("holder_robot") in names and isinstance(dev.get("workpiece_mount"), list):
            return pose_to_T(*[float(v) for v in dev["workpiece_mount"]])
    return None
