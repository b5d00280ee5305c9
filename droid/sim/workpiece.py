"""Workpieces as data: a lap-joint seam of lines and arcs (thesis §6.1.1).

A workpiece file (``droid/sim/workpieces/NAME.toml``, or any path) describes
the seam in the workpiece frame W (mm).  The seam lies in W's x-y plane, the
surface normal is +z_W, and the seam starts at the W origin heading +x_W
unless ``[start]`` says otherwise.  The seam is the *foot* of a lap-joint step:

* the lower surface is the plane z_W = 0 on one side of the seam, out to
  ``width_mm`` from it;
* the upper surface is the plane z_W = ``step_mm`` on the other side (the
  ``upper_side``, "left" = +lateral, the side on the left of the direction of
  travel), also out to ``width_mm``; its edge above the seam is a square,
  vertical wall of height ``step_mm``;
* anywhere else (|lateral| > width, before ``-lead_in_mm`` or after
  ``length_mm + lead_out_mm`` along the seam) there is no surface and the
  laser makes no stripe.

Lateral distance is signed: + to the left of the travel direction.  The
arc-length coordinate s [mm] runs from 0 at the start; before the start and
after the end the seam is extended along its end tangents, so ``nearest`` and
``point_at`` answer everywhere.

Issue 15 extends the format (docs/workpieces.md): ``rise_mm`` on lines and
arcs (helices), ``type = "curve"`` segments (``points_mm`` or ``csv``,
``interpolation``), ``roll_profile``, ``step_profile``, ``[[gap]]`` and
``[[tack]]``.  A file with none of them is the plane model below, exactly as
before (``planar``); one with any of them is a 3-D seam
(:class:`droid.sim.seam3d.Seam3D`, ``Workpiece.seam``), which the camera twin,
the tool-tip and the ideal sensors render.

File format (see docs/mvs.md)::

    name = "step_input"                  # optional, defaults to the file stem
    description = "..."                  # optional
    step_mm = 2.0                        # height of the upper surface, > 0
    width_mm = 50.0                      # each surface's width from the seam, > 0
    upper_side = "left"                  # or "right"
    lead_in_mm = 10.0                    # surface before s = 0, >= 0
    lead_out_mm = 10.0                   # surface after the end, >= 0
    [start]                              # optional
    x_mm = 0.0
    y_mm = 0.0
    heading_deg = 0.0
    [[segment]]
    type = "line"                        # straight: length_mm > 0
    length_mm = 100.0
    [[segment]]
    type = "turn"                        # instantaneous change of direction
    angle_deg = 5.0                      # + = left (counter-clockwise about +z_W)
    [[segment]]
    type = "arc"                         # circular arc: radius_mm > width_mm
    radius_mm = 200.0
    angle_deg = 90.0                     # + = left turn, - = right turn
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from droid.cli import BadInput, read_toml
from droid.numbers import NumberError, check_numbers, finite_numbers

WORKPIECE_DIR = Path(__file__).parent / "workpieces"

#: Length [mm] of the virtual straight extensions before the start and after the end.
EXTENSION_MM = 1.0e6

_TOP_KEYS = {
    "name", "description", "step_mm", "width_mm", "upper_side",
    "lead_in_mm", "lead_out_mm", "start", "segment",
    "roll_profile", "step_profile", "gap", "tack", "contact",
}
_START_KEYS = {"x_mm", "y_mm", "heading_deg"}
_SEGMENT_KEYS = {
    "line": {"type", "length_mm", "rise_mm"},
    "arc": {"type", "radius_mm", "angle_deg", "rise_mm"},
    "turn": {"type", "angle_deg"},
    "curve": {"type", "points_mm", "csv", "interpolation"},
}
_GAP_KEYS = {"s_mm", "length_mm"}
_TACK_KEYS = {"s_mm", "length_mm", "height_mm"}
#: Largest |roll| [deg] a roll_profile may give.
MAX_ROLL_DEG = 80.0


@dataclass(frozen=True)
class Segment:
    """One piece of the seam: a straight line or a circular arc.

    ``sweep_rad`` is 0 for a line, signed for an arc (+ = left turn).
    """

    s0_mm: float
    length_mm: float
    start_xy: tuple[float, float]
    heading0_rad: float
    radius_mm: float = math.inf
    sweep_rad: float = 0.0

    def __post_init__(self) -> None:
        # constants of project(), once per segment: the heading as a unit vector, the start
        # point, the arc's centre (the same arithmetic as before, only not repeated per call)
        h = np.array([math.cos(self.heading0_rad), math.sin(self.heading0_rad)])
        object.__setattr__(self, "_h", h)
        object.__setattr__(self, "_start", np.asarray(self.start_xy))
        if self.sweep_rad != 0.0:
            object.__setattr__(self, "_c", self._center())

    @property
    def is_arc(self) -> bool:
        return self.sweep_rad != 0.0

    def _turn_sign(self) -> float:
        return 1.0 if self.sweep_rad > 0 else -1.0

    def _center(self) -> np.ndarray:
        left = np.array([-math.sin(self.heading0_rad), math.cos(self.heading0_rad)])
        return np.asarray(self.start_xy) + self._turn_sign() * self.radius_mm * left

    def at(self, s_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points (N, 2) and headings (N,) [rad] at arc lengths s (extrapolates a line)."""
        u = np.asarray(s_mm, float) - self.s0_mm
        if not self.is_arc:
            h = np.array([math.cos(self.heading0_rad), math.sin(self.heading0_rad)])
            return np.asarray(self.start_xy) + u[:, None] * h, np.full(u.shape, self.heading0_rad)
        sign = self._turn_sign()
        heading = self.heading0_rad + sign * u / self.radius_mm
        radial = heading - sign * math.pi / 2  # direction from the centre to the point
        pts = self._center() + self.radius_mm * np.stack([np.cos(radial), np.sin(radial)], axis=1)
        return pts, heading

    def end(self) -> tuple[np.ndarray, float]:
        """End point (2,) and heading [rad]."""
        pts, heading = self.at(np.array([self.s0_mm + self.length_mm]))
        return pts[0], float(heading[0])

    def project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest point on this segment for (N, 2) points.

        Returns (distance [mm], s [mm], signed lateral [mm], + = left).
        """
        if self.sweep_rad == 0.0:
            h = self._h
            d = xy - self._start
            t = np.minimum(np.maximum(d @ h, 0.0), self.length_mm)  # np.clip, without its overhead
            off = d - t[:, None] * h
            dist = np.hypot(off[:, 0], off[:, 1])
            cross = h[0] * d[:, 1] - h[1] * d[:, 0]
            return dist, self.s0_mm + t, np.copysign(dist, cross)
        sign = self._turn_sign()
        v = xy - self._c
        r = np.hypot(v[:, 0], v[:, 1])
        start_radial = self.heading0_rad - sign * math.pi / 2
        delta = np.mod(sign * (np.arctan2(v[:, 1], v[:, 0]) - start_radial), 2 * math.pi)
        sweep = abs(self.sweep_rad)
        on_arc = delta <= sweep
        dist = np.abs(r - self.radius_mm)
        s = self.s0_mm + self.radius_mm * np.minimum(delta, sweep)
        lateral = sign * (self.radius_mm - r)
        if not on_arc.all():
            # Off the arc's angular span: the nearer end point is nearest.
            ends = []
            for s_end in (self.s0_mm, self.s0_mm + self.length_mm):
                p, hd = self.at(np.array([s_end]))
                off = xy - p[0]
                de = np.hypot(off[:, 0], off[:, 1])
                cross = math.cos(hd[0]) * off[:, 1] - math.sin(hd[0]) * off[:, 0]
                ends.append((de, np.full(len(xy), s_end), np.copysign(de, cross)))
            use_start = ends[0][0] <= ends[1][0]
            for k, arr in enumerate((dist, s, lateral)):
                alt = np.where(use_start, ends[0][k], ends[1][k])
                arr[~on_arc] = alt[~on_arc]
        return dist, s, lateral


@dataclass(frozen=True)
class Workpiece:
    """A lap-joint seam with its two surfaces (see the module docstring)."""

    name: str
    segments: tuple[Segment, ...]
    step_mm: float = 2.0
    width_mm: float = 50.0
    upper_side: str = "left"
    lead_in_mm: float = 0.0
    lead_out_mm: float = 0.0
    description: str = ""
    source: str = "<dict>"
    #: the 3-D seam (droid.sim.seam3d) of a workpiece the plane model cannot hold (``planar`` False);
    #: None: built from ``segments`` when asked for (:attr:`seam`)
    seam3d: object = field(default=None, repr=False, compare=False)
    planar: bool = True
    roll_profile: tuple = ()  # ((s_mm, roll_deg), ...) as in the file
    step_profile: tuple = ()  # ((s_mm, step_mm), ...)
    gaps: tuple = ()  # ((s_mm, length_mm), ...)
    tacks: tuple = ()  # ((s_mm, length_mm, height_mm), ...)
    #: the ``[contact]`` table (droid.sim.contact.ContactParams), or None: no contact model
    contact: object = None
    _all: tuple[Segment, ...] = field(default=(), repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.planar:
            return
        first, last = self.segments[0], self.segments[-1]
        h0 = np.array([math.cos(first.heading0_rad), math.sin(first.heading0_rad)])
        before = Segment(-EXTENSION_MM, EXTENSION_MM,
                         tuple(np.asarray(first.start_xy) - EXTENSION_MM * h0), first.heading0_rad)
        end_xy, end_heading = last.end()
        after = Segment(self.length_mm, EXTENSION_MM, tuple(end_xy), end_heading)
        object.__setattr__(self, "_all", (before, *self.segments, after))

    # -- geometry -------------------------------------------------------------
    @property
    def length_mm(self) -> float:
        """Seam length [mm] from the start to the end (extensions excluded)."""
        if not self.planar:
            return self.seam3d.length_mm
        last = self.segments[-1]
        return last.s0_mm + last.length_mm

    @property
    def seam(self):
        """The seam as a :class:`droid.sim.seam3d.Seam3D` (any workpiece; built once for a plane one)."""
        if self.seam3d is None:
            object.__setattr__(self, "seam3d", _planar_seam(self))
        return self.seam3d

    def in_gap(self, s_mm: float) -> bool:
        """True where the seam has no feature (inside a ``[[gap]]``)."""
        return any(a <= s_mm <= a + n for a, n in self.gaps)

    def seam_frame(self, s_mm: float) -> np.ndarray:
        """T_W_seam (4x4, mm): the nominal sensor frame on the seam foot at arc length s.

        Origin on the foot, x into the surface (-normal), y the left lateral,
        z the direction of travel (droid.sim.mvs.tool_sensor.seam_frame)."""
        if not self.planar:
            return self.seam3d.seam_frame(s_mm)
        xy, heading = self.point_at(s_mm)
        c, s = math.cos(heading), math.sin(heading)
        t = np.eye(4)
        t[0:3, 0] = (0.0, 0.0, -1.0)
        t[0:3, 1] = (-s, c, 0.0)
        t[0:3, 2] = (c, s, 0.0)
        t[0:2, 3] = xy
        return t

    @property
    def upper_sign(self) -> float:
        """+1 if the upper surface is on the left (+lateral), -1 if on the right."""
        return 1.0 if self.upper_side == "left" else -1.0

    def point_at(self, s_mm: float) -> tuple[np.ndarray, float]:
        """Seam point (x, y) [mm] in W and heading [rad from +x_W] at arc length s [mm].

        For a 3-D seam: the plan view (x, y of the foot; the azimuth of the tangent)."""
        s_mm = float(s_mm)
        if not self.planar:
            p, t, _, _ = self.seam3d.point_frame(s_mm)
            return p[0:2].copy(), math.atan2(float(t[1]), float(t[0]))
        seg = self._all[0]
        for candidate in self._all:
            if s_mm >= candidate.s0_mm:
                seg = candidate
        pts, heading = seg.at(np.array([s_mm]))
        return pts[0], float(heading[0])

    def nearest_many(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length s [mm] and signed lateral [mm] of the nearest seam point, for (N, 2) points.

        The plane model's; for a 3-D seam use :attr:`seam` (its ``measure``)."""
        if not self.planar:
            raise ValueError(f"workpiece {self.name}: nearest_many is the plane model's (a 3-D seam: .seam)")
        xy = np.asarray(xy, float).reshape(-1, 2)
        best_d = np.full(len(xy), np.inf)
        best_s = np.zeros(len(xy))
        best_lat = np.zeros(len(xy))
        for seg in self._all:
            d, s, lat = seg.project(xy)
            better = d < best_d
            best_d = np.where(better, d, best_d)
            best_s = np.where(better, s, best_s)
            best_lat = np.where(better, lat, best_lat)
        return best_s, best_lat

    def nearest(self, p_xyz: np.ndarray) -> tuple[float, float, float]:
        """(s [mm], lateral [mm, + = left of travel], height above the LOWER surface [mm]).

        ``p_xyz`` is a point in W; the seam point nearest to its x-y projection
        gives s and the lateral distance.
        """
        p = np.asarray(p_xyz, float)
        if not self.planar:  # the nearest sample of the foot, in 3-D
            seam = self.seam3d
            k = int(np.argmin(np.sum((seam.p - p) ** 2, axis=1)))
            _, _, n, l = seam.point_frame(float(seam.s[k]))
            d = p - seam.p[k]
            return float(seam.s[k]), float(d @ l), float(d @ n)
        s, lat = self.nearest_many(p[None, 0:2])
        return float(s[0]), float(lat[0]), float(p[2])

    def surface_heights(self, xy: np.ndarray) -> np.ndarray:
        """Surface height z_W [mm] above (N, 2) points: 0, ``step_mm`` or NaN (no surface)."""
        s, lat = self.nearest_many(xy)
        return self.heights_from(s, lat)

    def heights_from(self, s_mm: np.ndarray, lateral_mm: np.ndarray) -> np.ndarray:
        """Surface height [mm] at seam coordinates (s, lateral): 0, ``step_mm`` or NaN."""
        side = self.upper_sign * np.asarray(lateral_mm)
        along = (s_mm >= -self.lead_in_mm) & (s_mm <= self.length_mm + self.lead_out_mm)
        upper = along & (side >= 0) & (side <= self.width_mm)
        lower = along & (side < 0) & (side >= -self.width_mm)
        return np.where(upper, self.step_mm, np.where(lower, 0.0, np.nan))

    def surface_height(self, p_xy: np.ndarray) -> float | None:
        """Surface height [mm] at one W point: 0.0 (lower), ``step_mm`` (upper) or None."""
        z = float(self.surface_heights(np.asarray(p_xy, float)[None, 0:2])[0])
        return None if math.isnan(z) else z

    # -- construction ---------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict, source: str = "<dict>") -> "Workpiece":
        """Build and validate from a parsed TOML table; BadInput names the fault."""
        rd = _TableReader(source)
        bad = rd.bad
        if not isinstance(data, dict):
            raise bad("not a table")
        rd.check_keys(data, _TOP_KEYS, "")
        try:
            check_numbers(data)  # every number finite and inside its key's range (issue 16)
        except NumberError as exc:
            raise bad(str(exc)) from None
        name = data.get("name", Path(source).stem if source != "<dict>" else "workpiece")
        description = data.get("description", "")
        if not isinstance(name, str) or not name or not isinstance(description, str):
            raise bad("name and description must be strings")
        step = rd.number(data, "step_mm", "", default=2.0, minimum=0.0, exclusive=True)
        width = rd.number(data, "width_mm", "", default=50.0, minimum=0.0, exclusive=True)
        lead_in = rd.number(data, "lead_in_mm", "", default=0.0, minimum=0.0)
        lead_out = rd.number(data, "lead_out_mm", "", default=0.0, minimum=0.0)
        upper = data.get("upper_side", "left")
        if upper not in ("left", "right"):
            raise bad(f"upper_side must be \"left\" or \"right\", got {upper!r}")
        xy, heading = _start_pose(data, rd)
        raw = data.get("segment")
        segments, builder = _segments(raw, rd, xy, heading, width)
        planar = not any(k in data for k in ("roll_profile", "step_profile", "gap", "tack")) and all(
            isinstance(seg, dict) and seg.get("type") != "curve" and not seg.get("rise_mm") for seg in raw)
        length_total = builder.s
        roll_profile = _profile(data, "roll_profile", "roll_deg", bad, lo=-MAX_ROLL_DEG, hi=MAX_ROLL_DEG)
        step_profile = _profile(data, "step_profile", "step_mm", bad, lo=0.0, lo_exclusive=True)
        gaps = tuple((g["s_mm"], g["length_mm"]) for g in
                     _intervals(data, "gap", _GAP_KEYS, length_total, rd.check_keys, rd.number, bad))
        tacks = tuple((t["s_mm"], t["length_mm"], t["height_mm"]) for t in
                      _intervals(data, "tack", _TACK_KEYS, length_total, rd.check_keys, rd.number, bad))
        contact = None
        if "contact" in data:
            from droid.sim.contact import ContactParams

            contact = ContactParams.from_table(data["contact"], bad)
        common = dict(name=name, step_mm=step, width_mm=width, upper_side=upper, lead_in_mm=lead_in,
                      lead_out_mm=lead_out, description=description, source=source, contact=contact)
        if planar:
            return cls(segments=tuple(segments), **common)
        from droid.sim.seam3d import Seam3D

        seam = Seam3D(*builder.arrays(), step_mm=step, width_mm=width, upper_sign=1.0 if upper == "left" else -1.0,
                      lead_in_mm=lead_in, lead_out_mm=lead_out,
                      roll_profile=[(a, math.radians(r)) for a, r in roll_profile], step_profile=step_profile,
                      gaps=[(a, a + n) for a, n in gaps], tacks=[(a, a + n, h) for a, n, h in tacks])
        return cls(segments=(), seam3d=seam, planar=False, roll_profile=roll_profile, step_profile=step_profile,
                   gaps=gaps, tacks=tacks, **common)


