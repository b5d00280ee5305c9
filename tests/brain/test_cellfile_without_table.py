"""droid.brain.cell.cellfile.without_table: derived cells drop one table of the built-in cell."""
from __future__ import annotations

import pytest

from droid.brain.cell.cellfile import builtin_cell_path, without_table
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


def test_an_array_continued_on_lines_that_open_with_a_bracket_is_part_of_its_table():
    """The built-in cell's ``[guard] allow`` runs over lines that start with ``[`` once indented:
    they are the table's, not the next table's header."""
    text = ('[cell]\nname = "x"\n\n[guard]\nallow = [["a.tool", "b.workpiece"],\n'
            '         ["a.link_1", "fixture.floor"]]\nworkpiece = { arm = "b" }\n\n'
            '# the next table\n[world]\nseed = 1\n')
    out = without_table(text, "[guard]")
    assert out == '[cell]\nname = "x"\n\n# the next table\n[world]\nseed = 1\n'
    built_in = without_table(builtin_cell_path().read_text(), "[guard]")
    assert "fixture.floor" not in built_in and "[guard]" not in built_in
