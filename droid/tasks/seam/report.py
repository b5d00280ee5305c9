"""Seam-tracking logs, summaries and figures (thesis §6.1, Figures 6.5-6.35).

Pure: numpy and csv; matplotlib is imported inside the figure functions only
(Agg canvas, no pyplot, no global backend change).  Used by droid-experiment
(the lockstep trials, droid.experiments) and by the real-time task program
droid-seamtrack, so nothing here imports droid.sim.

The log is one row per 100 ms (10 Hz, §6.1) in :data:`COLUMNS` order: the
nine columns of docs/experiments.md first, then the extras of the trial
harness.  Seam length ``s_mm`` is the tool point's progress along the seam,
0 where the tool starts (CAMERA_TO_TCP before the seam's start, §6.1.1).

A summary (:func:`summarize`) gives the RMS and the largest |tool lateral| and
|tool depth| error *after settling*: rows with ``s_mm > CAMERA_TO_TCP +
SETTLE_EXTRA_MM`` (the initial straight section the tool needs before
tracking starts, §6.1.1 and §6.2.2, plus 50 mm), NaN rows ignored; and how
the run ended (end of seam, seam lost, unreachable, ...) and where.
"""
from __future__ import annotations

import csv
import math
import os
from dataclasses import asdict, dataclass
from typing import Iterable, Sequence

import numpy as np

from droid.cli import BadInput
from droid.tasks.seam.params import PHASE_DEAD_ZONE, PHASE_INITIAL, PHASE_TRACKING
from droid.tasks.seam.stops import STOP_LOST

#: The columns every log has, in this order (issue 7), with their units in the names.
REQUIRED_COLUMNS = ("s_mm", "lead_lateral_mm", "lead_depth_mm", "lead_roll_rad", "tool_lateral_mm",
                    "tool_depth_mm", "tool_roll_rad", "yaw_deg", "pitch_deg")
#: Every column of a log: the required ones, then the trial harness's extras.
COLUMNS = REQUIRED_COLUMNS + ("t_s", "travel_mm", "phase", "lead_valid", "ctrl_yaw_deg", "ctrl_pitch_deg",
                              "delay_state")
#: Text columns (the rest are numbers; ``lead_valid`` is 0/1).
TEXT_COLUMNS = frozenset({"phase", "delay_state"})
INT_COLUMNS = frozenset({"lead_valid"})
#: What each column means (docs/experiments.md lists the same).
COLUMN_DOCS = {
    "s_mm": "seam length: the tool point's progress along the seam [mm], 0 at the tool's start",
    "lead_lateral_mm": "lead sensor lateral reading (sensor y, left +) [mm]; NaN when invalid",
    "lead_depth_mm": "lead sensor depth reading (sensor x, toward the surface +) [mm]; NaN when invalid",
    "lead_roll_rad": "lead sensor surface roll [rad]; NaN when invalid",
    "tool_lateral_mm": "tool-tip sensor lateral error [mm] (the tracking error, §6.1)",
    "tool_depth_mm": "tool-tip sensor depth (height) error [mm]",
    "tool_roll_rad": "tool-tip sensor roll error [rad]",
    "yaw_deg": "yaw angle from the two sensors, atan2(lead - tool lateral, CAMERA_TO_TCP) [deg] (Figure 6.14)",
    "pitch_deg": "pitch angle from the two sensors, atan2(lead - tool depth, CAMERA_TO_TCP) [deg]",
    "t_s": "time since the start of the trial [s]",
    "travel_mm": "the tracking core's tool travel [mm] (its run-length and delay trigger)",
    "phase": "tracking core phase: dead_zone, initial, tracking",
    "lead_valid": "1 if the lead sensor reading was valid, else 0",
    "ctrl_yaw_deg": "the core's yaw correction this cycle [deg] (eq. 5.6)",
    "ctrl_pitch_deg": "the core's pitch correction this cycle [deg] (eq. 5.7)",
    "delay_state": "transport delay buffer: off, zeroed, delayed (§6.2.5)",
}
#: Settling: the tool's initial straight section (CAMERA_TO_TCP) plus this [mm].
SETTLE_EXTRA_MM = 50.0
#: CAMERA_TO_TCP of the bundled layout [mm] (droid/cells/seamtrack_layout.toml).
DEFAULT_CAMERA_TO_TCP_MM = 100.0


