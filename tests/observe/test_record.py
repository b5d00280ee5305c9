"""droid-record's core and the MCAP layout: what goes in comes back, bad files are refused."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from droid.brain.db.databases import open_brain
from droid.brain.db.layouts import CMD_REFUSED, FAULT_WATCHDOG, HOME_MODE
from droid.cli import BadInput
from droid.observe.mcapfile import (FORMAT_VERSION, RecordingWriter, cell_meta, read_recording, recover)
from droid.observe.record import CellRecorder
from droid.observe.sampler import CellSampler
from droid.observe.scene import scene_meta
from tests.brain.cellutil import ROOT


def record_ticks(cell, path, n, change=None, flush_ticks=60):
    s = CellSampler(cell).connect()
    core = CellRecorder(RecordingWriter(path, cell_meta(cell, "live", scene_meta(cell)), flush_ticks=flush_ticks))
    try:
        for i in range(n):
            if change:
                change(i)
            core.sample(100 + i, i * 16_666_667, s.read())
    finally:
        s.close()
    return core


def test_every_database_by_tick_roundtrips(db_cell, tmp_path):
    cell, _ = db_cell
    arm = open_brain(cell, cell.subunit("arm1"), "status")
    mvs = open_brain(cell, cell.subunit("mvs"), "status")

    def change(i):
        arm.update(tick=100 + i, x=300.0 + i * 0.1, encoder_pos=[i, -i, 2 * i, 0, 0, i], busy=i % 3)
        mvs.update(tick=100 + i, x=1.5 * i, y=-0.25 * i, updated_ns=123456789 + i)

    path = str(tmp_path / "r.mcap")
    record_ticks(cell, path, 30, change).close()
    arm.close()
    mvs.close()
    rec = read_recording(path)
    assert rec.ticks == list(range(100, 130))
    assert rec.meta["format_version"] == FORMAT_VERSION and rec.meta["cell"] == cell.name
    # every Brain database of every subunit has a channel, read generically from the cell
    assert set(rec.layouts()) == {("arm1", "status"), ("arm1", "command"), ("gmf1", "status"),
                                  ("gmf1", "command"), ("mvs", "status"), ("tool", "status"),
                                  ("joy", "status"), ("ft", "status"), ("ft", "command"),
                                  ("guard", "status")}  # the collision guard's Status (issue 41)
    f = rec.frames[7]
    a = f["/arm1/status"][0]
    assert a["_tick"] == 107 and a["x"] == pytest.approx(300.7) and a["encoder_pos"] == [7, -7, 14, 0, 0, 7]
    m = f["/mvs/status"][0]
    assert m["x"] == 10.5 and m["y"] == -1.75 and m["updated_ns"] == 123456796
    assert len(f["/arm1/status"][0]["R"]) == 3
    names = {t["child_frame_id"] for t in f["/tf"][0]["transforms"]}
    assert {"arm1/base", "arm1/wcp", "gmf1/wcp", "tool", "sensor", "workpiece"} <= names


def test_schemas_are_json_schema_and_foxglove(db_cell, tmp_path):
    from mcap.reader import make_reader

    cell, _ = db_cell
    path = str(tmp_path / "r.mcap")
    record_ticks(cell, path, 3).close()
    with open(path, "rb") as fh:
        r = make_reader(fh)
        assert r.get_header().profile == "droid"
        summ = r.get_summary()
        got = {s.name: s for s in summ.schemas.values()}
    assert {"foxglove.FrameTransforms", "foxglove.SceneUpdate", "droid.arm_status", "droid.sensor_status",
            "droid.arm_command", "droid.tick"} <= set(got)
    assert all(s.encoding == "jsonschema" for s in got.values())
    sch = json.loads(got["droid.arm_status"].data)
    assert sch["properties"]["encoder_pos"]["maxItems"] == 6
    assert sch["properties"]["R"]["items"]["minItems"] == 3
    assert all(c.message_encoding == "json" for c in summ.channels.values())
    assert summ.statistics.chunk_count >= 1


def test_faults_and_events_are_logged(db_cell, tmp_path):
    cell, _ = db_cell
    arm = open_brain(cell, cell.subunit("arm1"), "status")

    def change(i):
        if i == 5:
            arm.update(fault=FAULT_WATCHDOG, stale=1)
        if i == 7:
            arm.update(cmd_mode=HOME_MODE)
        if i == 8:
            arm.update(cmd_id=4, cmd_result=CMD_REFUSED)
        if i == 10:
            arm.update(fault=0, stale=0)

    path = str(tmp_path / "r.mcap")
    record_ticks(cell, path, 12, change).close()
    arm.close()
    rec = read_recording(path)
    logs = [(m["_tick"], m["level"], m["name"], m["message"]) for fr in rec.frames for m in fr.get("/log", [])]
    assert (105, 4, "arm1", "fault watchdog set") in logs
    assert (105, 3, "arm1", "stale") in logs
    assert (108, 3, "arm1", "command 4 refused") in logs
    assert (107, 2, "arm1", "mode OFF -> HOME") in logs
    assert (110, 2, "arm1", "fault watchdog cleared") in logs


def test_unclean_stop_loses_at_most_the_open_chunk(db_cell, tmp_path):
    cell, _ = db_cell
    path = str(tmp_path / "crash.mcap")
    core = record_ticks(cell, path, 95, flush_ticks=30)  # never closed: as if killed
    core.w._f.flush()
    with pytest.raises(BadInput, match="truncated"):
        read_recording(path)
    good = str(tmp_path / "good.mcap")
    rec = recover(path, good)
    assert not rec.complete
    # chunks closed every 30 ticks: at least the first 90 survive
    assert rec.ticks[:90] == list(range(100, 190))
    again = read_recording(good)
    assert again.complete and again.ticks == rec.ticks
    os.close(os.open(path, os.O_RDONLY))


def run_prog(module, *args):
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, cwd=ROOT,
                          timeout=60)


def test_foreign_future_and_truncated_files_exit_2(db_cell, tmp_path):
    from mcap.writer import Writer

    cell, cell_file = db_cell
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="x")
        w.finish()
    future = tmp_path / "future.mcap"
    w = RecordingWriter(str(future), dict(cell_meta(cell, "live")))
    w.meta["format_version"] = FORMAT_VERSION + 1
    w._w.add_metadata("droid", {"format_version": str(FORMAT_VERSION + 1)})
    w.close()
    # the first droid metadata wins: make a file whose only metadata is from the future
    fut2 = tmp_path / "future2.mcap"
    with open(fut2, "wb") as fh:
        w2 = Writer(fh)
        w2.start(profile="droid", library="droid-record (format 9)")
        w2.add_metadata("droid", {"format_version": "9"})
        w2.finish()
    text = tmp_path / "text.mcap"
    text.write_text("hello\n")
    good = tmp_path / "good.mcap"
    record_ticks(cell, str(good), 70).close()
    trunc = tmp_path / "trunc.mcap"
    trunc.write_bytes(good.read_bytes()[: os.path.getsize(good) // 2])
    for f, why in ((foreign, "foreign MCAP"), (fut2, "newer"), (text, "not an MCAP"), (trunc, "truncated"),
                   (tmp_path / "none.mcap", "no such file")):
        out = run_prog("droid.observe.replay", str(f), "--export", "csv", "--subunit", "arm1")
        assert out.returncode == 2, (f, out.stderr)
        assert why in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr


def test_record_cli_bad_input(tmp_path):
    out = run_prog("droid.observe.record", "--out", str(tmp_path / "no" / "x.mcap"))
    assert out.returncode == 2 and "does not exist" in out.stderr
    out = run_prog("droid.observe.record", "--out", str(tmp_path / "x.mcap"), "nosuch")
    assert out.returncode == 2 and "unknown subunit" in out.stderr
    out = run_prog("droid.observe.record")
    assert out.returncode == 2 and "--out" in out.stderr


def test_record_cli_cell_not_up(tmp_path, cell_name):
    from tests.brain.cellutil import make_cell_file

    path = make_cell_file(tmp_path, cell_name)
    out = run_prog("droid.observe.record", "--cell", str(path), "--out", str(tmp_path / "x.mcap"))
    assert out.returncode == 1 and "does not exist" in out.stderr, out.stderr


def test_record_cli_follows_the_heartbeat(db_cell, tmp_path):
    """droid-record's shell on a heartbeat (published here, no cell programs): one sample per tick."""
    import threading
    import time

    import zmq

    from droid.brain.plumbing import wire

    cell, cf = db_cell
    cell.run_dir.mkdir(parents=True, exist_ok=True)
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.bind(cell.heartbeat)
    stop = threading.Event()

    def beat():
        k, t0 = 0, time.monotonic()
        while not stop.is_set():
            k += 1
            pub.send(wire.pack_tick(wire.Tick(k, time.monotonic_ns(), cell.period_ns)))
            time.sleep(max(0.0, t0 + k / cell.heartbeat_hz - time.monotonic()))

    th = threading.Thread(target=beat, daemon=True)
    th.start()
    try:
        out = run_prog("droid.observe.record", "--cell", str(cf), "--out", str(tmp_path / "hb.mcap"),
                       "--seconds", "2", "arm1", "mvs")
    finally:
        stop.set()
        th.join()
        pub.close(0)
        ctx.term()
    assert out.returncode == 0, out.stderr
    rec = read_recording(tmp_path / "hb.mcap")
    assert set(rec.layouts()) == {("arm1", "status"), ("arm1", "command"), ("mvs", "status")}
    assert len(rec.ticks) >= 10 and rec.ticks == sorted(set(rec.ticks))
    assert "/health" in rec.channels and rec.frames[0]["/tick"][0]["t_ns"] > 0


def test_foxglove_frames_are_in_metres(db_cell, tmp_path):
    cell, _ = db_cell
    arm = open_brain(cell, cell.subunit("arm1"), "status")
    arm.update(x=300.0, y=100.0, z=1340.0)
    arm.close()
    path = str(tmp_path / "m.mcap")
    record_ticks(cell, path, 2).close()
    tf = {t["child_frame_id"]: t for t in read_recording(path).frames[0]["/tf"][0]["transforms"]}
    assert tf["arm1/wcp"]["translation"] == {"x": 0.3, "y": 0.1, "z": 1.34}
    assert tf["gmf1/base"]["translation"]["x"] == pytest.approx(2.0)
    q = tf["gmf1/base"]["rotation"]
    assert abs(q["x"] ** 2 + q["y"] ** 2 + q["z"] ** 2 + q["w"] ** 2 - 1) < 1e-12
