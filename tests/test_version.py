"""Every console script answers --version (issue 15): ``PROG VERSION`` on stdout, exit 0."""
from __future__ import annotations

import importlib
import tomllib
from pathlib import Path

import pytest

from droid.cli import droid_version

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


@pytest.mark.parametrize("script", sorted(SCRIPTS))
def test_every_program_answers_version(script, capsys):
    module, func = SCRIPTS[script].split(":")
    main = getattr(importlib.import_module(module), func)
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out == f"{script} {droid_version()}\n"