#: The core's phases as log words.
PHASE_CODES = {PHASE_DEAD_ZONE: "dead_zone", PHASE_INITIAL: "initial", PHASE_TRACKING: "tracking"}


def log_row(*, s_mm: float, t_s: float, lead, tool, out, camera_to_tcp_mm: float) -> tuple:
    """One log row in COLUMNS order (the lockstep harness and droid-seamtrack both use it).

    ``lead``: the lead sensor's Reading (droid.tasks.seam.delay); ``tool``: the
    tool-tip sensor's (lateral, depth [mm], roll [rad]) or None; ``out``: the
    core's last CycleOutput, or None before the first cycle.  Yaw and pitch of
    the sensor pair come from the two sensors' data (Figure 6.14).
    """
    nan = math.nan
    lat, dep, roll = (lead.y_mm, lead.x_mm, lead.roll_rad) if lead.valid else (nan, nan, nan)
    tlat, tdep, troll = tool if tool is not None else (nan, nan, nan)
    yaw = math.degrees(math.atan2(lat - tlat, camera_to_tcp_mm))
    pitch = math.degrees(math.atan2(dep - tdep, camera_to_tcp_mm))
    if out is None:
        return (s_mm, lat, dep, roll, tlat, tdep, troll, yaw, pitch, t_s, 0.0, "dead_zone", int(lead.valid),
                0.0, 0.0, "off")
    return (s_mm, lat, dep, roll, tlat, tdep, troll, yaw, pitch, t_s, out.travel_mm,
            PHASE_CODES.get(out.phase, out.phase), int(lead.valid), math.degrees(out.yaw_rad),
            math.degrees(out.pitch_rad), out.delay_state)


# ---------------------------------------------------------------- CSV

def _cell(name: str, value) -> str:
    if name in TEXT_COLUMNS:
        return str(value)
    if name in INT_COLUMNS:
        return str(int(value))
    v = float(value)
    return "nan" if math.isnan(v) else repr(v)  # repr: the shortest text that reads back exactly


def write_csv(path: str | os.PathLike, rows: Iterable[Sequence]) -> int:
    """Write a log (rows in :data:`COLUMNS` order) as CSV with a header line; returns the row count."""
    n = 0
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for row in rows:
            if len(row) != len(COLUMNS):
                raise ValueError(f"row {n}: {len(row)} values, expected {len(COLUMNS)}")
            w.writerow([_cell(c, v) for c, v in zip(COLUMNS, row)])
            n += 1
    return n


def _parse(name: str, text: str, where: str):
    if name in TEXT_COLUMNS:
        return text
    try:
        return int(text) if name in INT_COLUMNS else float(text)
    except ValueError:
        raise BadInput(f"{where}: column {name}: not a number: {text!r}") from None


def read_csv(path: str | os.PathLike) -> list[tuple]:
    """Read a log written by :func:`write_csv` back into rows in :data:`COLUMNS` order.

    The required columns must be present (in any order); a missing extra
    column reads as NaN (numbers) or "" (text); unknown columns are ignored.
    """
    path = os.fspath(path)
    try:
        f = open(path, newline="")
    except OSError as exc:
        raise BadInput(f"{path}: {exc.strerror}") from None
    with f:
        reader = csv.reader(f)
        header = next(reader, None)
        if header is None:
            raise BadInput(f"{path}: empty file, expected a header line")
        missing = [c for c in REQUIRED_COLUMNS if c not in header]
        if missing:
            raise BadInput(f"{path}: missing columns {', '.join(missing)}")
        index = {c: header.index(c) if c in header else None for c in COLUMNS}
        rows = []
        for lineno, rec in enumerate(reader, start=2):
            if len(rec) != len(header):
                raise BadInput(f"{path}:{lineno}: {len(rec)} fields, expected {len(header)}")
            rows.append(tuple(_parse(c, rec[i], f"{path}:{lineno}") if i is not None
                              else ("" if c in TEXT_COLUMNS else math.nan) for c, i in index.items()))
    return rows


