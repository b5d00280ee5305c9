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
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from droid.cli import BadInput

WORKPIECE_DIR = Path(__file__).parent / "workpieces"

#: Length [mm] of the virtual straight extensions before the start and after the end.
EXTENSION_MM = 1.0e6

_TOP_KEYS = {
    "name", "description", "step_mm", "width_mm", "upper_side",
    "lead_in_mm", "lead_out_mm", "start", "segment",
}
_START_KEYS = {"x_mm", "y_mm", "heading_deg"}
_SEGMENT_KEYS = {
    "line": {"type", "length_mm"},
    "arc": {"type", "radius_mm", "angle_deg"},
    "turn": {"type", "angle_deg"},
}


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
    _all: tuple[Segment, ...] = field(default=(), repr=False, compare=False)

    def __post_init__(self) -> None:
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
        last = self.segments[-1]
        return last.s0_mm + last.length_mm

    @property
    def upper_sign(self) -> float:
        """+1 if the upper surface is on the left (+lateral), -1 if on the right."""
        return 1.0 if self.upper_side == "left" else -1.0

    def point_at(self, s_mm: float) -> tuple[np.ndarray, float]:
        """Seam point (x, y) [mm] in W and heading [rad from +x_W] at arc length s [mm]."""
        s_mm = float(s_mm)
        seg = self._all[0]
        for candidate in self._all:
            if s_mm >= candidate.s0_mm:
                seg = candidate
        pts, heading = seg.at(np.array([s_mm]))
        return pts[0], float(heading[0])

    def nearest_many(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length s [mm] and signed lateral [mm] of the nearest seam point, for (N, 2) points."""
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

        def bad(msg: str) -> BadInput:
            return BadInput(f"workpiece {source}: {msg}")

        def check_keys(table: dict, allowed: set[str], where: str) -> None:
            for key in table:
                if key not in allowed:
                    raise bad(f"{where}unknown key {key!r} (expected one of {', '.join(sorted(allowed))})")

        def number(table: dict, key: str, where: str, default=None, minimum=None,
                   exclusive=False, required=False) -> float:
            if key not in table:
                if required or default is None:
                    raise bad(f"{where}missing {key}")
                return float(default)
            value = table[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise bad(f"{where}{key} must be a finite number, got {value!r}")
            if minimum is not None and (value <= minimum if exclusive else value < minimum):
                raise bad(f"{where}{key} must be {'>' if exclusive else '>='} {minimum:g}, got {value!r}")
            return float(value)

        if not isinstance(data, dict):
            raise bad("not a table")
        check_keys(data, _TOP_KEYS, "")
        name = data.get("name", Path(source).stem if source != "<dict>" else "workpiece")
        description = data.get("description", "")
        if not isinstance(name, str) or not name or not isinstance(description, str):
            raise bad("name and description must be strings")
        step = number(data, "step_mm", "", default=2.0, minimum=0.0, exclusive=True)
        width = number(data, "width_mm", "", default=50.0, minimum=0.0, exclusive=True)
        lead_in = number(data, "lead_in_mm", "", default=0.0, minimum=0.0)
        lead_out = number(data, "lead_out_mm", "", default=0.0, minimum=0.0)
        upper = data.get("upper_side", "left")
        if upper not in ("left", "right"):
            raise bad(f"upper_side must be \"left\" or \"right\", got {upper!r}")
        start = data.get("start", {})
        if not isinstance(start, dict):
            raise bad("[start] must be a table")
        check_keys(start, _START_KEYS, "[start]: ")
        xy = (number(start, "x_mm", "[start]: ", default=0.0), number(start, "y_mm", "[start]: ", default=0.0))
        heading = math.radians(number(start, "heading_deg", "[start]: ", default=0.0))

        raw = data.get("segment")
        if not isinstance(raw, list) or not raw:
            raise bad("needs at least one [[segment]]")
        segments: list[Segment] = []
        s = 0.0
        for i, seg in enumerate(raw, 1):
            where = f"segment {i}: "
            if not isinstance(seg, dict):
                raise bad(f"{where}must be a table")
            kind = seg.get("type")
            if kind not in _SEGMENT_KEYS:
                raise bad(f"{where}type must be one of line, arc, turn, got {kind!r}")
            check_keys(seg, _SEGMENT_KEYS[kind], where)
            if kind == "turn":
                angle = number(seg, "angle_deg", where, required=True)
                if not -180.0 < angle < 180.0:
                    raise bad(f"{where}angle_deg must be within (-180, 180), got {angle:g}")
                heading += math.radians(angle)
                continue
            if kind == "line":
                length = number(seg, "length_mm", where, minimum=0.0, exclusive=True, required=True)
                new = Segment(s, length, xy, heading)
            else:
                radius = number(seg, "radius_mm", where, minimum=0.0, exclusive=True, required=True)
                angle = number(seg, "angle_deg", where, required=True)
                if radius <= width:
                    raise bad(f"{where}radius_mm ({radius:g}) must exceed width_mm ({width:g})")
                if angle == 0.0 or abs(angle) > 360.0:
                    raise bad(f"{where}angle_deg must be non-zero and within [-360, 360], got {angle:g}")
                sweep = math.radians(angle)
                new = Segment(s, radius * abs(sweep), xy, heading, radius, sweep)
            segments.append(new)
            end_xy, heading = new.end()
            xy = (float(end_xy[0]), float(end_xy[1]))
            s += new.length_mm
        if not segments:
            raise bad("needs at least one line or arc segment")
        return cls(name=name, segments=tuple(segments), step_mm=step, width_mm=width,
                   upper_side=upper, lead_in_mm=lead_in, lead_out_mm=lead_out,
                   description=description, source=source)


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
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise BadInput(f"workpiece {path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise BadInput(f"workpiece {path}: {exc.strerror}") from None
    return Workpiece.from_dict(data, source=str(path))