class _TableReader:
    """The checks of a workpiece file's tables; every BadInput names the file (``source``)."""

    def __init__(self, source: str) -> None:
        self.source = source

    def bad(self, msg: str) -> BadInput:
        return BadInput(f"workpiece {self.source}: {msg}")

    def check_keys(self, table: dict, allowed: set[str], where: str) -> None:
        for key in table:
            if key not in allowed:
                raise self.bad(f"{where}unknown key {key!r} (expected one of {', '.join(sorted(allowed))})")

    def number(self, table: dict, key: str, where: str, default=None, minimum=None,
               exclusive=False, required=False) -> float:
        if key not in table:
            if required or default is None:
                raise self.bad(f"{where}missing {key}")
            return float(default)
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.bad(f"{where}{key} must be a finite number, got {value!r}")
        if minimum is not None and (value <= minimum if exclusive else value < minimum):
            raise self.bad(f"{where}{key} must be {'>' if exclusive else '>='} {minimum:g}, got {value!r}")
        return float(value)


def _start_pose(data: dict, rd: _TableReader) -> tuple[tuple[float, float], float]:
    """``[start]``: the seam's start point (x_mm, y_mm) in W and its heading [rad]."""
    start = data.get("start", {})
    if not isinstance(start, dict):
        raise rd.bad("[start] must be a table")
    rd.check_keys(start, _START_KEYS, "[start]: ")
    xy = (rd.number(start, "x_mm", "[start]: ", default=0.0), rd.number(start, "y_mm", "[start]: ", default=0.0))
    heading = math.radians(rd.number(start, "heading_deg", "[start]: ", default=0.0))
    return xy, heading


