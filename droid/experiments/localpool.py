"""Trials on the local cores: one process per core, one pipe each, nothing shared.

``multiprocessing.Pool`` was the first choice; its workers share one result queue
guarded by a lock, and a worker terminated while it held that lock (sending a trial's
large result) left ``Pool.terminate()`` waiting for ever: after a Ctrl-C under load the
sweep did not exit within 120 s (issue 16).  Here each worker has its own duplex pipe,
takes one job at a time and sends back one result; on Ctrl-C or an error every worker is
killed (SIGKILL) and reaped -- no lock can be left held, nothing waits on a dead process.
A worker that dies in a trial gives that trial an error result and is replaced.

Workers start (fork where the OS has it) with SIGINT blocked, ignore it, then unblock:
Ctrl-C reaches the whole process group, only the parent acts on it.
"""
from __future__ import annotations

import multiprocessing
import signal
from multiprocessing.connection import wait
from typing import Callable, Iterable


def _worker(conn, fn: Callable) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    while True:
        try:
            job = conn.recv()
        except EOFError:
            return
        if job is None:
            return
        conn.send(fn(job))


def run_local(jobs: Iterable, workers: int, fn: Callable, failed: Callable, on_result: Callable) -> None:
    """Run ``fn(job)`` for every job on ``workers`` processes; ``on_result(job, result)`` in the
    parent as each arrives (a worker that died: ``on_result(job, failed(job, why))``)."""
    todo = list(jobs)
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods else None)
    live: dict = {}  # conn -> [process, job or None]
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})

    def start():
        parent, child = ctx.Pipe(duplex=True)
        p = ctx.Process(target=_worker, args=(child, fn), daemon=True)
        p.start()
        child.close()
        live[parent] = [p, None]
        return parent

    def feed(conn) -> None:
        job = todo.pop(0) if todo else None
        live[conn][1] = job
        conn.send(job)
        if job is None:  # nothing left for it: it exits
            live[conn][0].join()
            conn.close()
            del live[conn]

    try:
        for _ in range(min(workers, len(todo))):
            start()
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)  # a pending Ctrl-C is raised here
        for conn in list(live):
            feed(conn)
        while live:
            by_sentinel = {v[0].sentinel: c for c, v in live.items()}
            for ready in wait(list(live) + list(by_sentinel)):
                conn = by_sentinel.get(ready, ready)
                if conn not in live:
                    continue
                proc, job = live[conn]
                try:
                    result = conn.recv()
                except (EOFError, OSError):  # the worker died in this job
                    proc.join()
                    conn.close()
                    del live[conn]
                    on_result(job, failed(job, f"its worker process died (exit {proc.exitcode})"))
                    if todo:
                        feed(start())
                    continue
                on_result(job, result)
                feed(conn)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        for proc, _ in live.values():  # Ctrl-C or an error: stop every worker now
            if proc.is_alive():
                proc.kill()
        for conn, (proc, _) in list(live.items()):
            proc.join()
            conn.close()