def column(rows: Sequence[Sequence], name: str) -> np.ndarray:
    """One numeric column of a log as a float array."""
    i = COLUMNS.index(name)
    return np.array([r[i] for r in rows], dtype=float)


# ---------------------------------------------------------------- summary

@dataclass(frozen=True)
class Summary:
    """How well one run tracked (all lengths in mm; NaN where no row qualifies)."""

    trial_id: str
    rows: int
    settle_s_mm: float  # rows with s_mm > this count
    settled_rows: int
    rms_lateral_mm: float
    max_lateral_mm: float  # max |tool_lateral_mm|
    rms_depth_mm: float
    max_depth_mm: float  # max |tool_depth_mm|
    end_s_mm: float  # the largest seam length logged
    seam_lost: bool
    lost_s_mm: float  # where the seam was lost (NaN if not)
    stop_reason: str
    stop_detail: str
    stop_s_mm: float
    travel_speed_mm_s: float = math.nan  # achieved: the slope of s_mm over t_s after settling [mm/s]
    commanded_mm_s: float = math.nan  # the commanded travel speed [mm/s] (NaN: not given)

    def as_dict(self) -> dict:
        return asdict(self)


def _rms_max(v: np.ndarray) -> tuple[float, float]:
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan
    return float(np.sqrt(np.mean(v * v))), float(np.max(np.abs(v)))


def summarize(rows: Sequence[Sequence], *, trial_id: str = "", stop_reason: str = "", stop_detail: str = "",
              stop_s_mm: float = math.nan, camera_to_tcp_mm: float = DEFAULT_CAMERA_TO_TCP_MM,
              commanded_mm_s: float = math.nan) -> Summary:
    """RMS and max tool error after settling, and how and where the run ended (see the module docstring).

    ``stop_s_mm``: the seam length at which the run stopped; a ``stop_reason``
    of "seam lost" (droid.tasks.seam.stops.STOP_LOST) marks the seam as lost there.
    """
    settle = camera_to_tcp_mm + SETTLE_EXTRA_MM
    s = column(rows, "s_mm") if rows else np.zeros(0)
    after = np.isfinite(s) & (s > settle)
    lat = column(rows, "tool_lateral_mm")[after] if rows else s
    dep = column(rows, "tool_depth_mm")[after] if rows else s
    rms_lat, max_lat = _rms_max(lat)
    rms_dep, max_dep = _rms_max(dep)
    finite_s = s[np.isfinite(s)]
    lost = stop_reason == STOP_LOST
    speed = math.nan
    if rows and int(after.sum()) >= 3:
        t = column(rows, "t_s")[after]
        if np.ptp(t) > 0:
            speed = float(np.polyfit(t, s[after], 1)[0])
    return Summary(trial_id=trial_id, rows=len(rows), settle_s_mm=settle, settled_rows=int(after.sum()),
                   rms_lateral_mm=rms_lat, max_lateral_mm=max_lat, rms_depth_mm=rms_dep, max_depth_mm=max_dep,
                   end_s_mm=float(finite_s.max()) if finite_s.size else math.nan, seam_lost=lost,
                   lost_s_mm=float(stop_s_mm) if lost else math.nan, stop_reason=stop_reason,
                   stop_detail=stop_detail, stop_s_mm=float(stop_s_mm), travel_speed_mm_s=speed,
                   commanded_mm_s=float(commanded_mm_s))


def _mm(v: float) -> str:
    return "n/a" if math.isnan(v) else f"{v:.2f} mm"


def summary_line(summary: Summary) -> str:
    """One line: the errors after settling and how the run ended, units included."""
    su = summary
    head = f"{su.trial_id}: " if su.trial_id else ""
    errors = (f"tool lateral RMS {_mm(su.rms_lateral_mm)} max {_mm(su.max_lateral_mm)}, "
              f"depth RMS {_mm(su.rms_depth_mm)} max {_mm(su.max_depth_mm)} "
              f"(s > {su.settle_s_mm:.0f} mm, {su.settled_rows} rows)")
    where = "" if math.isnan(su.stop_s_mm) else f" at s {su.stop_s_mm:.1f} mm"
    if su.seam_lost:
        end = f"seam LOST{where}"
    else:
        end = f"{su.stop_reason or 'no stop reason'}{where}; seam not lost"
    detail = f" ({su.stop_detail})" if su.stop_detail and not su.stop_reason.startswith("end of seam") else ""
    speed = ""
    if not math.isnan(su.commanded_mm_s):
        got = "n/a" if math.isnan(su.travel_speed_mm_s) else f"{su.travel_speed_mm_s:.1f} mm/s"
        speed = f"; travel speed {got} (commanded {su.commanded_mm_s:g} mm/s)"
    return f"{head}{errors}{speed}; {end}{detail}"