def _segments(raw, rd: _TableReader, xy: tuple[float, float], heading: float,
              width: float) -> tuple[list[Segment], "_SeamBuilder"]:
    """``[[segment]]`` in order (line, arc, turn, curve): the planar segments and the seam's
    builder, which holds every piece."""
    bad = rd.bad
    if not isinstance(raw, list) or not raw:
        raise bad("needs at least one [[segment]]")
    segments: list[Segment] = []
    builder = _SeamBuilder(xy, heading)
    s = 0.0
    for i, seg in enumerate(raw, 1):
        where = f"segment {i}: "
        if not isinstance(seg, dict):
            raise bad(f"{where}must be a table")
        kind = seg.get("type")
        if kind not in _SEGMENT_KEYS:
            raise bad(f"{where}type must be one of line, arc, turn, curve, got {kind!r}")
        rd.check_keys(seg, _SEGMENT_KEYS[kind], where)
        if kind == "turn":
            angle = rd.number(seg, "angle_deg", where, required=True)
            if not -180.0 < angle < 180.0:
                raise bad(f"{where}angle_deg must be within (-180, 180), got {angle:g}")
            heading += math.radians(angle)
            builder.turn(math.radians(angle))
            continue
        if kind == "curve":
            points = _curve_points(seg, where, rd.source, bad)
            interp = seg.get("interpolation", "spline")
            if interp not in ("spline", "linear"):
                raise bad(f"{where}interpolation must be \"spline\" or \"linear\", got {interp!r}")
            try:
                builder.curve(points, interp)
            except ValueError as exc:
                raise bad(f"{where}points_mm: {exc}") from None
            continue
        rise = rd.number(seg, "rise_mm", where, default=0.0)
        if kind == "line":
            length = rd.number(seg, "length_mm", where, minimum=0.0, exclusive=True, required=True)
            new = Segment(s, length, xy, heading)
            builder.line(length, rise)
        else:
            radius = rd.number(seg, "radius_mm", where, minimum=0.0, exclusive=True, required=True)
            angle = rd.number(seg, "angle_deg", where, required=True)
            if radius <= width:
                raise bad(f"{where}radius_mm ({radius:g}) must exceed width_mm ({width:g})")
            if angle == 0.0 or abs(angle) > 360.0:
                raise bad(f"{where}angle_deg must be non-zero and within [-360, 360], got {angle:g}")
            sweep = math.radians(angle)
            new = Segment(s, radius * abs(sweep), xy, heading, radius, sweep)
            builder.arc(radius, sweep, rise)
        segments.append(new)
        end_xy, heading = new.end()
        xy = (float(end_xy[0]), float(end_xy[1]))
        s += new.length_mm
    if not builder.pieces:
        raise bad("needs at least one line or arc (or curve) segment")
    return segments, builder


