"""The seam-tracking cell layout as data (thesis §5.1-5.2, Figures 5.1-5.2, §6.1.1-6.1.2).

One TOML file (default: the bundled ``droid/cells/seamtrack_layout.toml``)
holds the geometry the seam-tracking task and the experiments share:

* ``[bases]`` -- the robot base frames in the global frame (``global T (Reis)0``,
  ``global T (GMF1)0`` of eq. 5.3-5.11);
* ``[wrist]`` -- the Reis wrist centre (WCP) to the tool point
  (``(Reis)6 T tool``, the listing's ``T67tool``) and to the lead sensor's
  measuring point (``(Reis)6 T sensor``, the listing's ``Tcamera_6``), for
  each wrist variant: ``standard`` and experiment 5's ``extension30`` (a
  block slanted in the pitch axis between the tool plate and the dual sensor
  fixture, §6.2.7);
* ``[workpieces]`` -- where the workpiece frame W sits on the GMF1's wrist
  centre (``(GMF1)6 T W``; the thesis puts the workpiece frame at the holder's
  WCP, §5.1);
* ``[positions]`` -- the seven start positions/orientations (i)-(vii) of
  §6.1.2, as the placement of the seam in the global frame.

Poses are ``[x, y, z, A, B, C]``: mm and Z-Y-Z Euler degrees (eq. 4.2).
The task program (droid-seamtrack) uses only the bases and the wrist; the
lockstep harness (droid.experiments) uses all of it.  See docs/seamtrack.md.

Frames of the tool point T and the sensor S (docs/mvs.md): x along the tool
axis toward the surface (depth), y lateral (left of travel), z the travel
direction along the seam.  CAMERA_TO_TCP of the listing is the distance from
T's origin to S's origin.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from droid.cli import BadInput, read_toml
from droid.numbers import NumberError, check_numbers
from droid.kinematics.transforms import inv_homo, pose_to_T, roty, rotx, rotz, trans

#: the repository's cells/ (a link to droid/cells/), as before the Brain's split (issue 43 item 5):
#: three folders up from droid/brain/cell/, the same path as two up from droid/brain/ was
BUNDLED_LAYOUT = Path(__file__).resolve().parents[3] / "cells" / "seamtrack_layout.toml"
POSITION_IDS = ("i", "ii", "iii", "iv", "v", "vi", "vii")
#: ``W T seam`` at the seam start: the tool/sensor frame convention (x = -z_W into the
#: surface, y = +y_W lateral left, z = +x_W the travel direction; docs/mvs.md).
T_W_SEAM = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Wrist:
    """One wrist set-up: WCP -> tool point and WCP -> sensor point (4x4, mm)."""

    name: str
    T_wcp_tool: np.ndarray  # (Reis)6 T tool  (T67tool)
    T_wcp_sensor: np.ndarray  # (Reis)6 T sensor  (Tcamera_6)
    description: str = ""

    @property
    def camera_to_tcp_mm(self) -> float:
        """CAMERA_TO_TCP [mm]: distance from the tool point to the sensor's measuring point."""
        return float(np.linalg.norm(self.T_wcp_sensor[:3, 3] - self.T_wcp_tool[:3, 3]))


@dataclass(frozen=True)
class Position:
    """A start position/orientation of the seam (§6.1.2) in the global frame.

    The tool point starts at ``tool_start_mm``; the seam's first segment heads
    ``heading_deg`` (azimuth from +x, counter-clockwise seen from above),
    climbs at ``pitch_deg`` and the workpiece is rolled by ``roll_deg`` about
    that direction (+ = the left side up).  W's origin (the seam start) lies
    CAMERA_TO_TCP ahead of the tool point, so the lead sensor starts on the
    seam start and the tool point on the seam's straight extension (§6.1.1).
    """

    name: str
    tool_start_mm: tuple[float, float, float]
    heading_deg: float
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    workpiece: str = "step_input"
    description: str = ""

    def R_global_W(self) -> np.ndarray:
        """Rotation (4x4) of the workpiece frame W in the global frame: Rz(heading) Ry(-pitch) Rx(roll)."""
        return (rotz(math.radians(self.heading_deg)) @ roty(-math.radians(self.pitch_deg))
                @ rotx(math.radians(self.roll_deg)))

    def T_global_W(self, camera_to_tcp_mm: float) -> np.ndarray:
        """Pose (4x4, mm) of the workpiece frame W in the global frame."""
        r = self.R_global_W()
        t = r.copy()
        t[:3, 3] = np.asarray(self.tool_start_mm, float) + camera_to_tcp_mm * r[:3, 0]
        return t


