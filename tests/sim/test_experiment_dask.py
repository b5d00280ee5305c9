"""droid-experiment --dask (issue 15): a scheduler and two workers on loopback give the pool's results.csv."""
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

import distributed  # the [cluster] extra (scripts/venv.sh installs it): its absence fails, never skips

from droid.experiments.cli import main  # noqa: E402
from tests.brain.cellutil import free_port
from tests.sim.sweep20 import NAME as SWEEP20_NAME, SWEEP20, TRIALS as SWEEP20_TRIALS

PROG = [sys.executable, "-m", "droid.experiments.cli"]
DASK = str(Path(sys.executable).parent / "dask")
ROOT = str(Path(__file__).resolve().parents[2])

PLAN = """
name = "dask"
[defaults]
length_mm = 140
sensor = "ideal"
seed = 3
arm = "fast"
[sweep]
position = ["i", "iii"]
speed_mm_s = [16, 32]
delay_cycles = [0, 2]
"""


@pytest.fixture(scope="module")
def loopback_cluster(tmp_path_factory):
    """A dask scheduler and two single-threaded workers on 127.0.0.1, importing this droid;
    started once for the module's tests that run on it (stopped after the module's last test)."""
    assert os.path.exists(DASK), f"no dask command at {DASK} (pip install 'droid[cluster]')"
    tmp_path = tmp_path_factory.mktemp("cluster")
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    logs = open(tmp_path / "dask.log", "w")
    procs = [subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], env=env, stdout=logs, stderr=logs)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen([DASK, "worker", address, "--nthreads", "1", "--host", "127.0.0.1",
                                           "--no-dashboard", "--local-directory", str(tmp_path / "workers")],
                                          env=env, stdout=logs, stderr=logs))
        client = distributed.Client(address, timeout=60)
        try:
            client.wait_for_workers(2, timeout=120)
        finally:
            client.close()
        yield address
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        logs.close()


def test_two_loopback_workers_give_the_pools_results_value_for_value(tmp_path, loopback_cluster):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    # the pool's figures are not compared (only its tables and logs): its run skips them
    pool = subprocess.run(PROG + ["run", "--plan", str(plan), "--out", str(tmp_path / "pool"), "--jobs", "2",
                                  "--no-figures"], capture_output=True, text=True, timeout=600)
    assert pool.returncode == 0, pool.stderr
    dask = subprocess.run(PROG + ["run", "--plan", str(plan), "--out", str(tmp_path / "dask"),
                                  "--dask", loopback_cluster], capture_output=True, text=True, timeout=600)
    assert dask.returncode == 0, dask.stderr
    assert f"on Dask {loopback_cluster}" in dask.stderr
    a = (tmp_path / "pool" / "dask" / "results.csv").read_text()
    b = (tmp_path / "dask" / "dask" / "results.csv").read_text()
    assert a == b and len(a.splitlines()) == 9
    for png in (tmp_path / "dask" / "dask").glob("*.png"):  # the workers' figures, written here
        assert png.read_bytes()[:4] == b"\x89PNG"
    assert len(list((tmp_path / "dask" / "dask").glob("*.png"))) == 8
    # the per-trial logs too, byte for byte
    for csv_file in (tmp_path / "pool" / "dask").glob("t*.csv"):
        assert csv_file.read_bytes() == (tmp_path / "dask" / "dask" / csv_file.name).read_bytes()


def test_experiment_ids_run_on_dask_too(tmp_path, loopback_cluster):
    p = subprocess.run(PROG + ["run", "1.1", "1.2", "--length", "150", "--arm", "fast", "--out", str(tmp_path / "o"),
                               "--dask", loopback_cluster, "--no-figures"], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    assert f"on Dask {loopback_cluster}" in p.stderr
    rows = (tmp_path / "o" / "table6.1" / "summary.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[1].startswith("1.1,") and rows[2].startswith("1.2,")
    assert (tmp_path / "o" / "table6.1" / "1.2.csv").is_file()


def test_dask_local_runs_a_local_cluster(tmp_path):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN.replace('position = ["i", "iii"]', 'position = ["i"]'))
    p = subprocess.run(PROG + ["run", "--plan", str(plan), "--out", str(tmp_path / "o"), "--dask", "local",
                               "--jobs", "2", "--no-figures"], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    assert "on Dask local" in p.stderr
    assert len((tmp_path / "o" / "dask" / "results.csv").read_text().splitlines()) == 5


def test_an_address_that_does_not_answer_exits_1_naming_it(tmp_path):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    address = f"tcp://127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    p = subprocess.run(PROG + ["run", "--plan", str(plan), "--out", str(tmp_path / "o"), "--dask", address],
                       capture_output=True, text=True, timeout=120)
    elapsed = time.monotonic() - t0
    assert p.returncode == 1, p.stderr
    lines = p.stderr.strip().splitlines()
    assert any(address in ln and "no Dask scheduler answers" in ln for ln in lines), p.stderr
    assert "Traceback" not in p.stderr
    print(f"refused in {elapsed:.1f} s")  # the 10 s bound is CONNECT_TIMEOUT_S (5 s); timing decides nothing


def test_a_listener_that_never_answers_exits_1_naming_it(tmp_path):
    """Client's own timeout does not bound a peer that accepts and stays silent (it hung 10 min)."""
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(4)
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        p = subprocess.run(PROG + ["run", "--plan", str(plan), "--out", str(tmp_path / "o"), "--dask", address],
                           capture_output=True, text=True, timeout=120)  # a hang guard only
    assert p.returncode == 1, p.stderr
    assert f"--dask {address}: no Dask scheduler answers there" in p.stderr and "Traceback" not in p.stderr



def test_a_malformed_address_is_bad_input(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN)
    assert main(["run", "--plan", str(plan), "--out", str(tmp_path / "o"), "--dask", "tcp://nohost"]) == 2
    assert "--dask" in capsys.readouterr().err


def test_ctrl_c_on_a_local_cluster_then_resume(tmp_path, sweep20_reference):
    """SIGINT to the process group (a terminal's Ctrl-C): exit 130 with no worker's traceback and no
    process left; --resume on the cluster completes the pool's table (``sweep20_reference``: one
    uninterrupted pool run of the same plan, tests/sim/sweep20.py)."""
    import signal

    plan = tmp_path / "p.toml"
    plan.write_text(SWEEP20)  # 20 trials, ~0.5 s each
    out = tmp_path / "out"
    proc = subprocess.Popen(PROG + ["run", "--plan", str(plan), "--out", str(out), "--no-figures", "--dask", "local",
                                    "--jobs", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    d = out / SWEEP20_NAME
    deadline = time.monotonic() + 300
    while len(list(d.glob("*.json"))) < 2 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err, err
    done = len(list(d.glob("*.json")))
    assert 2 <= done < SWEEP20_TRIALS, "the run ended before the interrupt: nothing was tested"
    p = subprocess.run(PROG + ["run", "--plan", str(plan), "--out", str(out), "--no-figures", "--dask", "local",
                               "--jobs", "2", "--resume"], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    assert (d / "results.csv").read_text() == sweep20_reference