def _profile(data: dict, key: str, value_name: str, bad, lo: float, hi: float = math.inf,
             lo_exclusive: bool = False) -> tuple:
    """``key = [[s_mm, value], ...]``: at least one point, s strictly increasing, values in range."""
    if key not in data:
        return ()
    raw = data[key]
    if not isinstance(raw, list) or not raw:
        raise bad(f"{key} must be a non-empty list of [s_mm, {value_name}] pairs")
    out = []
    for k, pair in enumerate(raw, 1):
        if not finite_numbers(pair, 2):
            raise bad(f"{key}: point {k} must be [s_mm, {value_name}] (two finite numbers), got {pair!r}")
        s_k, v = float(pair[0]), float(pair[1])
        if out and s_k <= out[-1][0]:
            raise bad(f"{key}: point {k}: s_mm must increase, got {s_k:g} after {out[-1][0]:g}")
        if v < lo or (lo_exclusive and v == lo) or v > hi:
            rng = f"> {lo:g}" if hi == math.inf else f"within [{lo:g}, {hi:g}]"
            raise bad(f"{key}: point {k}: {value_name} must be {rng}, got {v:g}")
        out.append((s_k, v))
    return tuple(out)


def _intervals(data: dict, key: str, keys: set, length_mm: float, check_keys, number, bad) -> list[dict]:
    """``[[gap]]`` / ``[[tack]]`` tables: s_mm >= 0, lengths (and heights) > 0, within the seam."""
    raw = data.get(key, [])
    if not isinstance(raw, list) or not all(isinstance(t, dict) for t in raw):
        raise bad(f"{key} must be [[{key}]] tables")
    out = []
    for k, table in enumerate(raw, 1):
        where = f"[[{key}]] {k}: "
        check_keys(table, keys, where)
        item = {"s_mm": number(table, "s_mm", where, minimum=0.0, required=True),
                "length_mm": number(table, "length_mm", where, minimum=0.0, exclusive=True, required=True)}
        if "height_mm" in keys:
            item["height_mm"] = number(table, "height_mm", where, minimum=0.0, exclusive=True, required=True)
        if item["s_mm"] + item["length_mm"] > length_mm + 1e-9:
            raise bad(f"{where}s_mm + length_mm ({item['s_mm'] + item['length_mm']:g}) must lie within the "
                      f"seam (length {length_mm:g} mm)")
        out.append(item)
    return out


