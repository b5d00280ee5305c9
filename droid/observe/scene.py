"""Frames and geometry of the cell from its Status records (thesis §5.1-5.2, eq. 4.1-4.2).

:class:`SceneBuilder` turns one snapshot of Status records (JSON dicts, as a
recording stores them) into what a viewer draws:

* every arm's link frames: the cumulative D-H A-matrices (eq. 4.1) of the
  joint angles its Status ``encoder_pos`` [counts] gives through the robot's
  gearing, on its base from the cell file;
* the wrist-centre pose (the Status x, y, z, R, Table 3.1), the tool point and
  the lead sensor's measuring point (``(Reis)6 T tool`` / ``T sensor`` of the
  seam-tracking layout), the workpiece frame W (``global T (GMF1)6 (GMF1)6 T W``);
* the laser line (the stripe across the lead sensor's frame at the depth it
  reads) and the seam map: the global points of the valid lead-sensor
  readings so far (x depth, y lateral in the sensor frame, docs/mvs.md).

The geometry comes from the recording's metadata (:func:`scene_meta`), so a
file carries what it needs.  All lengths in mm.
"""
from __future__ import annotations

import math

import numpy as np

from droid.kinematics import load_robot
from droid.kinematics.dh import link_matrix
from droid.kinematics.transforms import pose_to_T
from droid.observe.mcapfile import stamp

LASER_HALF_MM = 30.0  # half length of the drawn laser stripe [mm]
SEAM_STEP_MM = 1.0  # a new seam-map point when the reading moved at least this far [mm]
SEAM_MAX_POINTS = 20000
WORKPIECE_BOX_MM = (400.0, 200.0, 10.0)  # schematic plate drawn at W: length along x_W, width, thickness


def scene_meta(cell, layout_path=None) -> dict:
    """Geometry for the scene: tool/holder/sensor subunits, the wrist transforms and the workpiece mount
    (from the seam-tracking layout, and the cell's world table where it names a mount)."""
    from droid.tasks.seam.layout import load_layout

    try:
        lay = load_layout(layout_path)
    except Exception:  # noqa: BLE001 -- a scene is optional: no layout, no tool/sensor frames
        return {}
    wrist = lay.wrist("standard")
    mount = lay.mount("default") if "default" in lay.mounts else next(iter(lay.mounts.values()))
    for dev in (cell.world.get("devices") or {}).values():
        if isinstance(dev, dict) and "workpiece_mount" in dev:
            mount = pose_to_T(*[float(v) for v in dev["workpiece_mount"]])
    return {"tool_robot": lay.tool_robot, "holder_robot": lay.holder_robot, "sensor": lay.sensor,
            "T_wcp_tool": wrist.T_wcp_tool.tolist(), "T_wcp_sensor": wrist.T_wcp_sensor.tolist(),
            "T_wcp_workpiece": np.asarray(mount).tolist()}


def is_arm(sub: dict) -> bool:
    """A recorded subunit is an arm if it has a Command database (or a robot model): read from the
    recording's metadata, not from a list of classes."""
    return "command" in (sub.get("areas") or {}) or bool(sub.get("robot")) or sub.get("class") == "arm6r"