@dataclass(frozen=True)
class Layout:
    """The seam-tracking cell layout (see the module docstring)."""

    name: str
    bases: dict[str, np.ndarray]
    wrists: dict[str, Wrist]
    mounts: dict[str, np.ndarray]  # workpiece name (or "default") -> (GMF1)6 T W
    positions: dict[str, Position]
    robots: dict[str, str] = field(default_factory=dict)
    tool_robot: str = "arm1"
    holder_robot: str = "gmf1"
    sensor: str = "mvs"
    source: str = "<dict>"

    def wrist(self, name: str = "standard") -> Wrist:
        try:
            return self.wrists[name]
        except KeyError:
            raise BadInput(f"layout {self.source}: unknown wrist {name!r} "
                           f"(known: {', '.join(sorted(self.wrists))})") from None

    def position(self, name: str) -> Position:
        try:
            return self.positions[name]
        except KeyError:
            raise BadInput(f"layout {self.source}: unknown position {name!r} "
                           f"(known: {', '.join(self.positions)})") from None

    def mount(self, workpiece: str) -> np.ndarray:
        """(GMF1)6 T W [mm] for a workpiece name (its own entry, else its family, else ``default``)."""
        for key in (workpiece, workpiece.split("_")[0], "default"):
            if key in self.mounts:
                return self.mounts[key]
        raise BadInput(f"layout {self.source}: no mount for workpiece {workpiece!r} and no default")

    def base(self, robot: str) -> np.ndarray:
        return self.bases[robot]

    def start_poses(self, position: str, wrist: str = "standard") -> tuple[np.ndarray, np.ndarray]:
        """The two wrist-centre poses (4x4, mm, global) at the start of a run at ``position``.

        Returns ``(global T (Reis)6, global T (GMF1)6)``: the Reis with its
        tool frame on the seam's straight extension CAMERA_TO_TCP before the
        seam start (tool axis along the surface normal, travel along the seam,
        so the lead sensor's laser line lies on the seam start, §6.1.1), and
        the GMF1 holding the position's workpiece so that W lies where the
        position puts it (``global T W  ((GMF1)6 T W)^-1``, §5.1).  The seam
        starts at W's origin heading +x_W (the bundled workpieces do).
        """
        pos = self.position(position)
        wr = self.wrist(wrist)
        L = wr.camera_to_tcp_mm
        T_gW = pos.T_global_W(L)
        T_tool = T_gW @ trans(-L, 0.0, 0.0) @ T_W_SEAM
        return T_tool @ inv_homo(wr.T_wcp_tool), T_gW @ inv_homo(self.mount(pos.workpiece))


# ---------------------------------------------------------------- parsing

def _bad(source: str, msg: str) -> BadInput:
    return BadInput(f"layout {source}: {msg}")


def _check_keys(source: str, where: str, table, allowed: set[str], required: set[str] = frozenset()) -> dict:
    if not isinstance(table, dict):
        raise _bad(source, f"[{where}] must be a table")
    unknown = set(table) - allowed
    if unknown:
        raise _bad(source, f"[{where}] unknown key(s) {', '.join(sorted(unknown))} "
                           f"(expected {', '.join(sorted(allowed))})")
    missing = set(required) - set(table)
    if missing:
        raise _bad(source, f"[{where}] missing key(s) {', '.join(sorted(missing))}")
    return table


