"""Hostile command lines for droid-record, droid-replay, droid-web and droid-foxglove: exit 2, one line, nothing created."""
from __future__ import annotations

import importlib

import pytest

from droid.brain.db.shmdb import cell_objects
from tests.brain.cellutil import make_cell_file

BAD = [  # (module, argv, reason); rows alike in shape only: web and foxglove refuse the same mistakes each
    ("droid.observe.record", ["--out", "{tmp}/x.mcap", "--seconds", "nan"], "not a finite number"),
    ("droid.observe.record", ["--out", "{tmp}/x.mcap", "--seconds", "-1"], "must be > 0"),
    ("droid.observe.record", ["--out", "{tmp}/x.mcap", "--seconds", "86401"], "<= 86400 s"),
    ("droid.observe.record", ["--out", "{tmp}"], "is a directory"),
    ("droid.observe.record", ["--out", "{tmp}/x.mcap", "arm1", "nosuch"], "unknown subunit"),
    ("droid.observe.replay", ["{tmp}/x.mcap", "--rate", "0"], "must be >= 0.01 and <= 1000 x"),
    ("droid.observe.replay", ["{tmp}/x.mcap", "--rate", "1e"], "not a number"),
    ("droid.observe.replay", ["{tmp}/x.mcap", "--from", "-3"], "must be >= 0"),
    ("droid.observe.replay", ["{tmp}/x.mcap", "--from", "１"], "not an integer"),
    ("droid.observe.replay", ["{tmp}/x.mcap", "--export", "json", "--subunit", "arm1"], "invalid choice"),
    ("droid.observe.replay", ["{tmp}/x.mcap", "--export", "csv"], "--subunit"),
    ("droid.observe.replay", ["{tmp}"], "is a directory"),
    ("droid.observe.replay", ["{tmp}/x.mcap", "--recover", "{tmp}/x.mcap"], "another file"),
    ("droid.observe.web", ["--port", "0"], "must be > 0"),
    ("droid.observe.web", ["--port", "99999"], "<= 65535"),
    ("droid.observe.web", ["--rate", "inf"], "not a finite number"),
    ("droid.observe.web", ["--rate", "500"], "<= 120 Hz"),
    ("droid.observe.web", ["--rate", "1e-320"], ">= 0.1"),
    ("droid.observe.web", ["--bind", "10.1.2.3"], "not loopback"),
    ("droid.observe.web", ["--bind", "::", "--file", "{tmp}/x.mcap"], "not loopback"),
    ("droid.observe.web", ["--token", "short"], "at least 8"),
    ("droid.observe.web", ["--file", "{tmp}/none.mcap"], "no such file"),
    ("droid.observe.web", ["extra"], "unrecognized arguments"),
    ("droid.observe.web", ["--foxglove", "0"], "must be > 0"),
    ("droid.observe.foxglove", ["--port", "0"], "must be > 0"),
    ("droid.observe.foxglove", ["--port", "99999"], "<= 65535"),
    ("droid.observe.foxglove", ["--rate", "nan"], "not a finite number"),
    ("droid.observe.foxglove", ["--rate", "500"], "<= 120 Hz"),
    ("droid.observe.foxglove", ["--host", "10.1.2.3"], "not loopback"),
    ("droid.observe.foxglove", ["--host", "::", "--file", "{tmp}/x.mcap"], "not loopback"),
    ("droid.observe.foxglove", ["--token", "short"], "at least 8"),
    ("droid.observe.foxglove", ["--file", "{tmp}/none.mcap"], "no such file"),
    ("droid.observe.foxglove", ["--file", "{tmp}/x.mcap"], "not an MCAP file"),
    ("droid.observe.foxglove", ["extra"], "unrecognized arguments"),
    ("droid.brain.runtime.launcher", ["up", "--replay", "{tmp}/none.mcap"], "no such file"),
    ("droid.brain.runtime.launcher", ["up", "--replay", "{tmp}/x.mcap", "--host", "brain"], "no --host"),
]


@pytest.mark.parametrize("module,argv,reason", BAD, ids=[f"{m.rsplit('.', 1)[1]} {' '.join(a)}" for m, a, _ in BAD])
def test_bad_invocation(module, argv, reason, tmp_path, cell_name, capsys):
    (tmp_path / "x.mcap").write_bytes(b"")
    main = importlib.import_module(module).main
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv] + ["--cell", str(make_cell_file(tmp_path, cell_name))]
    if module == "droid.brain.runtime.launcher":  # its --cell belongs after the subcommand
        argv = argv[:1] + argv[-2:] + argv[1:-2]
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and reason in lines[0], err
    assert "Traceback" not in err
    assert cell_objects(cell_name) == []