# ---------------------------------------------------------------- summary tables

def summary_table_row(summary: Summary) -> dict:
    """The numeric part of a summary-table row (mm, 3 decimals; "" for NaN)."""
    def f(v: float) -> str:
        return "" if math.isnan(v) else f"{v:.3f}"
    su = summary
    return {"rms_lateral_mm": f(su.rms_lateral_mm), "max_lateral_mm": f(su.max_lateral_mm),
            "rms_depth_mm": f(su.rms_depth_mm), "max_depth_mm": f(su.max_depth_mm),
            "seam_lost": "yes" if su.seam_lost else "no", "stop_reason": su.stop_reason,
            "stop_s_mm": f(su.stop_s_mm)}


def write_table(csv_path: str | os.PathLike, md_path: str | os.PathLike, records: Sequence[dict],
                title: str = "") -> None:
    """Write records (dicts with the same keys, in order) as a CSV and a Markdown table."""
    if not records:
        raise ValueError("no records")
    keys = list(records[0])
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(records)
    lines = [f"# {title}", ""] if title else []
    lines.append("| " + " | ".join(keys) + " |")
    lines.append("|" + "|".join("---" for _ in keys) + "|")
    for r in records:
        lines.append("| " + " | ".join(str(r[k]).replace("|", "/") for k in keys) + " |")
    with open(md_path, "w") as f:
        f.write("\n".join(lines) + "\n")


# ---------------------------------------------------------------- repeatability (experiment 4)

STD_COLUMNS = ("lead_lateral_mm", "tool_lateral_mm", "lead_depth_mm", "tool_depth_mm")


