"""A live test lost to a host stall says so in its report (issue 40 item 5): the stall lines of
its cell's program logs, each with its program, and the kernel's RT throttling."""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from types import SimpleNamespace

from tests.conftest import stall_summary


def test_the_stall_summary_names_each_stalled_program_and_the_kernel():
    # not under tmp_path: the suite's check takes logs there for a cell this test ran
    where = Path(tempfile.mkdtemp(prefix="droid-stall-report."))
    try:
        _summary_of_a_stalled_cell(where)
    finally:
        shutil.rmtree(where)


def _summary_of_a_stalled_cell(tmp_path: Path) -> None:
    logs = tmp_path / "run" / "logs"
    logs.mkdir(parents=True)
    (logs / "droid-sim.log").write_text("droid-sim: ready 0.4 s\n"
                                        "droid-sim: device arm1 took 53 ms for one 1 ms step at world time 41.2 s\n")
    (logs / "droid-servo-agent.arm1.log").write_text("starting\nbraking: the servo ran out of commands\n")
    (logs / "droid-heartbeat.log").write_text("ready\n")
    got = stall_summary(SimpleNamespace(funcargs={"tmp_path": tmp_path}))
    lines = got.splitlines()
    assert lines[0] == "2 stall line(s) in the cell's logs"
    assert "droid-sim: droid-sim: device arm1 took 53 ms for one 1 ms step at world time 41.2 s" in lines
    assert "droid-servo-agent.arm1: braking: the servo ran out of commands" in lines
    assert not any("heartbeat" in ln for ln in lines)
    assert any(ln.startswith("kernel log: ") for ln in lines)


def test_a_test_without_a_cell_has_no_stall_summary():
    assert stall_summary(SimpleNamespace(funcargs={})) == ""
