"""Start droid-web as a process for a test and wait until it listens; stop a server process;
hold a port so that a server finds it taken."""
from __future__ import annotations

import contextlib
import json
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request

from tests.brain.cellutil import ROOT, free_port


def stop_process(proc: subprocess.Popen, timeout_s: float) -> None:
    """SIGTERM ``proc`` if it still runs, SIGKILL if it has not exited within ``timeout_s``; reaped."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextlib.contextmanager
def taken_port():
    """A loopback TCP port a listening socket holds for the ``with`` block (yields the port)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


class WebServer:
    def __init__(self, *args: str) -> None:
        self.port = free_port()
        self.proc = subprocess.Popen([sys.executable, "-m", "droid.observe.web", "--port", str(self.port), *args],
                                     cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.url = f"http://127.0.0.1:{self.port}/"
        deadline = time.monotonic() + 60
        while True:
            if self.proc.poll() is not None:
                raise AssertionError(f"droid-web exited {self.proc.returncode}: {self.proc.stderr.read()}")
            try:
                self.get("api/cell")
                return
            except urllib.error.HTTPError:
                return  # listening (e.g. 401 without the token)
            except OSError:
                if time.monotonic() > deadline:
                    self.stop()
                    raise AssertionError("droid-web did not start listening")
                time.sleep(0.1)

    def get(self, path: str, token: str | None = None):
        req = urllib.request.Request(self.url + path)
        if token:
            req.add_header("Authorization", f"Bearer {token}")
        with urllib.request.urlopen(req, timeout=10) as r:
            return json.loads(r.read())

    def stop(self) -> int:
        stop_process(self.proc, 10)
        self.proc.stdout.close()
        self.proc.stderr.close()
        return self.proc.returncode

    def __enter__(self) -> "WebServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def lockstep_recording(path) -> str:
    """A short lockstep trial recorded to ``path`` (fast: well under a second)."""
    from droid.experiments.matrix import resolve
    from droid.experiments.trial import run_trial, with_overrides

    cfg = with_overrides(resolve(["1.3"])[0].config, length_mm=60.0)
    run_trial(cfg, record=str(path))
    return str(path)


