"""droid-ft, the program, against the Net F/T twin: one process, no cell (docs/ft.md).

The test creates the subunit's ctrl_status record itself, serves the twin on free loopback
ports, steps it from a thread, and runs ``python -m droid.subunits.ft.prog`` with a copy of
cells/sim.toml pointing at the twin.  Verdicts are on what the record holds, waited for with
generous bounds (never on how fast it came).
"""
from __future__ import annotations

import signal
import subprocess
import sys
import time

import numpy as np

from droid.brain.cell.cellfile import load_cell
from droid.brain.db.databases import local_layouts
from droid.brain.db.shmdb import Database, db_name
from tests.brain.cellutil import make_cell_file
from tests.ft.test_ft_twin import SIGMA, Stepper, twin_device, within_noise


def wait_for(read, cond, seconds=60.0):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        rec = read()
        if cond(rec):
            return rec
        time.sleep(0.02)
    return read()


def test_droid_ft_writes_the_twin_s_wrench_and_goes_stale_when_records_stop(tmp_path, cell_name):
    dev = twin_device()
    path = make_cell_file(tmp_path, cell_name)
    text = path.read_text().replace("netft://{loopback}:49152?rate_hz=100&http_port=8049",
                                    f"netft://127.0.0.1:{dev.port}?rate_hz=100&http_port={dev.http_port}")
    assert f"http_port={dev.http_port}" in text
    path.write_text(text)
    cell = load_cell(path)
    sub = cell.subunit("ft")
    db = Database(db_name(cell.name, "ft", "ctrl_status"), local_layouts(sub)["ctrl_status"], create=True)
    # droid-ft also reads its Command and guards arm1 (the shipped cell's guard_arm): their records
    cmd_db = Database(db_name(cell.name, "ft", "ctrl_command"), local_layouts(sub)["ctrl_command"], create=True)
    arm = cell.subunit("arm1")
    arm_db = Database(db_name(cell.name, "arm1", "ctrl_status"), local_layouts(arm)["ctrl_status"], create=True)
    stepper = Stepper(dev)
    proc = subprocess.Popen([sys.executable, "-m", "droid.subunits.ft.prog", "--cell", str(path), "ft"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        rec = wait_for(db.read, lambda r: int(r["valid"]) == 1 and int(r["records"]) > 50)
        assert int(rec["valid"]) == 1, proc.stderr.read() if proc.poll() is not None else rec
        f_true, m_true = dev.true_wrench()
        assert within_noise([*rec["force_N"], *rec["torque_Nm"]], np.r_[f_true, m_true])
        assert int(rec["fault"]) == 0 and int(rec["dropped"]) == 0 and int(rec["bad_datagrams"]) == 0
        assert int(rec["sample_ns"]) > 0 and 0.0 <= float(rec["sample_age_ms"]) < 60_000.0
        stepper.close()  # the device goes silent
        rec = wait_for(db.read, lambda r: int(r["valid"]) == 0)
        assert int(rec["valid"]) == 0 and int(rec["stale"]) == 1 and int(rec["fault"]) != 0
        assert np.all(np.abs(SIGMA) > 0)
        assert int(arm_db.read()["fault"]) == 0  # the guard is not armed: a silent sensor faults no arm
    finally:
        stepper.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            out, err = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
        for d in (db, cmd_db, arm_db):
            d.close()
            d.unlink()
        dev.close()
    assert proc.returncode == 0, err
    lines = err.strip().splitlines()
    assert lines and lines[0].startswith("droid-ft: calibration: 1e+06 counts/N"), lines
    assert "Traceback" not in err
