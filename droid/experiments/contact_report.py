"""Figures and tables of the force-control trials a contact plan sweeps (issue 27 item 5;
thesis §7.3; docs/contact.md, "Sweeps").

* :func:`figure`: one trial's PNG, three panels against time [s]: the force error [N]
  (the sensor's, and the contact model's true one; scaled to the errors on the path: the
  approach's and the touch's larger ones run off it), the tool point's depth below the
  surface [mm] (its normal position), its speed along the path [mm/s] (and the set speed);
  dotted lines where the tool touched, where the path started and where settling ended, a
  red one where a trial stopped early.
* :func:`write_results`: ``results.csv`` (one row per trial of the plan, in plan order: the
  parameters, then :data:`RESULT_COLUMNS`) and ``results.md`` (the same as a table).

matplotlib is imported inside :func:`figure` only (Agg canvas, no pyplot).
"""
from __future__ import annotations

import csv
import math
import os
from typing import Callable, Sequence

from droid.experiments.contact_trial import COLUMNS, ContactSummary

#: results.csv: the figures after a trial's parameters (ContactSummary's fields, + sim_s and error).
RESULT_COLUMNS = ("cycles", "settled_cycles", "rms_n", "max_n", "max_path_n", "peak_force_n", "mean_speed_mm_s",
                  "mean_true_force_n", "min_true_force_n", "mean_friction_n", "path_mm", "stop", "stop_detail",
                  "sim_s", "error")
#: results.md: the columns shown (with the swept parameters before them)
_MD_COLUMNS = (("rms_n", "RMS error [N]"), ("max_n", "max error [N]"), ("peak_force_n", "peak force [N]"),
               ("min_true_force_n", "min true force [N]"), ("mean_speed_mm_s", "mean speed [mm/s]"),
               ("stop", "stop"))
_T, _PHASE, _F, _ERR, _TRUE = (COLUMNS.index(c) for c in ("t_s", "phase", "force_n", "force_error_n",
                                                             "true_force_n"))
_DEPTH, _SPEED = COLUMNS.index("depth_mm"), COLUMNS.index("speed_mm_s")


def _first_t(rows: Sequence[Sequence], phases: tuple[str, ...]) -> float:
    return next((float(r[_T]) for r in rows if r[_PHASE] in phases), math.nan)


def figure(path: str | os.PathLike, rows: Sequence[Sequence], su: ContactSummary, title: str = "") -> None:
    """The trial's PNG (module docstring); ``rows`` as run_contact_trial gives them (``COLUMNS``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 6.3), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    fig.suptitle(title, fontsize=10)
    t = [float(r[_T]) for r in rows]
    touch, path0 = _first_t(rows, ("settle", "path")), _first_t(rows, ("path",))
    settled = path0 + su.settle_after_s
    stop_t = t[-1] if t and su.stop != "end" else math.nan
    thin = dict(lw=0.9)
    axes[0].plot(t, [float(r[_ERR]) for r in rows], color="tab:red", label="sensor: F_set - F", **thin)
    axes[0].plot(t, [su.force_n - float(r[_TRUE]) for r in rows], color="tab:blue", ls="--", lw=0.7,
                 label="true: F_set - F_contact")
    axes[0].set_ylabel("force error [N]", fontsize=8)
    held = [r for r in rows if r[_PHASE] == "path"]
    if held:  # the scale of the force held on the path: the approach's and the touch's larger errors run off it
        span = max(1.0, 1.2 * max(max(abs(float(r[_ERR])), abs(su.force_n - float(r[_TRUE]))) for r in held))
        axes[0].set_ylim(-span, span)
        if max(abs(float(r[_ERR])) for r in rows) > span:
            axes[0].annotate("approach and touch: off scale", (0.01, 0.97), xycoords="axes fraction",
                             fontsize=7, color="0.3", ha="left", va="top")
    axes[1].plot(t, [float(r[_DEPTH]) for r in rows], color="tab:green", label="tool point below the surface",
                 **thin)
    axes[1].set_ylabel("depth [mm]", fontsize=8)
    axes[2].plot(t, [float(r[_SPEED]) for r in rows], color="tab:purple", label="tool point along the path",
                 **thin)
    axes[2].axhline(su.speed_mm_s, color="0.4", lw=0.7, ls="--", label=f"set {su.speed_mm_s:g} mm/s")
    axes[2].set_ylabel("speed [mm/s]", fontsize=8)
    for ax in axes:
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.grid(True, lw=0.3, alpha=0.6)
        ax.tick_params(labelsize=7)
        for x, style in ((touch, ":"), (path0, "-."), (settled, ":")):
            if math.isfinite(x):
                ax.axvline(x, color="0.4", lw=0.7, ls=style)
        if math.isfinite(stop_t):
            ax.axvline(stop_t, color="red", lw=0.8, ls="--")
        ax.legend(fontsize=7, loc="lower right", frameon=False)
    for x, label in ((touch, "touch"), (path0, "path"), (settled, "settled")):
        if math.isfinite(x):
            axes[0].annotate(label, (x, 1.0), xycoords=("data", "axes fraction"), fontsize=7, color="0.3",
                             ha="left", va="bottom")
    if math.isfinite(stop_t):
        axes[0].annotate(su.stop, (stop_t, 1.0), xycoords=("data", "axes fraction"), fontsize=7, color="red",
                         ha="right", va="bottom")
    axes[-1].set_xlabel("time from the approach's start [s]", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, format="png")


def _cell(v) -> str:
    """A results.csv cell: floats as repr (they read back exactly), NaN/None blank."""
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not math.isfinite(v) else repr(v)
    return str(v)


def _md(v) -> str:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.2f}"
    return "" if v is None else str(v).replace("|", "/")


def write_results(out_dir: str, plan, record_of: Callable, errors: dict[str, str]) -> str:
    """``results.csv`` and ``results.md`` of a contact plan, in plan order (``record_of(trial)``:
    its stored record or None; trials without results: blank figures and why).  Returns the CSV's path."""
    fields = plan.fields
    swept = [k for k in fields if k in plan.sweep]
    path, md_path = os.path.join(out_dir, "results.csv"), os.path.join(out_dir, "results.md")
    md = [f"# {plan.name} (contact trials)" + (f" -- {plan.description}" if plan.description else ""), "",
          "| index | trial | " + " | ".join(swept + [h for _, h in _MD_COLUMNS]) + " |",
          "|" + "---|" * (2 + len(swept) + len(_MD_COLUMNS))]
    tmp = path + ".part"
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(("index", "trial_id") + fields + RESULT_COLUMNS)
        for t in plan.trials:
            rec = record_of(t)
            row = [t.index, t.id] + [_cell(t.params[k]) for k in fields]
            shown = [_md(t.params[k]) for k in swept]
            if rec is None:
                why = errors.get(t.id, "not run")
                row += [""] * (len(RESULT_COLUMNS) - 1) + [why]
                shown += [""] * (len(_MD_COLUMNS) - 1) + [why]
            else:
                su = {**rec["summary"], "sim_s": rec.get("sim_s")}
                row += [_cell(su.get(k)) for k in RESULT_COLUMNS[:-1]] + [""]
                shown += [_md(math.nan if su.get(k) is None else su.get(k)) for k, _ in _MD_COLUMNS]
            w.writerow(row)
            md.append(f"| {t.index} | {t.id} | " + " | ".join(shown) + " |")
    os.replace(tmp, path)
    with open(md_path + ".part", "w") as f:
        f.write("\n".join(md) + "\n")
    os.replace(md_path + ".part", md_path)
    return path
