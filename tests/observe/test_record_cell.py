"""Recording a real-time cell of processes (integration: the coordinator runs these).

``droid-seamtrack --record`` on the live simulated cell writes droid-record's
layout: every tick of the tracking loop, the Reis commands, the lead sensor's
readings and the seam map -- and droid-web opens the file.
"""
from __future__ import annotations

import numpy as np
import pytest

from droid.observe.mcapfile import read_recording
from tests.brain.cellutil import droid

pytestmark = pytest.mark.integration


def test_seamtrack_records_the_live_cell(homed_sim_cell, tmp_path):
    """On the session's shared homed cell (tests/conftest.py)."""
    sim_cell = homed_sim_cell
    path = tmp_path / "run.mcap"
    out = droid("droid.tasks.seamtrack", "8", "--start", "i", "--length", "40", "--record", str(path),
                "--cell", str(sim_cell), timeout=180)
    assert out.returncode == 0, out.stderr
    rec = read_recording(path)
    assert rec.meta["source"] == "live" and rec.complete
    assert {("arm1", "status"), ("arm1", "command"), ("gmf1", "status"), ("mvs", "status"),
            ("tool", "status")} <= set(rec.layouts())
    ticks = np.array(rec.ticks)
    assert len(ticks) > 60 and np.all(np.diff(ticks) >= 1)
    ids = [f["/arm1/command"][0]["cmd_id"] for f in rec.frames if "/arm1/command" in f]
    assert ids[-1] - ids[0] > 10  # the tracking loop's cartesian commands, one per cycle
    assert any(f["/mvs/status"][0]["homed"] == 0 for f in rec.frames)  # valid lead readings
    assert any(m["programs"] for f in rec.frames for m in f.get("/health", []))
    from droid.observe.web import FileSource

    src = FileSource(str(path))
    last = src.frame(len(src.snaps) - 1)
    assert len(last["seam"]) > 5 and set(last["subunits"]) >= {"arm1", "gmf1", "mvs", "tool"}
