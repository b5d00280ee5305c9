"""What droid-web shows, as plain JSON: one :class:`ViewBuilder` for a live cell and a recording.

A *snapshot* is one tick of the cell::

    {"tick": 1234, "t_ns": ..., "subunits": {name: {tick, class, homed, busy, mode, stale, fault,
     cmd_result, cmd_id, x, y, z, valid}}, "health": {...}, "plots": {"tool_lateral_mm": ..,
     "tool_height_mm": .., "lead_lateral_mm": .., "lead_depth_mm": .., "speed_mm_s": ..},
     "geo": {"links": {arm: [[x,y,z] x 7]}, "frames": {name: 16 numbers, row-major 4x4},
             "bodies": {arm | "torch" | "bracket" | "fixture": [[x0,y0,z0,x1,y1,z1,r], ...]},
             "forces": [{"subunit", "at": [x,y,z], "force_N": [3], "torque_Nm": [3]}],
             "laser": [[x,y,z],[x,y,z]] | null, "laser_src": [x,y,z] | null,
             "tool": [x,y,z] | null, "seam_n": N},
     "guard": {"state": "off" | "clear" | "slowing" | "stopped", "why": str | null, "tick",
               "distance_mm", "pair": [{"arm", "body"}, {"arm", "body"}], "points": [[x,y,z], [x,y,z]] | null,
               "override": {arm: 0..1}, "closing_mm_s", "separation_mm", "trips", "stale"}}

(mm; droid/observe/scene.py).  What does not change over a run -- the workpiece's surfaces
(``scene.workpiece_mesh`` of the recording's metadata) -- is served once, by ``/api/cell``.

``guard`` is the collision guard's Status (``/guard/status``; docs/guard.md §7a): the least
distance [mm] between the arms' bodies, the closest pair and its two closest points (the page
draws the line between them), the guard's state and its speed override per arm.  A cell without
a ``[guard]`` table, one with ``run = false`` (no droid-guard writes the record) or a record not
yet written says ``off`` and why -- never zeros.

The seam map is sent apart (``seam``: the points so far), since it only grows.
Tracking errors are the tool-tip sensor's reading (thesis §6.1: the seam's
lateral and height deviation from the tool point) and the lead sensor's; the
speed is the tool point's [mm/s] over the ticks between snapshots.
"""
from __future__ import annotations

import math

import numpy as np

from droid.brain.db.layouts import CMD_MODE_NAMES, GUARD_STATE_NAMES
from droid.brain.db.layouts import fault_names
from droid.observe.scene import SceneBuilder, is_arm

CMD_RESULT_NAMES = {0: "ok", 1: "failed", 2: "refused"}
#: the collision guard's record among a snapshot's Status dicts (droid.observe.sampler.GUARD)
GUARD = "guard"


def _finite(v, nd: int = 3):
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return round(f, nd) if math.isfinite(f) else None


def _split(key: str) -> dict:
    arm, _, body = key.partition(".")
    return {"arm": arm, "body": body}


def guard_off(why: str) -> dict:
    return {"state": "off", "why": why, "tick": None, "distance_mm": None, "pair": None, "points": None,
            "override": {}, "closing_mm_s": None, "separation_mm": None, "trips": None, "stale": False}


def guard_view(meta_guard: dict | None, d: dict | None, newest_tick: int = 0) -> dict:
    """What the viewers show of the guard (the module docstring): ``meta_guard`` the recording's
    ``guard`` metadata (:func:`droid.observe.mcapfile.guard_meta`; None in a recording made
    before it), ``d`` the guard's Status dict (None: no record), ``newest_tick`` the newest
    subunit tick of the snapshot (a guard record older than its ``stale_ticks``: ``stale``)."""
    if meta_guard is not None and not meta_guard.get("declared"):
        return guard_off("no [guard] table in the cell: no collision guard")
    if meta_guard is not None and not meta_guard.get("run"):
        return guard_off("[guard] run = false: no droid-guard runs (docs/guard.md §9)")
    if d is None:
        return guard_off("no guard Status in the cell" if meta_guard is None else "no guard Status record")
    tick = int(d.get("tick", 0) or 0)
    if tick == 0:
        return guard_off("droid-guard has not written its Status (not running yet)")
    n = int(d.get("n_arms", 0) or 0)
    arms, over = list(d.get("arms") or [])[:n], list(d.get("override") or [])[:n]
    pair = None
    if d.get("a_arm"):
        pair = [{"arm": d.get("a_arm", ""), "body": d.get("a_body", "")},
                {"arm": d.get("b_arm", ""), "body": d.get("b_body", "")}]
    points = None
    a, b = d.get("a_point_mm"), d.get("b_point_mm")
    if pair is not None and a is not None and b is not None:
        pa, pb = [_finite(c, 2) for c in a], [_finite(c, 2) for c in b]
        if None not in pa and None not in pb and len(pa) == len(pb) == 3:
            points = [pa, pb]
    stale_ticks = int(d.get("stale_ticks", 0) or 0)
    return {"state": GUARD_STATE_NAMES.get(int(d.get("state", 0)), str(d.get("state"))), "why": None, "tick": tick,
            "distance_mm": _finite(d.get("distance_mm")), "pair": pair, "points": points,
            "override": {str(k): _finite(v) for k, v in zip(arms, over)},
            "closing_mm_s": _finite(d.get("closing_mm_s"), 1), "separation_mm": _finite(d.get("separation_mm")),
            "trips": int(d.get("trips", 0) or 0),
            "stale": bool(stale_ticks and newest_tick - tick > stale_ticks)}


