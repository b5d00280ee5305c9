"""Make docs/web.png: droid-web showing a recorded lockstep trial, in headless chromium.

    PYTHONPATH=. python scripts/web_screenshot.py [--out docs/web.png] [--trial 1.3] [--view cell]

Records trial ``--trial`` (droid-experiment's matrix, lockstep, 120 mm; 1.3 tracks the
default cell's step-input seam), opens it with ``droid-web --file`` at camera preset
``--view`` (``#view=``: cell, tool or side), moves the time slider to 3/4 of the run (the
arm tracking) and saves a 1400x800 screenshot.  Needs chromium (scripts/browser.sh).
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "web.png"))
    ap.add_argument("--trial", default="1.3")
    ap.add_argument("--view", default="cell", choices=("cell", "tool", "side"))
    args = ap.parse_args()
    chromium = shutil.which("chromium")
    if chromium is None:
        sys.exit("web_screenshot: chromium is not installed (run scripts/browser.sh)")
    from playwright.sync_api import sync_playwright

    from droid.experiments.matrix import resolve
    from droid.experiments.trial import run_trial, with_overrides
    from tests.observe.webutil import WebServer

    with tempfile.TemporaryDirectory() as d:
        rec = str(Path(d) / "trial.mcap")
        run_trial(with_overrides(resolve([args.trial])[0].config, length_mm=120.0), record=rec)
        with WebServer("--file", rec) as w, sync_playwright() as p:
            b = p.chromium.launch(executable_path=chromium, headless=True,
                                  args=["--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"])
            page = b.new_page(viewport={"width": 1400, "height": 800})
            page.goto(w.url + f"#view={args.view}")
            page.wait_for_function("window.droidState && window.droidState.ready === true", timeout=30000)
            n = int(page.locator("#slider").get_attribute("max"))
            i = 3 * n // 4
            page.locator("#slider").evaluate(f"(s) => {{ s.value = {i}; s.dispatchEvent(new Event('input')); }}")
            page.wait_for_function(f"droidState.index === {i}", timeout=10000)
            page.wait_for_timeout(300)
            page.screenshot(path=args.out)
            b.close()
    print(f"web_screenshot: wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
