"""droid-experiment's jobs: one trial as a worker runs it, and what comes back (issue 25 item 4).

A :class:`Job` (an experiment of the chapter-6 matrix, or a plan's trial: thesis §6.2; a
contact plan's force-control trial: §7.3) goes to a worker -- this process, a local pool
(droid.experiments.localpool) or a Dask cluster (droid.experiments.cluster) -- and
:func:`run_job` returns its :class:`Outcome`: the 10 Hz log, the summary, the figure's PNG
bytes or why there is none.  :func:`store` writes a trial's files.  The command line
(droid.experiments.cli) builds the jobs and writes the tables; the job model lives here so the
runners import it without importing the command line.
"""
from __future__ import annotations

import json
import math
import os
import tempfile
import time
from dataclasses import dataclass, replace

from droid.cli import BadInput
from droid.experiments import phases
from droid.experiments.matrix import Experiment
from droid.experiments.plan import TRIAL_CONTACT, PlanTrial
from droid.tasks.seam import report
from droid.tasks.seam.stops import STOP_END


@dataclass(frozen=True)
class Job:
    exp: Experiment  # or a plan.PlanTrial (both have .id, .table, .config)
    out_dir: str  # DIR/<table>
    figures: bool
    realtime: bool = False
    record: bool = False  # also write DIR/<table>/<id>.mcap (droid.observe, docs/observe.md)


@dataclass(frozen=True)
class Outcome:
    exp: Experiment
    summary: report.Summary | None  # a contact plan trial's: contact_trial.ContactSummary
    error: str = ""
    sim_s: float = math.nan
    wall_s: float = math.nan
    rows: tuple = ()  # the 10 Hz log (written by the parent: a Dask worker may be another machine)
    png: bytes | None = None  # the figure, rendered by the worker
    figure_error: str = ""  # why there is no figure (one line), e.g. matplotlib missing
    stored: bool = False  # its files were written by the worker (a local process)


#: The one line a figure path ends with when matplotlib is missing (issue 15: never a traceback).
NO_MATPLOTLIB = "no figures: matplotlib is not installed (pip install matplotlib)"


def render_figure(rows, cfg, summary: report.Summary, result) -> tuple[bytes | None, str]:
    """The trial's figure as PNG bytes, or (None, one-line reason)."""
    early = not result.stop_reason.startswith(STOP_END)
    return _render(lambda path: report.figure(
        path, rows, cfg.title or cfg.trial_id, cfg.panels, settle_s_mm=summary.settle_s_mm,
        stop_s_mm=result.stop_s_mm if early else math.nan, stop_label=result.stop_reason if early else ""))


def _render(draw) -> tuple[bytes | None, str]:
    """``draw(path)``'s PNG as bytes, or (None, one-line reason: matplotlib missing)."""
    fd, path = tempfile.mkstemp(suffix=".png", prefix="droid-exp-")
    os.close(fd)
    try:
        draw(path)
        with open(path, "rb") as f:
            return f.read(), ""
    except ImportError:
        return None, NO_MATPLOTLIB
    finally:
        try:
            os.unlink(path)
        except OSError:
            pass


def run_job(job: Job) -> Outcome:
    """Run one trial; return its log, summary and figure (the parent writes the files).

    A trial that cannot start (BadInput: e.g. a start the arm cannot reach)
    is an Outcome with an error."""
    phases.mark("trial", trial=job.exp.id)
    if is_contact(job.exp):
        return run_contact_job(job)
    cfg = job.exp.config
    if job.realtime:
        from droid.experiments.realtime import run_trial_realtime

        os.makedirs(job.out_dir, exist_ok=True)
        result = run_trial_realtime(cfg, job.out_dir)
    else:
        from droid.experiments.trial import run_trial

        try:
            if job.record:
                os.makedirs(job.out_dir, exist_ok=True)
            result = run_trial(cfg, record=os.path.join(job.out_dir, job.exp.id + ".mcap") if job.record else None)
        except BadInput as exc:
            return Outcome(job.exp, None, str(exc))
        except Exception as exc:  # noqa: BLE001 -- one trial's failure must not end the sweep: exit 1, named
            return Outcome(job.exp, None, f"the trial failed: {type(exc).__name__}: {exc}")
    summary = report.summarize(result.rows, trial_id=job.exp.id, stop_reason=result.stop_reason,
                               stop_detail=result.stop_detail, stop_s_mm=result.stop_s_mm,
                               camera_to_tcp_mm=result.camera_to_tcp_mm, commanded_mm_s=cfg.speed_mm_s)
    png, why = render_figure(result.rows, cfg, summary, result) if job.figures else (None, "")
    phases.mark("figure")
    return Outcome(job.exp, summary, sim_s=result.sim_s, wall_s=result.wall_s, rows=tuple(result.rows),
                   png=png, figure_error=why)


def is_contact(exp) -> bool:
    """A trial of a contact plan (``trial = "contact"``: droid.experiments.contact_trial)."""
    return isinstance(exp, PlanTrial) and exp.kind == TRIAL_CONTACT


def run_contact_job(job: Job) -> Outcome:
    """One force-control trial of a contact plan (thesis §7.3): its rows, figures and PNG."""
    from droid.experiments.contact_trial import run_contact_trial

    t = job.exp
    t0 = time.perf_counter()
    try:
        result = run_contact_trial(t.config)
    except BadInput as exc:
        return Outcome(t, None, str(exc))
    except Exception as exc:  # noqa: BLE001 -- one trial's failure must not end the sweep: exit 1, named
        return Outcome(t, None, f"the trial failed: {type(exc).__name__}: {exc}")
    wall = time.perf_counter() - t0
    su = replace(result.figures, trial_id=t.id)
    png, why = None, ""
    if job.figures:
        from droid.experiments.contact_report import figure

        p = t.params
        title = (f"{t.table} {t.id}: {p['force_n']:g} N at {p['speed_mm_s']:g} mm/s, seed {p['seed']}, "
                 f"stop: {su.stop}")
        png, why = _render(lambda path: figure(path, result.rows, su, title))
    phases.mark("figure")
    return Outcome(t, su, sim_s=result.sim_s, wall_s=wall, rows=tuple(result.rows), png=png, figure_error=why)


def store(job: Job, o: Outcome) -> None:
    """Write a trial's files: CSV, PNG, and for a plan trial its JSON record (last: its results exist)."""
    os.makedirs(job.out_dir, exist_ok=True)
    base = os.path.join(job.out_dir, job.exp.id)
    if o.summary is None:
        return
    if is_contact(job.exp):
        from droid.experiments.contact_trial import write_csv

        write_csv(base + ".csv", list(o.rows))
    else:
        report.write_csv(base + ".csv", o.rows)
    if o.png is not None:
        _write_atomic(base + ".png", o.png)
    if isinstance(job.exp, PlanTrial):
        record = {"trial_id": job.exp.id, "index": job.exp.index, "params": job.exp.params,
                  "summary": o.summary.as_dict(), "sim_s": o.sim_s}
        _write_atomic(base + ".json", json.dumps(json_safe(record), indent=1).encode())


def _write_atomic(path: str, data: bytes) -> None:
    tmp = path + ".part"
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def json_safe(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [json_safe(x) for x in v]
    return v


def run_and_store(job: Job) -> Outcome:
    """A local worker's job: the trial, its files written here (the same disk as the parent's),
    and a small result back -- no 10 Hz log or figure through the pipe."""
    o = run_job(job)
    store(job, o)
    return replace(o, rows=(), png=None, stored=True)