def _number(source: str, where: str, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _bad(source, f"[{where}] {key} must be a finite number, got {value!r}")
    return float(value)


def _numbers(source: str, where: str, key: str, value, n: int) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise _bad(source, f"[{where}] {key} must be a list of {n} finite numbers")
    return [_number(source, where, key, v) for v in value]


def _pose(source: str, where: str, key: str, value) -> np.ndarray:
    return pose_to_T(*_numbers(source, where, key, value, 6))


def _wrist(source: str, name: str, table: dict, fixture: dict, flange_mm: float) -> Wrist:
    where = f"wrist.variants.{name}"
    _check_keys(source, where, table, {"description", "block_length_mm", "block_pitch_deg"})
    length = _number(source, where, "block_length_mm", table.get("block_length_mm", 0.0))
    pitch = _number(source, where, "block_pitch_deg", table.get("block_pitch_deg", 0.0))
    if length < 0:
        raise _bad(source, f"[{where}] block_length_mm must be >= 0")
    # WCP -> tool plate (along the WCP z axis) -> the block: turned by its slant
    # about the plate's y axis (the tool's lateral = pitch axis), then its length
    # along the turned axis -> the dual sensor fixture (thesis §6.2.7).
    plate = trans(0.0, 0.0, flange_mm) @ roty(math.radians(pitch)) @ trans(0.0, 0.0, length)
    return Wrist(name=name, T_wcp_tool=plate @ fixture["tool"], T_wcp_sensor=plate @ fixture["sensor"],
                 description=str(table.get("description", "")))


def layout_from_dict(data: dict, source: str = "<dict>") -> Layout:
    """Build and validate a layout from a parsed TOML table (BadInput names the fault)."""
    _check_keys(source, "top level", data,
                {"name", "description", "tool_robot", "holder_robot", "sensor", "bases", "robots",
                 "wrist", "workpieces", "positions"},
                {"bases", "wrist", "workpieces", "positions"})
    try:
        check_numbers(data)  # every number finite and inside its key's range (issue 16)
    except NumberError as exc:
        raise _bad(source, str(exc)) from None
    name = data.get("name", Path(source).stem)
    roles = {k: data.get(k, d) for k, d in (("tool_robot", "arm1"), ("holder_robot", "gmf1"), ("sensor", "mvs"))}
    for k, v in roles.items():
        if not isinstance(v, str) or not v:
            raise _bad(source, f"{k} must be a subunit name")
    bases_t = _check_keys(source, "bases", data["bases"], {roles["tool_robot"], roles["holder_robot"]},
                          {roles["tool_robot"], roles["holder_robot"]})
    bases = {k: _pose(source, "bases", k, v) for k, v in bases_t.items()}
    robots_t = _check_keys(source, "robots", data.get("robots", {}),
                           {roles["tool_robot"], roles["holder_robot"]})
    robots = {k: str(v) for k, v in robots_t.items()}

    w = _check_keys(source, "wrist", data["wrist"], {"flange_mm", "fixture", "variants"},
                    {"flange_mm", "fixture", "variants"})
    flange = _number(source, "wrist", "flange_mm", w["flange_mm"])
    fx = _check_keys(source, "wrist.fixture", w["fixture"], {"tool", "sensor"}, {"tool", "sensor"})
    fixture = {k: _pose(source, "wrist.fixture", k, v) for k, v in fx.items()}
    variants = _check_keys(source, "wrist.variants", w["variants"], set(w["variants"]) if isinstance(
        w["variants"], dict) else set(), {"standard"})
    wrists = {k: _wrist(source, k, v, fixture, flange) for k, v in variants.items()}
    for wr in wrists.values():
        if wr.camera_to_tcp_mm <= 0:
            raise _bad(source, f"wrist {wr.name}: the sensor point coincides with the tool point")

    wps = data["workpieces"]
    if not isinstance(wps, dict) or not wps:
        raise _bad(source, "[workpieces] must name at least one mount")
    mounts = {}
    for k, v in wps.items():
        _check_keys(source, f"workpieces.{k}", v, {"mount", "description"}, {"mount"})
        mounts[k] = _pose(source, f"workpieces.{k}", "mount", v["mount"])

    ps = data["positions"]
    if not isinstance(ps, dict) or not ps:
        raise _bad(source, "[positions] must name at least one position")
    positions = {}
    for k, v in ps.items():
        where = f"positions.{k}"
        _check_keys(source, where, v, {"description", "tool_start_mm", "heading_deg", "pitch_deg", "roll_deg",
                                       "workpiece"}, {"tool_start_mm", "heading_deg"})
        wp = v.get("workpiece", "step_input")
        if not isinstance(wp, str) or not wp:
            raise _bad(source, f"[{where}] workpiece must be a workpiece name")
        positions[k] = Position(
            name=k,
            tool_start_mm=tuple(_numbers(source, where, "tool_start_mm", v["tool_start_mm"], 3)),
            heading_deg=_number(source, where, "heading_deg", v["heading_deg"]),
            pitch_deg=_number(source, where, "pitch_deg", v.get("pitch_deg", 0.0)),
            roll_deg=_number(source, where, "roll_deg", v.get("roll_deg", 0.0)),
            workpiece=wp,
            description=str(v.get("description", "")),
        )
    return Layout(name=str(name), bases=bases, wrists=wrists, mounts=mounts, positions=positions,
                  robots=robots, source=source, **roles)


def load_layout(path: str | os.PathLike | None = None) -> Layout:
    """Read a layout file (default: the bundled seamtrack_layout.toml).  Raises BadInput."""
    p = Path(path) if path is not None else BUNDLED_LAYOUT
    return layout_from_dict(read_toml(p, "layout file"), source=str(p))


def layout_path_for(cell, path: str | os.PathLike | None = None) -> Path:
    """The layout file a task on ``cell`` reads: ``path`` (a --layout option) when given, else the
    cell file's ``[cell] layout``, else the bundled seamtrack_layout.toml."""
    if path is not None:
        return Path(path)
    return cell.layout if getattr(cell, "layout", None) is not None else BUNDLED_LAYOUT


#: how far a layout's robot base may lie from its cell's [subunits.*] base [mm, and the rotation
#: matrix's entries]
BASE_TOL_MM = 1e-3


def check_bases(layout: Layout, cell) -> None:
    """The layout's tool and holder robots are arms of ``cell`` at the cell's bases, or every
    command would land elsewhere.  BadInput (one line) otherwise."""
    for name in (layout.tool_robot, layout.holder_robot):
        sub = cell.subunit(name)
        if not sub.is_arm:
            raise BadInput(f"layout {layout.source}: {name} is a {sub.cls} subunit of the cell, not an arm")
        if not np.allclose(pose_to_T(*sub.base), layout.base(name), atol=BASE_TOL_MM):
            raise BadInput(f"layout {layout.source}: the base of {name} differs from the cell's "
                           f"[subunits.{name}] base")


def check_robots(layout: Layout, cell) -> None:
    """The layout's tool and holder robots have the robot files of ``cell``'s subunits (one arm,
    one robot file: a layout's ``[robots]`` entry may be left out).  BadInput (one line) otherwise."""
    for name in (layout.tool_robot, layout.holder_robot):
        robot, sub = layout.robots.get(name), cell.subunit(name)
        if robot is not None and robot != sub.robot:
            raise BadInput(f"{cell.path}: [subunits.{name}] robot {sub.robot!r} differs from its layout "
                           f"{layout.source}'s {robot!r}: one arm, one robot file")


def layout_for_cell(cell, path: str | os.PathLike | None = None) -> Layout:
    """The seam-tracking layout of ``cell`` (:func:`layout_path_for`).  Raises BadInput."""
    return load_layout(layout_path_for(cell, path))
