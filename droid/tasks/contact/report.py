"""The force task's log, summary line and figure (issue 27 item 5; docs/contact.md).

One row per controller cycle (:data:`COLUMNS`).  :func:`summary` gives the line that begins
``normal force RMS error X N, max Y N``, over the path after ``settle_after_s`` (the
errors as the path starts, while friction sets in, are the settling the issue excludes);
:func:`figure` draws force error, normal position and speed over time.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass

import numpy as np

#: t_s: since the first cycle [s]; phase: approach/settle/path; force_n: the sensor's normal force;
#: force_error_n: setpoint - force_n; depth_mm: the commanded touching point along the tool axis
#: from where the task started; normal_mm: the measured one (the arm's Status pose); along_mm:
#: measured travel along the path; speed_mm_s: measured speed along the path over the cycle.
COLUMNS = ("t_s", "phase", "force_n", "force_error_n", "depth_mm", "normal_mm", "along_mm", "speed_mm_s")
SETTLE_AFTER_S = 1.0  # the summary starts this long after the path starts [s]


@dataclass(frozen=True)
class Summary:
    rms_n: float
    max_n: float
    cycles: int
    mean_speed_mm_s: float
    peak_force_n: float

    def line(self, force_n: float, speed_mm_s: float, length_mm: float, stop: str, detail: str,
             settle_after_s: float = SETTLE_AFTER_S) -> str:
        return (f"normal force RMS error {self.rms_n:.2f} N, max {self.max_n:.2f} N (path after "
                f"{settle_after_s:g} s settling, {self.cycles} cycles); {force_n:g} N at {speed_mm_s:g} mm/s over "
                f"{length_mm:g} mm, mean speed {self.mean_speed_mm_s:.2f} mm/s, peak force {self.peak_force_n:.2f} N; "
                f"stop: {stop}{f' ({detail})' if detail else ''}")


def summary(rows, settle_after_s: float = SETTLE_AFTER_S) -> Summary:
    """Over the path rows from ``settle_after_s`` after the path's first row (COLUMNS order)."""
    path = [r for r in rows if r[1] == "path"]
    t_from = path[0][0] + settle_after_s if path else math.inf
    after = [r for r in path if r[0] >= t_from]
    errs = np.array([r[3] for r in after], float)
    speeds = np.array([r[7] for r in after], float)
    touched = [r[2] for r in rows if r[1] in ("settle", "path")]
    return Summary(rms_n=float(np.sqrt(np.mean(errs ** 2))) if len(errs) else math.nan,
                   max_n=float(np.max(np.abs(errs))) if len(errs) else math.nan,
                   cycles=len(errs),
                   mean_speed_mm_s=float(np.mean(speeds)) if len(speeds) else math.nan,
                   peak_force_n=float(max(touched)) if touched else math.nan)


def write_csv(path: str, rows) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([f"{r[0]:.4f}", r[1], *(f"{x:.4f}" for x in r[2:])])


def figure(path: str, rows, title: str, force_n: float) -> None:
    """Three panels over time: force error [N], normal position [mm], speed along the path [mm/s]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([r[0] for r in rows], float)
    fig, ax = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    ax[0].plot(t, [r[3] for r in rows], lw=0.8)
    ax[0].axhline(0.0, color="k", lw=0.5)
    ax[0].set_ylabel(f"force error [N]\n(setpoint {force_n:g} N)")
    ax[1].plot(t, [r[4] for r in rows], lw=0.8, label="commanded")
    ax[1].plot(t, [r[5] for r in rows], lw=0.8, label="measured")
    ax[1].set_ylabel("normal position [mm]")
    ax[1].legend(loc="best", fontsize=8)
    ax[2].plot(t, [r[7] for r in rows], lw=0.8)
    ax[2].set_ylabel("speed [mm/s]")
    ax[2].set_xlabel("time [s]")
    for a in ax:
        a.grid(True, lw=0.3)
    phases = [(r[0], r[1]) for i, r in enumerate(rows) if i == 0 or rows[i - 1][1] != r[1]]
    for t0, ph in phases:
        ax[0].axvline(t0, color="grey", lw=0.5, ls="--")
        ax[0].annotate(ph, (t0, 1.0), xycoords=("data", "axes fraction"), fontsize=7, va="top")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
