"""droid-web's server CPU while a browser plays a recording with bodies (issue 29 item 2).

    PYTHONPATH=. nice -n 15 python bench/bench_web.py [--seconds 30] [--file run.mcap]

Records a lockstep trial (trial 1.3 of the chapter-6 matrix, the default
cell's step-input seam, 120 mm; or opens ``--file``), serves it with
``droid-web --file`` as its own process, and attaches one headless chromium
(Debian's, through playwright; scripts/browser.sh installs it) that opens
the page with ``#play=1``: the page asks for the next snapshot
(``/api/frame``, with the bodies, the frames and the seam points it lacks)
30 times a second and draws it.  Over ``--seconds`` of play it prints the
server's CPU time (user + system, from /proc) as % of one core (target
<= 15 %), the updates the page drew per second, the mean frame size [kB] and
the load average.  The browser's own CPU is not counted (it is the client).
Figures only; the verdict is the reader's (docs/benchmarks.md).
"""
from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from droid.cli import ArgumentParser, duration_s  # noqa: E402


def proc_cpu_s(pid: int) -> float:
    """User + system CPU time [s] of a running process, from /proc/PID/stat."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main(argv=None) -> int:
    ap = ArgumentParser(prog="bench_web.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=duration_s(600.0), default=30.0, help="play this long (default 30)")
    ap.add_argument("--file", default=None, help="a recording to serve (default: record trial 1.3, 120 mm)")
    args = ap.parse_args(argv)
    chromium = shutil.which("chromium")
    if chromium is None:
        print("bench_web: chromium is not installed (run scripts/browser.sh)", file=sys.stderr)
        return 1
    from playwright.sync_api import sync_playwright

    from tests.observe.webutil import WebServer

    with tempfile.TemporaryDirectory() as d:
        rec = args.file
        if rec is None:
            from droid.experiments.matrix import resolve
            from droid.experiments.trial import run_trial, with_overrides

            rec = str(Path(d) / "trial.mcap")
            run_trial(with_overrides(resolve(["1.3"])[0].config, length_mm=120.0), record=rec)
        with WebServer("--file", rec) as w, sync_playwright() as p:
            b = p.chromium.launch(executable_path=chromium, headless=True,
                                  args=["--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"])
            page = b.new_page(viewport={"width": 1400, "height": 800})
            sizes = []
            page.on("response", lambda r: sizes.append(int(r.headers.get("content-length", 0)))
                    if "/api/frame" in r.url else None)
            page.goto(w.url + "#play=1")
            page.wait_for_function("window.droidState && window.droidState.ready === true && droidState.playing",
                                   timeout=60000)
            time.sleep(2.0)  # settle: the page's first frames, the server's first requests
            pid = w.proc.pid
            c0, t0, n0, k0 = proc_cpu_s(pid), time.monotonic(), page.evaluate("droidState.snapshots"), len(sizes)
            time.sleep(args.seconds)
            c1, t1, n1, k1 = proc_cpu_s(pid), time.monotonic(), page.evaluate("droidState.snapshots"), len(sizes)
            count = w.get("api/cell")["file"]["count"]
            b.close()
    wall = t1 - t0
    got = sizes[k0:k1]
    load = os.getloadavg()
    # Alike in shape only to other benches' output: this bench's own figures, one line each.
    print(f"droid-web --file ({count} ticks), one headless chromium playing it (#play=1) for {wall:.1f} s:")
    print(f"  server CPU      {100.0 * (c1 - c0) / wall:6.2f} % of one core (target <= 15 %)")
    print(f"  page updates    {(n1 - n0) / wall:6.1f} /s (asked: 30)")
    print(f"  /api/frame      {len(got) / wall:6.1f} /s, mean {sum(got) / max(1, len(got)) / 1000:.1f} kB")
    print(f"  load average    {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} ({os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