def _curve_points(seg: dict, where: str, source: str, bad) -> np.ndarray:
    """The (N, 3) points [mm] of a curve segment: ``points_mm`` inline or ``csv`` (relative to the file)."""
    if ("points_mm" in seg) == ("csv" in seg):
        raise bad(f"{where}give points_mm or csv (one of them)")
    if "points_mm" in seg:
        raw = seg["points_mm"]
        if not isinstance(raw, list):
            raise bad(f"{where}points_mm must be a list of [x, y, z] points")
        rows = []
        for k, pt in enumerate(raw, 1):
            if not finite_numbers(pt, 3):
                raise bad(f"{where}points_mm: point {k} must be [x, y, z] (three finite numbers), got {pt!r}")
            rows.append([float(v) for v in pt])
        what = "points_mm"
    else:
        rel = seg["csv"]
        if not isinstance(rel, str) or not rel:
            raise bad(f"{where}csv must be a file name, got {rel!r}")
        base = Path(source).parent if source != "<dict>" else Path.cwd()
        path = Path(rel) if os.path.isabs(rel) else base / rel
        rows = _read_points_csv(path, where, bad)
        what = f"csv {rel}"
    pts = np.array(rows, float).reshape(-1, 3)
    if len(pts) < 2:
        raise bad(f"{where}{what}: needs at least 2 points, got {len(pts)}")
    if np.max(np.abs(pts[0])) > 1e-6:
        raise bad(f"{where}{what}: the first point must be [0, 0, 0] (the segment's start), got {pts[0].tolist()}")
    return pts


