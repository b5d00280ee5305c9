"""droid.experiments.localpool: every job once, a dead worker's job named, nothing left running."""
from __future__ import annotations

import os

from droid.experiments.localpool import run_local


def _square_or_die(x: int) -> int:
    if x == 3:
        os._exit(7)  # a worker that dies in this job
    return x * x


def test_every_job_gets_one_result_and_a_dead_workers_job_an_error():
    got = {}
    run_local(range(8), 2, _square_or_die, lambda job, why: f"error: {why}",
              lambda job, r: got.setdefault(job, r))
    assert sorted(got) == list(range(8))
    assert got[3] == "error: its worker process died (exit 7)"
    assert all(got[k] == k * k for k in range(8) if k != 3)


def test_an_error_in_the_parent_kills_and_reaps_every_worker():
    seen = []

    def on_result(job, r):
        seen.append(job)
        raise RuntimeError("stop")  # as a Ctrl-C in the parent would

    try:
        run_local(range(6), 2, _square_or_die, lambda job, why: why, on_result)
    except RuntimeError:
        pass
    assert len(seen) == 1  # the conftest fixture checks that no child process is left
