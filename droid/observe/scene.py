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
  readings so far (x depth, y lateral in the sensor frame, docs/mvs.md);
* the bodies to draw (issue 29): every arm's links as capsules between its
  joint origins (:func:`arm_bodies`), each as thick as the robot file says
  (:func:`link_radii_mm`), the torch and the sensor's bracket on the tool
  arm's wrist, the fixture from the holder's wrist to the workpiece frame;
* a force arrow at the tool for every subunit whose Status has ``force_N``
  (a force/torque sensor, keyed on the field names, not on a class).

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
BODY_RADIUS_MM = (20.0, 400.0)  # a link's drawn radius is kept within these [mm]
BODY_FALLBACK_FRACTION = 0.08  # no [dynamics] in the robot file: radius = this x its longest D-H length
BODY_MIN_LENGTH_MM = 1.0  # shorter D-H offsets are not drawn as a capsule
TORCH_RADIUS_MM = 14.0  # the welding torch, drawn from the wrist centre to the tool point [mm]
BRACKET_RADIUS_MM = 10.0  # the sensor's bracket, from the wrist centre to the sensor head [mm]
FIXTURE_RADIUS_MM = 25.0  # the holder's fixture: from its wrist centre to a post under the workpiece [mm]
FIXTURE_DEPTH_MM = 60.0  # the post's length below the seam's middle (-z_W) [mm]
SENSOR_STANDOFF_MM = 150.0  # the lead sensor's head is this far behind its measuring point (-x_S; docs/mvs.md)


def link_radii_mm(model) -> np.ndarray:
    """Drawn radius [mm] of each of the six links, from the robot file.

    With a ``[dynamics]`` table: the radius of the uniform solid cylinder of the link's mass whose
    axial moment is the link's smallest principal moment of inertia, r = sqrt(2 I_min / m) (the files
    size their inertias as such cylinders, e.g. reis_v15's upper arm: a rod of r 0.1 m).  Without
    one: :data:`BODY_FALLBACK_FRACTION` of the longest D-H length.  Kept within :data:`BODY_RADIUS_MM`."""
    lo, hi = BODY_RADIUS_MM
    dyn = getattr(model, "dynamics", None)
    if dyn is not None:
        r = []
        for m, inertia in zip(dyn.link_mass_kg, dyn.link_inertia_kgm2):
            i_min = float(np.min(np.linalg.eigvalsh(np.asarray(inertia, float))))
            r.append(1000.0 * math.sqrt(2.0 * max(i_min, 0.0) / float(m)) if m > 0 else lo)
        return np.clip(np.asarray(r), lo, hi)
    dh = model.dh
    longest = max(max(abs(float(v)) for v in dh.d_mm), max(abs(float(v)) for v in dh.a_mm))
    return np.full(6, float(np.clip(BODY_FALLBACK_FRACTION * longest, lo, hi)))


def arm_bodies(frames: list, d_mm, radii_mm) -> list[list[float]]:
    """Capsules ``[x0, y0, z0, x1, y1, z1, r]`` [mm] of one arm from its base and six D-H link frames.

    A_k = Rz(theta) Tz(d_k) Tx(a_k) Rx(alpha) (eq. 4.1): the offset d_k along z_{k-1} is rigid with
    link k-1 (the base for k = 1, drawn with link 1's radius: the column it turns on), a_k along x_k
    with link k.  So each link is a capsule from frame k-1's origin along z_{k-1} and one along x_k
    to frame k's origin, each as thick as its link; a link with no length (the wrist's) is a ball
    (a capsule of length 0) at its frame's origin.  Link 6 (flange and payload) is left out: the
    payload is drawn from the cell's mounts (tool, sensor, workpiece)."""
    out: list[list[float]] = []

    def cap(p0, p1, r):
        out.append([round(float(v), 1) for v in (*p0, *p1)] + [round(float(r), 1)])

    for k in range(1, 7):
        o0, o1 = frames[k - 1][:3, 3], frames[k][:3, 3]
        mid = o0 + float(d_mm[k - 1]) * frames[k - 1][:3, 2]
        if abs(float(d_mm[k - 1])) >= BODY_MIN_LENGTH_MM:
            cap(o0, mid, radii_mm[max(k - 2, 0)])
        if k == 6:
            break
        if np.linalg.norm(o1 - mid) >= BODY_MIN_LENGTH_MM:
            cap(mid, o1, radii_mm[k - 1])
        elif abs(float(d_mm[k - 1])) < BODY_MIN_LENGTH_MM:
            cap(o1, o1, radii_mm[k - 1])
    return out


def live_workpiece_mesh(cell) -> dict | None:
    """The workpiece's shape a running simulated cell's world published in its run directory
    (``workpiece_mesh.json``: plain data, droid.sim.mvs.devices.publish_workpiece_mesh), or None
    (no such file: a real cell, or a cell not up; a file that is not a mesh is ignored)."""
    import json

    from droid.brain.cell.cellfile import WORKPIECE_MESH_FILE

    try:
        with open(cell.run_dir / WORKPIECE_MESH_FILE) as f:
            mesh = json.load(f)
    except (OSError, ValueError):
        return None
    if not (isinstance(mesh, dict) and isinstance(mesh.get("points"), list)
            and isinstance(mesh.get("sections"), int) and isinstance(mesh.get("per_section"), int)):
        return None
    return mesh


