"""Start droid-web as a process for a test and wait until it listens."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request

from tests.brain.cellutil import ROOT, free_port


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
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
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


