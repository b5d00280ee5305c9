"""droid-experiment's trials on a Dask distributed cluster (issue 15; docs/experiments.md).

``--dask tcp://HOST:8786`` connects to a running scheduler (``dask scheduler``
on one machine, ``dask worker tcp://HOST:8786 --nthreads 1`` on each of the
others, every one with this droid importable); ``--dask local`` starts a
LocalCluster of ``--jobs`` single-threaded worker processes on loopback.
Each trial is one task (``run_job``: it returns the log, the summary and the
figure's bytes); this process gathers them as they finish, behind the same
progress bar, and writes every file -- so the workers need no shared output
directory.  A trial's numbers do not depend on where it ran (lockstep,
seeded): a plan gives the same ``results.csv`` on the pool and on a cluster.

A scheduler that does not answer within :data:`CONNECT_TIMEOUT_S` is a
RuntimeFailure (exit 1) naming the address.  On Ctrl-C the trials not yet
finished are cancelled and the client (and a local cluster) closed.
"""
from __future__ import annotations

import logging
import signal
import sys
import threading
import uuid
from typing import Callable

from droid.cli import RuntimeFailure
from droid.experiments.jobs import Outcome

#: How long to wait for the scheduler to answer [s] (the issue's bound: exit 1 within 10 s).
CONNECT_TIMEOUT_S = 5.0


#: Above CRITICAL: a cluster closed under a Ctrl-C logs "CRITICAL - Closed comm ..." tracebacks from
#: its scheduler (a race seen in 1 of 3 suite runs); our own code reports every real failure.
QUIET_LEVEL = logging.CRITICAL + 1


def _quiet() -> None:
    # distributed logs every connection attempt and a closing cluster's chatter on stderr
    for name in ("distributed", "distributed.client", "distributed.core", "distributed.comm",
                 "distributed.scheduler", "distributed.nanny", "distributed.worker", "tornado"):
        logging.getLogger(name).setLevel(QUIET_LEVEL)


def connect(address: str, workers: int):
    """(client, cluster or None) for ``--dask ADDRESS``; RuntimeFailure names an address that does not answer."""
    _quiet()
    from distributed import Client

    if address == "local":
        from distributed import LocalCluster

        # Ctrl-C reaches the whole process group: the workers ignore it (inherited SIG_IGN, as the
        # pool's), this process cancels the trials and closes the cluster
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=None, silence_logs=QUIET_LEVEL)
        except Exception as exc:  # noqa: BLE001 -- any failure to start is one line
            raise RuntimeFailure(f"--dask local: could not start a LocalCluster: {exc}") from None
        finally:
            signal.signal(signal.SIGINT, previous)
        return Client(cluster), cluster
    # Client's own timeout bounds the TCP connect, not a peer that accepts and never answers (measured:
    # hung for 10 min on a silent listener): connect in a daemon thread and stop waiting at the bound.
    box: dict = {}

    def attempt() -> None:
        try:
            box["client"] = Client(address, timeout=CONNECT_TIMEOUT_S)
        except BaseException as exc:  # noqa: BLE001 -- reported by the waiting thread
            box["error"] = exc

    worker = threading.Thread(target=attempt, name="droid-dask-connect", daemon=True)
    worker.start()
    worker.join(CONNECT_TIMEOUT_S + 0.5)
    if "client" in box:
        return box["client"], None
    exc = box.get("error")
    if isinstance(exc, ValueError):
        raise RuntimeFailure(f"--dask {address}: {exc}")
    if exc is None:
        why = "no answer"
    elif isinstance(exc, (OSError, TimeoutError)):
        why = type(exc).__name__
    else:  # it answered, but not as a scheduler (measured: a proxy's bytes read as a 3 EiB frame length)
        why = f"the peer does not speak Dask's protocol: {type(exc).__name__}"
    raise RuntimeFailure(f"--dask {address}: no Dask scheduler answers there within {CONNECT_TIMEOUT_S:g} s "
                         f"({why})")


def run_on_dask(jobs: list, address: str, workers: int, run_job: Callable, done: Callable,
                progress: Callable) -> None:
    """Submit every job, call ``done(job, outcome)`` as each finishes (a failed task: an error Outcome)."""
    from distributed import as_completed


    client, cluster = connect(address, workers)
    try:
        if not client.scheduler_info().get("workers"):
            print(f"droid-experiment: --dask {address}: the scheduler has no workers yet; the trials wait for one",
                  file=sys.stderr)
    except Exception:  # noqa: BLE001 -- only a courtesy
        pass
    run_key = uuid.uuid4().hex[:8]
    futures = {}
    try:
        for job in jobs:
            fut = client.submit(run_job, job, key=f"droid-trial-{job.exp.id}-{run_key}", pure=False, retries=0)
            futures[fut] = job
        with progress(len(jobs)) as bar:
            for fut in as_completed(futures):
                job = futures[fut]
                try:
                    outcome = fut.result()
                except Exception as exc:  # noqa: BLE001 -- a worker died, or the trial raised
                    outcome = Outcome(job.exp, None, f"on the Dask cluster: {type(exc).__name__}: {exc}")
                done(job, outcome)
                bar.update()
    finally:
        try:
            client.cancel(list(futures), force=True)
        except Exception:  # noqa: BLE001 -- closing anyway
            pass
        client.close(timeout=10)
        if cluster is not None:
            cluster.close(timeout=10)
