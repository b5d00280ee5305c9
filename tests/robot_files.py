"""Helpers for the tests that spoil a robot file and expect a refusal naming file, key and reason."""
from __future__ import annotations

from pathlib import Path

import pytest

from droid.kinematics import RobotFileError, load_robot


def spoiled(source: Path, tmp_path: Path, old: str, new: str) -> Path:
    """A copy of ``source`` with its first ``old`` replaced by ``new``."""
    text = source.read_text()
    assert old in text
    p = tmp_path / f"bad_{source.name}"
    p.write_text(text.replace(old, new, 1))
    return p


def assert_refused(path: Path, words) -> str:
    """load_robot(path) raises RobotFileError whose message names the file and every word."""
    with pytest.raises(RobotFileError) as exc:
        load_robot(str(path))
    msg = str(exc.value)
    assert str(path) in msg
    for w in words:
        assert w in msg, msg
    return msg
