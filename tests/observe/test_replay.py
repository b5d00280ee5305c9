"""droid-replay: into a replay cell (databases only), CSV export, refusals."""
from __future__ import annotations

import csv
import dataclasses
import io
import json

from droid.brain.db.databases import open_brain
from droid.brain.db.layouts import ARM_STATUS_LAYOUT
from droid.brain.db.shmdb import cell_objects
from droid.observe.mcapfile import RecordingWriter, cell_meta, read_recording
from tests.brain.cellutil import droid, make_cell_file
from tests.observe.test_record import record_ticks


def make_recording(db_cell, tmp_path, n=40):
    cell, _ = db_cell
    arm = open_brain(cell, cell.subunit("arm1"), "status")
    cmd = open_brain(cell, cell.subunit("arm1"), "command")

    def change(i):
        arm.update(tick=90 + i, x=500.0 + i, encoder_pos=[i, 2 * i, 0, 0, 0, -i], homed=1, busy=40 - i)
        cmd.update(cmd_id=i // 10, joint_time_count=7)

    path = tmp_path / "rec.mcap"
    record_ticks(cell, str(path), n, change).close()
    arm.close()
    cmd.close()
    return path


def test_replay_into_a_replay_cell_then_snoop_reads_it(db_cell, tmp_path, cell_name):
    path = make_recording(db_cell, tmp_path)
    # a second cell (same layouts), brought up for replay: databases only
    other = f"{cell_name}r"
    import tests.conftest as c

    c._MY_CELLS.add(other)
    (tmp_path / "o").mkdir()
    cf = make_cell_file(tmp_path / "o", other)
    out = droid("droid.brain.runtime.launcher", "up", "--replay", str(path), "--cell", str(cf))
    try:
        assert out.returncode == 0, out.stderr
        objs = cell_objects(other)
        assert any(o.endswith(".arm1.status") for o in objs)
        assert not any(".proc." in o for o in objs), objs  # no programs
        assert not any(".vme" in o or "ctrl_" in o for o in objs), objs  # no world, no subunit side
        out = droid("droid.observe.replay", str(path), "--cell", str(cf), "--rate", "20")
        assert out.returncode == 0, out.stderr
        assert "40 ticks replayed" in out.stderr
        snoop = droid("droid.tasks.snoop", "arm1", "--count", "1", "--json", "--rate", "50", "--cell", str(cf))
        assert snoop.returncode == 0, snoop.stderr
        d = json.loads(snoop.stdout)
        assert d["tick"] == 129 and d["x"] == 539.0 and d["encoder_pos"] == [39, 78, 0, 0, 0, -39]
        from droid.brain.cell.cellfile import load_cell

        cell2 = load_cell(cf)
        with open_brain(cell2, cell2.subunit("arm1"), "command") as db:
            assert int(db.read()["cmd_id"]) == 3
    finally:
        out = droid("droid.brain.runtime.launcher", "down", "--cell", str(cf))
        assert out.returncode == 0, out.stderr
    assert cell_objects(other) == []


def test_replay_refuses_a_live_cell_and_a_cell_not_up(db_cell, tmp_path):
    path = make_recording(db_cell, tmp_path, 5)
    _, cf = db_cell  # databases exist, but it is not a replay cell
    out = droid("droid.observe.replay", str(path), "--cell", str(cf))
    assert out.returncode == 1 and "not a replay cell" in out.stderr


def test_replay_refuses_other_layout_versions_naming_both(db_cell, tmp_path):
    cell, cf = db_cell
    v2 = dataclasses.replace(ARM_STATUS_LAYOUT, version=2)
    path = tmp_path / "v2.mcap"
    with RecordingWriter(str(path), cell_meta(cell, "live")) as w:
        import numpy as np

        w.tick(1, 0)
        w.record("arm1", "status", v2, np.zeros((), ARM_STATUS_LAYOUT.dtype), 1, 0)
    out = droid("droid.observe.replay", str(path), "--cell", str(cf))
    assert out.returncode == 2, out.stderr
    assert "arm_status version 2" in out.stderr and "arm_status version 1" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


def test_export_csv_with_tick_range(db_cell, tmp_path):
    path = make_recording(db_cell, tmp_path)
    out = droid("droid.observe.replay", str(path), "--export", "csv", "--subunit", "arm1", "--from", "110", "--to", "114")
    assert out.returncode == 0, out.stderr
    rows = list(csv.DictReader(io.StringIO(out.stdout)))
    assert [int(r["tick"]) for r in rows] == [110, 111, 112, 113, 114]
    assert [int(r["record_tick"]) for r in rows] == [100, 101, 102, 103, 104]
    assert float(rows[2]["x"]) == 512.0 and int(rows[2]["encoder_pos_1"]) == 24 and "R_2_2" in rows[0]
    assert "magic" not in rows[0]
    out = droid("droid.observe.replay", str(path), "--export", "csv", "--subunit", "arm1", "--area", "command")
    assert out.returncode == 0 and int(list(csv.DictReader(io.StringIO(out.stdout)))[-1]["cmd_id"]) == 3
    out = droid("droid.observe.replay", str(path), "--export", "csv", "--subunit", "nosuch")
    assert out.returncode == 2 and "no status of 'nosuch'" in out.stderr
    out = droid("droid.observe.replay", str(path), "--export", "csv", "--subunit", "arm1", "--from", "9", "--to", "3")
    assert out.returncode == 2
    assert read_recording(path).ticks[-1] == 139