def scene_meta(cell, layout_path=None) -> dict:
    """Geometry for the scene: tool/holder/sensor subunits, the wrist transforms and the workpiece mount
    (from the seam-tracking layout, and the cell's world devices where they name one: ``tool_pose``,
    ``sensor_pose``, ``workpiece_mount``), and the workpiece's name (``workpiece``).

    The workpiece's shape (``workpiece_mesh``, :mod:`droid.sim.workpiece_mesh`) is not here: an
    observer cannot read the simulator's workpiece model (docs/design.md §7).  A recording whose maker may
    (a lockstep trial) carries it in its scene metadata."""
    from droid.brain.cell.cell_layout import layout_for_cell

    try:
        lay = layout_for_cell(cell, layout_path)
    except Exception:  # noqa: BLE001 -- a scene is optional: no layout, no tool/sensor frames
        return {}
    wrist = lay.wrist("standard")
    mount = lay.mount("default") if "default" in lay.mounts else next(iter(lay.mounts.values()))
    T_tool, T_sensor, workpiece = wrist.T_wcp_tool, wrist.T_wcp_sensor, None
    for dev in (cell.world.get("devices") or {}).values():
        if not isinstance(dev, dict):
            continue
        try:  # the cell's own mounts, where its world devices name them (T_wcp_*: x y z mm, ZYZ deg)
            if "workpiece_mount" in dev:
                mount = pose_to_T(*[float(v) for v in dev["workpiece_mount"]])
            if "tool_pose" in dev:
                T_tool = pose_to_T(*[float(v) for v in dev["tool_pose"]])
            if "sensor_pose" in dev:
                T_sensor = pose_to_T(*[float(v) for v in dev["sensor_pose"]])
        except (TypeError, ValueError):
            continue
        if isinstance(dev.get("workpiece"), str):
            workpiece = dev["workpiece"]
    out = {"tool_robot": lay.tool_robot, "holder_robot": lay.holder_robot, "sensor": lay.sensor,
           "T_wcp_tool": np.asarray(T_tool).tolist(), "T_wcp_sensor": np.asarray(T_sensor).tolist(),
           "T_wcp_workpiece": np.asarray(mount).tolist()}
    if workpiece is not None:
        out["workpiece"] = workpiece
    return out


def _capsule(p0, p1, r: float) -> list[float]:
    return [round(float(v), 1) for v in (*p0, *p1)] + [float(r)]


