"""Seam-tracking logs: the 10 Hz CSV row, the summary and the figure (thesis §6.1, §6.2).

Shared by the real-time task program (droid-seamtrack) and the lockstep
experiments (droid.sim.experiment): one row layout, one summary definition.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass

import numpy as np

#: CSV columns: the thesis's quantities first (§6.1: lead and tool-tip sensor
#: lateral/depth [mm] and roll [rad], the yaw/pitch angles of Figure 6.14 [deg]).
COLUMNS = ("s_mm", "lead_lateral_mm", "lead_depth_mm", "lead_roll_rad", "tool_lateral_mm", "tool_depth_mm",
           "tool_roll_rad", "yaw_deg", "pitch_deg", "t_s", "travel_mm", "phase", "lead_valid",
           "ctrl_yaw_deg", "ctrl_pitch_deg", "delay_state")
PHASE_CODES = {"dead zone": "dead_zone", "initial": "initial", "tracking": "tracking"}
SETTLE_EXTRA_MM = 50.0  # settling: the initial section (CAMERA_TO_TCP) + 50 mm


def log_row(*, s_mm: float, t_s: float, lead, tool, out, camera_to_tcp_mm: float) -> tuple:
    """One CSV row.  ``lead``: a Reading; ``tool``: (lateral, depth [mm], roll [rad]) or None;
    ``out``: the core's last CycleOutput (or None before the first cycle)."""
    nan = math.nan
    lv = bool(lead.valid)
    lat, dep, roll = (lead.y_mm, lead.x_mm, lead.roll_rad) if lv else (nan, nan, nan)
    tlat, tdep, troll = tool if tool is not None else (nan, nan, nan)
    L = camera_to_tcp_mm
    yaw = math.degrees(math.atan2(lat - tlat, L))  # Figure 6.14: from the two sensors' data
    pitch = math.degrees(math.atan2(dep - tdep, L))
    phase = PHASE_CODES.get(out.phase, out.phase) if out is not None else "dead_zone"
    return (s_mm, lat, dep, roll, tlat, tdep, troll, yaw, pitch, t_s,
            out.travel_mm if out is not None else 0.0, phase, int(lv),
            math.degrees(out.yaw_rad) if out is not None else 0.0,
            math.degrees(out.pitch_rad) if out is not None else 0.0,
            out.delay_state if out is not None else "off")


def write_csv(path, rows) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow(["" if isinstance(v, float) and math.isnan(v) else
                         (f"{v:.6g}" if isinstance(v, float) else v) for v in r])


def column(rows, name: str) -> np.ndarray:
    i = COLUMNS.index(name)
    return np.array([r[i] for r in rows], dtype=float)


@dataclass(frozen=True)
class Summary:
    rms_lateral_mm: float
    max_lateral_mm: float
    rms_depth_mm: float
    max_depth_mm: float
    stop_reason: str
    lost: bool
    stop_s_mm: float
    rows: int


def summarize(rows, camera_to_tcp_mm: float, stop_reason: str = "", stop_s_mm: float = math.nan) -> Summary:
    """RMS and max |tool error| after settling (s > CAMERA_TO_TCP + 50 mm), and how the run ended."""
    if rows:
        s = column(rows, "s_mm")
        settled = s > camera_to_tcp_mm + SETTLE_EXTRA_MM
        lat = column(rows, "tool_lateral_mm")[settled]
        dep = column(rows, "tool_depth_mm")[settled]
        if math.isnan(stop_s_mm):
            stop_s_mm = float(s[-1])
    else:
        lat = dep = np.zeros(0)

    def rms(a):
        a = a[np.isfinite(a)]
        return float(np.sqrt(np.mean(a ** 2))) if a.size else math.nan

    def mx(a):
        a = a[np.isfinite(a)]
        return float(np.max(np.abs(a))) if a.size else math.nan

    return Summary(rms(lat), mx(lat), rms(dep), mx(dep), stop_reason, "lost" in stop_reason, stop_s_mm, len(rows))


def summary_line(s: Summary) -> str:
    lost = f"seam lost at s {s.stop_s_mm:.0f} mm" if s.lost else "seam not lost"
    return (f"tool error after settling: lateral RMS {s.rms_lateral_mm:.2f} mm max {s.max_lateral_mm:.2f} mm, "
            f"depth RMS {s.rms_depth_mm:.2f} mm max {s.max_depth_mm:.2f} mm; {lost}; stop: {s.stop_reason}")


def figure(path, rows, title: str, panels: str = "errors") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = column(rows, "s_mm")
    fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    for ax, (lead, tool, label) in zip(axes, (("lead_lateral_mm", "tool_lateral_mm", "lateral [mm]"),
                                             ("lead_depth_mm", "tool_depth_mm", "depth [mm]"),
                                             ("lead_roll_rad", "tool_roll_rad", "roll [rad]"))):
        ax.plot(s, column(rows, lead), label="lead sensor")
        ax.plot(s, column(rows, tool), label="tool")
        ax.set_ylabel(label)
        ax.grid(True)
    axes[0].legend()
    axes[0].set_title(title)
    axes[-1].set_xlabel("seam length s [mm]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