def _read_points_csv(path: Path, where: str, bad) -> list[list[float]]:
    import csv

    try:
        with open(path, newline="") as f:
            reader = csv.reader(f)
            header = [h.strip() for h in next(reader, [])]
            if header != ["x_mm", "y_mm", "z_mm"]:
                raise bad(f"{where}csv {path}: the header must be x_mm,y_mm,z_mm, got {','.join(header)!r}")
            rows = []
            for line_no, row in enumerate(reader, 2):
                if not row or all(not c.strip() for c in row):
                    continue
                try:
                    vals = [float(c) for c in row]
                except ValueError:
                    vals = []
                if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
                    raise bad(f"{where}csv {path}: line {line_no}: expected three finite numbers, got {row!r}")
                rows.append(vals)
            return rows
    except FileNotFoundError:
        raise bad(f"{where}csv file not found: {path}") from None
    except OSError as exc:
        raise bad(f"{where}csv {path}: {exc.strerror}") from None


class _SeamBuilder:
    """Samples of the 3-D seam, piece by piece: s [mm], foot p, tangent t, unrolled normal n0.

    The current state is the end of the last piece: its point, tangent and
    normal.  A line or arc runs at the current azimuth (the tangent's plan
    direction) and height, climbing ``rise_mm`` linearly, its lateral
    horizontal (n0 = t x l0, l0 the plan's left normal); a turn rotates the
    tangent about the normal; a curve's points are in the frame of its
    start (x the tangent, z the normal, y = z x x), and its normal is the
    start normal made perpendicular to the curve's tangent.
    """

    def __init__(self, xy: tuple[float, float], heading_rad: float) -> None:
        self.p = np.array([xy[0], xy[1], 0.0])
        self.t = np.array([math.cos(heading_rad), math.sin(heading_rad), 0.0])
        self.n0 = np.array([0.0, 0.0, 1.0])
        self.s = 0.0
        self.pieces: list[tuple[np.ndarray, ...]] = []

    def _add(self, s, p, t, n0) -> None:
        self.pieces.append((np.asarray(s, float), np.asarray(p, float), np.asarray(t, float), np.asarray(n0, float)))
        self.s, self.p, self.t, self.n0 = float(s[-1]), np.asarray(p[-1], float), np.asarray(t[-1], float), \
            np.asarray(n0[-1], float)

    def turn(self, angle_rad: float) -> None:
        l0 = np.cross(self.n0, self.t)
        self.t = math.cos(angle_rad) * self.t + math.sin(angle_rad) * l0

    def _climb_frames(self, azimuth: np.ndarray, gamma: float) -> tuple[np.ndarray, np.ndarray]:
        cg, sg = math.cos(gamma), math.sin(gamma)
        t = np.stack([np.cos(azimuth) * cg, np.sin(azimuth) * cg, np.full_like(azimuth, sg)], axis=1)
        l0 = np.stack([-np.sin(azimuth), np.cos(azimuth), np.zeros_like(azimuth)], axis=1)
        return t, np.cross(t, l0)

    def line(self, length_mm: float, rise_mm: float) -> None:
        az = math.atan2(self.t[1], self.t[0])
        gamma = math.atan2(rise_mm, length_mm)
        u = np.array([0.0, 1.0])
        p = self.p + np.outer(u, [length_mm * math.cos(az), length_mm * math.sin(az), rise_mm])
        t, n0 = self._climb_frames(np.full(2, az), gamma)
        self._add(self.s + u * math.hypot(length_mm, rise_mm), p, t, n0)

    def arc(self, radius_mm: float, sweep_rad: float, rise_mm: float) -> None:
        az0 = math.atan2(self.t[1], self.t[0])
        sign = 1.0 if sweep_rad > 0 else -1.0
        plan = radius_mm * abs(sweep_rad)
        n = max(2, math.ceil(math.hypot(plan, rise_mm) / _sample_mm()) + 1)
        u = np.linspace(0.0, 1.0, n)
        az = az0 + sweep_rad * u
        cx = self.p[0] - sign * radius_mm * math.sin(az0)
        cy = self.p[1] + sign * radius_mm * math.cos(az0)
        p = np.stack([cx + sign * radius_mm * np.sin(az), cy - sign * radius_mm * np.cos(az),
                      self.p[2] + rise_mm * u], axis=1)
        t, n0 = self._climb_frames(az, math.atan2(rise_mm, plan))
        self._add(self.s + u * math.hypot(plan, rise_mm), p, t, n0)

    def curve(self, points: np.ndarray, interpolation: str) -> None:
        x, z = self.t / np.linalg.norm(self.t), self.n0
        y = np.cross(z, x)
        world = self.p + points @ np.stack([x, y, z])
        chords = np.linalg.norm(np.diff(world, axis=0), axis=1)
        if np.any(chords < 1e-6):
            k = int(np.argmax(chords < 1e-6)) + 1
            raise ValueError(f"points {k} and {k + 1} coincide")
        if interpolation == "linear":
            p = np.repeat(world, 2, axis=0)[1:-1]  # each inner vertex twice: the tangent jumps there
            t = np.repeat(np.diff(world, axis=0) / chords[:, None], 2, axis=0)
            seg_s = np.concatenate([[0.0], np.cumsum(chords)])
            s = np.repeat(seg_s, 2)[1:-1]
        else:
            p, d = _natural_spline(world, chords)
            t = d / np.linalg.norm(d, axis=1, keepdims=True)
            s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        along = t @ z
        if np.any(np.abs(along) > 1.0 - 1e-6):
            raise ValueError("the curve runs along the surface normal (its lateral is undefined there)")
        n0 = z - along[:, None] * t
        n0 /= np.linalg.norm(n0, axis=1, keepdims=True)
        self._add(self.s + s, p, t, n0)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return tuple(np.concatenate([piece[k] for piece in self.pieces]) for k in range(4))