def status_T(d: dict) -> np.ndarray:
    """A Status dict's pose as a 4x4 [mm]."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(d["R"], float)
    T[:3, 3] = (d["x"], d["y"], d["z"])
    return T


def quat(R) -> dict:
    """Unit quaternion {x, y, z, w} of a rotation matrix."""
    m = np.asarray(R, float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    return {"x": x, "y": y, "z": z, "w": w}


M_PER_MM = 1e-3  # Foxglove's schemas are in metres; everything else here is in mm


def _vec(p, scale: float = M_PER_MM) -> dict:
    """A foxglove Vector3/Point3 [m] of a point [mm]."""
    return {"x": float(p[0]) * scale, "y": float(p[1]) * scale, "z": float(p[2]) * scale}


class SceneBuilder:
    """Frames, link frames, laser line and seam map from Status snapshots (see the module docstring)."""

    def __init__(self, subunits: list[dict], scene: dict) -> None:
        self.arms = {}
        for s in subunits:
            if is_arm(s):
                try:
                    model = load_robot(s["robot"]) if s.get("robot") else None
                except Exception:  # noqa: BLE001 -- an unknown robot file: draw its wrist centre only
                    model = None
                self.arms[s["name"]] = (model, pose_to_T(*s.get("base", [0.0] * 6)))
        self.scene = scene or {}
        g = self.scene
        self.T_wcp_tool = np.asarray(g["T_wcp_tool"]) if "T_wcp_tool" in g else None
        self.T_wcp_sensor = np.asarray(g["T_wcp_sensor"]) if "T_wcp_sensor" in g else None
        self.T_wcp_W = np.asarray(g["T_wcp_workpiece"]) if "T_wcp_workpiece" in g else None
        self.seam: list[list[float]] = []

    def reset_seam(self) -> None:
        self.seam = []

    def link_frames(self, name: str, d: dict) -> list[np.ndarray]:
        """Base and the six link frames (4x4, mm, global) of arm ``name`` from its Status dict."""
        model, base = self.arms[name]
        frames = [base]
        if model is None or model.dh is None:
            frames.append(status_T(d))
            return frames
        q = model.gearing.counts_to_joints(np.asarray(d["encoder_pos"], float))
        t = base
        dh = model.dh
        for i in range(6):
            t = t @ link_matrix(math.radians(float(q[i]) + dh.theta_offset_deg[i]), dh.d_mm[i], dh.a_mm[i],
                                math.radians(dh.alpha_deg[i]))
            frames.append(t)
        return frames

    def step(self, statuses: dict[str, dict]) -> dict:
        """Geometry of one snapshot: ``{"frames": {name: 4x4}, "links": {arm: [[x,y,z]...]},
        "laser": [[x,y,z],[x,y,z]] | None, "seam": [[x,y,z]...]}``; extends the seam map."""
        frames: dict[str, np.ndarray] = {}
        links: dict[str, list] = {}
        for name, (model, base) in self.arms.items():
            d = statuses.get(name)
            frames[f"{name}/base"] = base
            if d is None:
                continue
            frames[f"{name}/wcp"] = status_T(d)
            try:
                links[name] = [f[:3, 3].tolist() for f in self.link_frames(name, d)]
            except (ValueError, KeyError):
                links[name] = [base[:3, 3].tolist(), status_T(d)[:3, 3].tolist()]
        g = self.scene
        tool_wcp = frames.get(f"{g.get('tool_robot')}/wcp")
        hold_wcp = frames.get(f"{g.get('holder_robot')}/wcp")
        laser = None
        if tool_wcp is not None and self.T_wcp_tool is not None:
            frames["tool"] = tool_wcp @ self.T_wcp_tool
        if tool_wcp is not None and self.T_wcp_sensor is not None:
            S = tool_wcp @ self.T_wcp_sensor
            frames["sensor"] = S
            lead = statuses.get(g.get("sensor"))
            valid = lead is not None and not lead.get("stale") and not lead.get("homed")
            depth = float(lead["x"]) if valid else 0.0
            laser = [(S @ [depth, -LASER_HALF_MM, 0.0, 1.0])[:3].tolist(),
                     (S @ [depth, LASER_HALF_MM, 0.0, 1.0])[:3].tolist()]
            if valid:
                p = (S @ [float(lead["x"]), float(lead["y"]), 0.0, 1.0])[:3]
                if not self.seam or np.linalg.norm(p - self.seam[-1]) >= SEAM_STEP_MM:
                    if len(self.seam) < SEAM_MAX_POINTS:
                        self.seam.append(p.tolist())
        if hold_wcp is not None and self.T_wcp_W is not None:
            frames["workpiece"] = hold_wcp @ self.T_wcp_W
        return {"frames": frames, "links": links, "laser": laser, "seam": self.seam}

    # -- Foxglove messages ---------------------------------------------------------
    @staticmethod
    def frame_transforms(frames: dict[str, np.ndarray], t_ns: int) -> dict:
        """foxglove.FrameTransforms: every frame a child of ``world`` (translations in m, as Foxglove expects)."""
        ts = stamp(t_ns)
        return {"transforms": [{"timestamp": ts, "parent_frame_id": "world", "child_frame_id": name,
                                "translation": _vec(T[:3, 3]), "rotation": quat(T[:3, :3])}
                               for name, T in frames.items()]}

    def scene_update(self, geo: dict, t_ns: int) -> dict:
        """foxglove.SceneUpdate: the workpiece plate (in frame ``workpiece``), the seam map and the laser line
        (lengths in m, as Foxglove expects)."""
        ts = stamp(t_ns)
        ident = {"position": _vec((0, 0, 0)), "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}}
        ents = []
        if "workpiece" in geo["frames"]:
            lx, wy, tz = WORKPIECE_BOX_MM
            ents.append({"timestamp": ts, "frame_id": "workpiece", "id": "workpiece", "lifetime": stamp(0),
                         "frame_locked": True,
                         "cubes": [{"pose": {"position": _vec((lx / 2, 0, -tz / 2)), "orientation": ident["orientation"]},
                                    "size": _vec((lx, wy, tz)), "color": {"r": 0.6, "g": 0.6, "b": 0.65, "a": 0.8}}],
                         "lines": []})
        lines = []
        if geo["seam"]:
            lines.append({"type": 0, "pose": ident, "thickness": 2.0, "scale_invariant": True,
                          "points": [_vec(p) for p in geo["seam"]], "color": {"r": 1, "g": 0.8, "b": 0, "a": 1},
                          "colors": [], "indices": []})
        if geo["laser"]:
            lines.append({"type": 0, "pose": ident, "thickness": 2.0, "scale_invariant": True,
                          "points": [_vec(p) for p in geo["laser"]], "color": {"r": 1, "g": 0, "b": 0, "a": 1},
                          "colors": [], "indices": []})
        if lines:
            ents.append({"timestamp": ts, "frame_id": "world", "id": "seam", "lifetime": stamp(0),
                         "frame_locked": False, "cubes": [], "lines": lines})
        return {"deletions": [], "entities": ents}