def std_across_runs(runs: Sequence[Sequence[Sequence]], step_mm: float = 2.0,
                    names: Sequence[str] = STD_COLUMNS) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Per-seam-length standard deviation of columns across repeated runs (§6.2.6, Figures 6.31-6.32).

    Each run is resampled (linear interpolation against ``s_mm``, NaN rows
    dropped) on a common grid every ``step_mm`` over the seam length all runs
    cover; the sample standard deviation (ddof = 1) is taken across runs at
    each grid point.  Returns (s grid [mm], {column: std [mm]}).
    """
    if len(runs) < 2:
        raise ValueError("need at least 2 runs for a standard deviation")
    spans = []
    for rows in runs:
        s = column(rows, "s_mm")
        s = s[np.isfinite(s)]
        if s.size < 2:
            raise ValueError("a run has fewer than 2 rows with a seam length")
        spans.append((s.min(), s.max()))
    lo, hi = max(a for a, _ in spans), min(b for _, b in spans)
    if not hi > lo:
        raise ValueError("the runs share no seam length")
    grid = np.arange(math.ceil(lo / step_mm) * step_mm, hi + 1e-9, step_mm)
    out = {}
    for name in names:
        stack = []
        for rows in runs:
            s, v = column(rows, "s_mm"), column(rows, name)
            ok = np.isfinite(s) & np.isfinite(v)
            order = np.argsort(s[ok], kind="stable")
            stack.append(np.interp(grid, s[ok][order], v[ok][order]) if ok.sum() >= 2
                         else np.full(grid.shape, np.nan))
        out[name] = np.std(np.vstack(stack), axis=0, ddof=1)
    return grid, out


def write_std_csv(path: str | os.PathLike, grid: np.ndarray, stds: dict[str, np.ndarray]) -> None:
    """The standard deviations as CSV: s_mm, then std_<column> per column [mm]."""
    names = list(stds)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["s_mm"] + [f"std_{n}" for n in names])
        for i, s in enumerate(grid):
            w.writerow([repr(float(s))] + [_cell("x", stds[n][i]) for n in names])


# ---------------------------------------------------------------- figures

PANELS = ("errors", "angles")
_LEAD, _TOOL = dict(color="tab:blue", lw=0.9, label="lead sensor"), dict(color="tab:red", lw=0.9, label="tool")


def _canvas(n_panels: int, title: str):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 1.9 * n_panels + 0.6), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(n_panels, 1, sharex=True, squeeze=False)[:, 0]
    fig.suptitle(title, fontsize=10)
    return fig, axes


def figure(path: str | os.PathLike, rows: Sequence[Sequence], title: str = "", panels: str = "errors",
           *, settle_s_mm: float | None = None, stop_s_mm: float = math.nan, stop_label: str = "") -> None:
    """A PNG of one run in the style of Figures 6.5-6.35: stacked panels against seam length s [mm].

    ``panels="errors"``: lateral (lead, tool) [mm], depth (lead, tool) [mm],
    roll (tool) [rad] -- Figures 6.5-6.13, 6.20-6.28.  ``panels="angles"``
    adds the yaw and pitch angles from the two sensors [deg] (Figure 6.14;
    Figures 6.17-6.19, 6.29-6.30, 6.34-6.35).  A dotted line marks the end of
    settling, a red one where the run stopped early.
    """
    if panels not in PANELS:
        raise BadInput(f"unknown panels {panels!r} (known: {', '.join(PANELS)})")
    s = column(rows, "s_mm") if rows else np.zeros(0)
    spec = [("lateral [mm]", [("lead_lateral_mm", _LEAD), ("tool_lateral_mm", _TOOL)]),
            ("depth [mm]", [("lead_depth_mm", _LEAD), ("tool_depth_mm", _TOOL)]),
            ("roll [rad]", [("tool_roll_rad", _TOOL)])]
    if panels == "angles":
        spec += [("yaw [deg]", [("yaw_deg", dict(color="tab:green", lw=0.9, label="yaw"))]),
                 ("pitch [deg]", [("pitch_deg", dict(color="tab:purple", lw=0.9, label="pitch"))])]
    fig, axes = _canvas(len(spec), title)
    for ax, (ylabel, series) in zip(axes, spec):
        for name, style in series:
            ax.plot(s, column(rows, name) if rows else s, **style)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.grid(True, lw=0.3, alpha=0.6)
        ax.tick_params(labelsize=7)
        if settle_s_mm is not None:
            ax.axvline(settle_s_mm, color="0.4", lw=0.7, ls=":")
        if not math.isnan(stop_s_mm):
            ax.axvline(stop_s_mm, color="red", lw=0.8, ls="--")
        ax.legend(fontsize=7, loc="upper left", frameon=False, ncol=2)
    if stop_label and not math.isnan(stop_s_mm):
        axes[0].annotate(stop_label, (stop_s_mm, 1.0), xycoords=("data", "axes fraction"), fontsize=7,
                         color="red", ha="right", va="bottom")
    axes[-1].set_xlabel("seam length s [mm]", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, format="png")


def std_figure(path: str | os.PathLike, grid: np.ndarray, stds: dict[str, np.ndarray], title: str = "") -> None:
    """Standard deviations against seam length (Figures 6.31 lateral, 6.32 depth), two stacked panels."""
    fig, axes = _canvas(2, title)
    for ax, (ylabel, lead, tool) in zip(axes, [("lateral std [mm]", "lead_lateral_mm", "tool_lateral_mm"),
                                               ("depth std [mm]", "lead_depth_mm", "tool_depth_mm")]):
        if lead in stds:
            ax.plot(grid, stds[lead], **_LEAD)
        if tool in stds:
            ax.plot(grid, stds[tool], **_TOOL)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.grid(True, lw=0.3, alpha=0.6)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=7, loc="upper left", frameon=False)
    axes[-1].set_xlabel("seam length s [mm]", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, format="png")


__all__ = ["COLUMNS", "REQUIRED_COLUMNS", "COLUMN_DOCS", "SETTLE_EXTRA_MM", "Summary", "write_csv", "read_csv",
           "column", "summarize", "summary_line", "summary_table_row", "write_table", "std_across_runs",
           "write_std_csv", "figure", "std_figure"]