def _sample_mm() -> float:
    from droid.sim.seam3d import SAMPLE_MM

    return SAMPLE_MM


def _natural_spline(points: np.ndarray, chords: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A natural cubic spline through (N, 3) points, chord-length parameter; dense samples and derivatives.

    Each interval is cut into pieces of at most SAMPLE_MM / 2 of chord."""
    n = len(points)
    h = chords
    m = np.zeros((n, 3))  # second derivatives (natural: 0 at both ends)
    if n > 2:
        # tridiagonal system for the inner second derivatives (Thomas algorithm)
        a = h[:-1].copy()
        b = 2.0 * (h[:-1] + h[1:])
        c = h[1:].copy()
        d = 6.0 * ((points[2:] - points[1:-1]) / h[1:, None] - (points[1:-1] - points[:-2]) / h[:-1, None])
        k = n - 2
        cp = np.zeros(k)
        dp = np.zeros((k, 3))
        cp[0], dp[0] = c[0] / b[0], d[0] / b[0]
        for i in range(1, k):
            den = b[i] - a[i] * cp[i - 1]
            cp[i] = c[i] / den
            dp[i] = (d[i] - a[i] * dp[i - 1]) / den
        x = np.zeros((k, 3))
        x[-1] = dp[-1]
        for i in range(k - 2, -1, -1):
            x[i] = dp[i] - cp[i] * x[i + 1]
        m[1:-1] = x
    step = _sample_mm() / 2
    pts, ders = [], []
    for i in range(n - 1):
        cnt = max(2, math.ceil(h[i] / step) + 1)
        tau = np.linspace(0.0, h[i], cnt)[:-1] if i < n - 2 else np.linspace(0.0, h[i], cnt)
        A, B = (h[i] - tau) / h[i], tau / h[i]
        p = (A[:, None] * points[i] + B[:, None] * points[i + 1]
             + ((A ** 3 - A)[:, None] * m[i] + (B ** 3 - B)[:, None] * m[i + 1]) * h[i] ** 2 / 6.0)
        dp_ = ((points[i + 1] - points[i]) / h[i]
               + (-(3 * A ** 2 - 1))[:, None] * m[i] * h[i] / 6.0 + (3 * B ** 2 - 1)[:, None] * m[i + 1] * h[i] / 6.0)
        pts.append(p)
        ders.append(dp_)
    return np.concatenate(pts), np.concatenate(ders)


def _planar_seam(wp: "Workpiece"):
    """The Seam3D of a plane workpiece (its segments sampled; no profiles, gaps or tacks)."""
    from droid.sim.seam3d import SAMPLE_MM, Seam3D

    parts = []
    for seg in wp.segments:
        n = 2 if not seg.is_arc else max(2, math.ceil(seg.length_mm / SAMPLE_MM) + 1)
        s = seg.s0_mm + np.linspace(0.0, seg.length_mm, n)
        xy, heading = seg.at(s)
        p = np.column_stack([xy, np.zeros(n)])
        t = np.column_stack([np.cos(heading), np.sin(heading), np.zeros(n)])
        parts.append((s, p, t, np.tile([0.0, 0.0, 1.0], (n, 1))))
    arrays = [np.concatenate([part[k] for part in parts]) for k in range(4)]
    return Seam3D(*arrays, step_mm=wp.step_mm, width_mm=wp.width_mm, upper_sign=wp.upper_sign,
                  lead_in_mm=wp.lead_in_mm, lead_out_mm=wp.lead_out_mm)


def bundled_workpieces() -> list[str]:
    """Names of the workpieces shipped in droid/sim/workpieces/."""
    return sorted(p.stem for p in WORKPIECE_DIR.glob("*.toml"))


def load_workpiece(spec: str | os.PathLike) -> Workpiece:
    """Load a workpiece by bundled name (``step_input``) or by path to a TOML file."""
    text = os.fspath(spec)
    path = Path(text)
    if not path.is_file():
        if os.sep in text or text.endswith(".toml"):
            raise BadInput(f"workpiece file not found: {text}")
        path = WORKPIECE_DIR / f"{text}.toml"
        if not path.is_file():
            raise BadInput(f"unknown workpiece {text!r} (bundled: {', '.join(bundled_workpieces())})")
    return Workpiece.from_dict(read_toml(path, "workpiece"), source=str(path))
