"""droid.brain.cellfile.without_table: derived cells drop one table of the built-in cell."""
from __future__ import annotations

import pytest

from droid.brain.cellfile import builtin_cell_path, without_table
from droid.cli import read_toml


def test_the_touch_device_leaves_and_every_other_table_stays(tmp_path):
    text = builtin_cell_path().read_text()
    out = without_table(text, "[world.devices.touch]")
    p_in, p_out = tmp_path / "in.toml", tmp_path / "out.toml"
    p_in.write_text(text)
    p_out.write_text(out)
    before, after = read_toml(str(p_in), "cell"), read_toml(str(p_out), "cell")
    assert "touch" in before["world"]["devices"] and "touch" not in after["world"]["devices"]
    assert {k: v for k, v in before["world"]["devices"].items() if k != "touch"} == after["world"]["devices"]
    assert before["subunits"] == after["subunits"] and before["cell"] == after["cell"]
    # the next table's own comment stays with it
    assert "# The Net F/T twin on the Reis wrist" in out


def test_a_missing_table_is_an_error():
    with pytest.raises(ValueError, match=r"no table \[world.devices.nothere\]"):
        without_table("[cell]\nname = \"x\"\n", "[world.devices.nothere]")