def is_arm(sub: dict) -> bool:
    """A recorded subunit is an arm if it has a Command database (or a robot model): read from the
    recording's metadata, not from a list of classes."""
    from droid.brain.cell.registry import classes

    cls = classes().get(sub.get("class"))  # a class of the device registry: kinematic or not
    if cls is not None:  # (a force/torque sensor has a Command too: bias, guard)
        return cls.kinematic or bool(sub.get("robot"))
    return "command" in (sub.get("areas") or {}) or bool(sub.get("robot"))


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
        self.radii: dict[str, np.ndarray] = {}
        for s in subunits:
            if is_arm(s):
                try:
                    model = load_robot(s["robot"]) if s.get("robot") else None
                except Exception:  # noqa: BLE001 -- an unknown robot file: draw its wrist centre only
                    model = None
                self.arms[s["name"]] = (model, pose_to_T(*s.get("base", [0.0] * 6)))
                if model is not None and model.dh is not None:
                    self.radii[s["name"]] = link_radii_mm(model)
        self.scene = scene or {}
        g = self.scene
        self.T_wcp_tool = np.asarray(g["T_wcp_tool"]) if "T_wcp_tool" in g else None
        self.T_wcp_sensor = np.asarray(g["T_wcp_sensor"]) if "T_wcp_sensor" in g else None
        self.T_wcp_W = np.asarray(g["T_wcp_workpiece"]) if "T_wcp_workpiece" in g else None
        self.seam: list[list[float]] = []
        # where the fixture holds the workpiece: under the middle of its seam (or plate) [mm, in W]
        mesh = g.get("workpiece_mesh") or {}
        try:
            k = (mesh["sections"] // 2) * mesh["per_section"] + 1  # the foot of the middle section
            self.W_centre = np.asarray(mesh["points"][3 * k: 3 * k + 3], float).reshape(3)
        except (KeyError, TypeError, ValueError):
            self.W_centre = np.array([WORKPIECE_BOX_MM[0] / 2, 0.0, 0.0])

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
        "bodies": {name: [[x0,y0,z0,x1,y1,z1,r]...]}, "laser": [[x,y,z],[x,y,z]] | None,
        "laser_src": [x,y,z] | None, "forces": [...], "seam": [[x,y,z]...]}``; extends the seam map.

        ``bodies``: every arm's links (:func:`arm_bodies`), ``torch`` (tool arm's wrist centre to
        the tool point), ``bracket`` (wrist centre to the lead sensor's head), ``fixture`` (holder's
        wrist centre to a post under the middle of the seam).  ``forces``: :meth:`forces`."""
        frames: dict[str, np.ndarray] = {}
        links: dict[str, list] = {}
        bodies: dict[str, list] = {}
        for name, (model, base) in self.arms.items():
            d = statuses.get(name)
            frames[f"{name}/base"] = base
            if d is None:
                continue
            frames[f"{name}/wcp"] = status_T(d)
            try:
                lf = self.link_frames(name, d)
                links[name] = [f[:3, 3].tolist() for f in lf]
                if name in self.radii and len(lf) == 7:
                    bodies[name] = arm_bodies(lf, model.dh.d_mm, self.radii[name])
            except (ValueError, KeyError):
                links[name] = [base[:3, 3].tolist(), status_T(d)[:3, 3].tolist()]
        g = self.scene
        tool_wcp = frames.get(f"{g.get('tool_robot')}/wcp")
        hold_wcp = frames.get(f"{g.get('holder_robot')}/wcp")
        laser = None
        laser_src = None
        if tool_wcp is not None and self.T_wcp_tool is not None:
            frames["tool"] = tool_wcp @ self.T_wcp_tool
            bodies["torch"] = [_capsule(tool_wcp[:3, 3], frames["tool"][:3, 3], TORCH_RADIUS_MM)]
        if tool_wcp is not None and self.T_wcp_sensor is not None:
            S = tool_wcp @ self.T_wcp_sensor
            frames["sensor"] = S
            lead = statuses.get(g.get("sensor"))
            valid = lead is not None and not lead.get("stale") and not lead.get("homed")
            depth = float(lead["x"]) if valid else 0.0
            laser = [(S @ [depth, -LASER_HALF_MM, 0.0, 1.0])[:3].tolist(),
                     (S @ [depth, LASER_HALF_MM, 0.0, 1.0])[:3].tolist()]
            laser_src = (S @ [-SENSOR_STANDOFF_MM, 0.0, 0.0, 1.0])[:3]
            bodies["bracket"] = [_capsule(tool_wcp[:3, 3], laser_src, BRACKET_RADIUS_MM)]
            if valid:
                p = (S @ [float(lead["x"]), float(lead["y"]), 0.0, 1.0])[:3]
                if not self.seam or np.linalg.norm(p - self.seam[-1]) >= SEAM_STEP_MM:
                    if len(self.seam) < SEAM_MAX_POINTS:
                        self.seam.append(p.tolist())
        if hold_wcp is not None and self.T_wcp_W is not None:
            frames["workpiece"] = hold_wcp @ self.T_wcp_W
            W = frames["workpiece"]
            under = W @ np.append(self.W_centre + [0.0, 0.0, -FIXTURE_RADIUS_MM], 1.0)  # its ball under the surface
            post = W @ np.append(self.W_centre + [0.0, 0.0, -FIXTURE_DEPTH_MM], 1.0)
            bodies["fixture"] = [_capsule(hold_wcp[:3, 3], post[:3], FIXTURE_RADIUS_MM),
                                 _capsule(post[:3], under[:3], FIXTURE_RADIUS_MM)]
        return {"frames": frames, "links": links, "bodies": bodies, "laser": laser,
                "laser_src": None if laser_src is None else laser_src.tolist(),
                "forces": self.forces(statuses, frames), "seam": self.seam}

    def forces(self, statuses: dict[str, dict], frames: dict[str, np.ndarray]) -> list[dict]:
        """A force arrow for every fresh Status with ``force_N`` [3] (and ``torque_Nm`` [3]): a
        force/torque sensor, whatever its class.  Its readings are taken in the tool arm's wrist
        (flange) axes, the Status R of ``<tool_robot>/wcp`` (a sensor at the flange), and drawn at the
        tool point (else at that wrist centre): ``{"subunit", "at" [mm], "force_N", "torque_Nm"}``
        with the vectors in the global frame."""
        out = []
        wcp = frames.get(f"{self.scene.get('tool_robot')}/wcp")
        at = frames.get("tool", wcp)
        for name, d in statuses.items():
            f = d.get("force_N")
            if f is None or d.get("stale") or at is None:
                continue
            try:
                fv = np.asarray(f, float).reshape(3)
                tv = np.asarray(d.get("torque_Nm", (0.0, 0.0, 0.0)), float).reshape(3)
            except ValueError:
                continue
            if not (np.all(np.isfinite(fv)) and np.all(np.isfinite(tv))):
                continue
            R = wcp[:3, :3]
            out.append({"subunit": name, "at": [round(float(v), 1) for v in at[:3, 3]],
                        "force_N": [round(float(v), 3) for v in R @ fv],
                        "torque_Nm": [round(float(v), 4) for v in R @ tv]})
        return out

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