def subunit_view(sub: dict, d: dict) -> dict:
    """The status fields the page's table shows for one subunit (``sub``: its recording metadata)."""
    cls = sub.get("class", "?")
    v = {"tick": int(d.get("tick", 0)), "class": cls, "homed": int(d.get("homed", 0)), "busy": int(d.get("busy", 0)),
         "mode": CMD_MODE_NAMES.get(int(d.get("cmd_mode", -1)), str(d.get("cmd_mode"))),
         "stale": bool(d.get("stale", 0)), "fault": fault_names(int(d.get("fault", 0))),
         "cmd_result": CMD_RESULT_NAMES.get(int(d.get("cmd_result", 0)), str(d.get("cmd_result"))),
         "cmd_id": int(d.get("cmd_id", 0)),
         "x": round(float(d.get("x", 0.0)), 3), "y": round(float(d.get("y", 0.0)), 3),
         "z": round(float(d.get("z", 0.0)), 3)}
    v["arm"] = is_arm(sub)
    if not v["arm"]:
        v["valid"] = not d.get("homed") and not d.get("stale")
    return v


class ViewBuilder:
    """Status dicts per tick -> snapshots (see the module docstring)."""

    def __init__(self, meta: dict) -> None:
        self.meta = meta
        self.subs = {s["name"]: s for s in meta.get("subunits", [])}
        self.scene = SceneBuilder(meta.get("subunits", []), meta.get("scene", {}))
        g = meta.get("scene", {})
        self.lead_name = g.get("sensor")
        self.tool_name = "tool" if "tool" in self.subs else None
        self.hz = float(meta.get("heartbeat_hz", 60.0))
        self._last_tool: tuple[int, np.ndarray] | None = None

    def snapshot(self, tick: int, t_ns: int, statuses: dict[str, dict], health: dict | None = None) -> dict:
        guard = None
        if GUARD not in self.subs:  # the collision guard's record is no subunit (a subunit may not be named so)
            statuses = dict(statuses)
            guard = statuses.pop(GUARD, None)
        geo = self.scene.step(statuses)
        subs = {n: subunit_view(self.subs.get(n, {}), d) for n, d in statuses.items()}
        tool_T = geo["frames"].get("tool")
        speed = None
        if tool_T is not None:
            p = tool_T[:3, 3]
            if self._last_tool is not None and tick > self._last_tool[0]:
                speed = float(np.linalg.norm(p - self._last_tool[1]) * self.hz / (tick - self._last_tool[0]))
            if self._last_tool is None or tick != self._last_tool[0]:
                self._last_tool = (tick, p.copy())
        plots = {"speed_mm_s": speed}
        for name, pre, xk in ((self.tool_name, "tool", "height"), (self.lead_name, "lead", "depth")):
            d = statuses.get(name) if name else None
            ok = d is not None and not d.get("homed") and not d.get("stale")
            plots[f"{pre}_lateral_mm"] = float(d["y"]) if ok else None
            plots[f"{pre}_{xk}_mm"] = float(d["x"]) if ok else None
        frames = {k: [round(float(v), 4) for v in T.reshape(-1)] for k, T in geo["frames"].items()}
        return {"tick": int(tick), "t_ns": int(t_ns), "subunits": subs, "health": health or {},
                "plots": {k: (None if v is None or not math.isfinite(v) else round(v, 4)) for k, v in plots.items()},
                "geo": {"links": {k: [[round(c, 3) for c in p] for p in pts] for k, pts in geo["links"].items()},
                        "bodies": geo["bodies"], "forces": geo["forces"],
                        "laser_src": None if geo["laser_src"] is None else [round(c, 2) for c in geo["laser_src"]],
                        "frames": frames, "laser": geo["laser"],
                        "tool": None if tool_T is None else tool_T[:3, 3].round(3).tolist(),
                        "seam_n": len(geo["seam"])},
                "guard": guard_view(self.meta.get("guard"), guard,
                                    max((int(d.get("tick", 0)) for d in statuses.values()), default=0))}

    @property
    def seam(self) -> list:
        return self.scene.seam
