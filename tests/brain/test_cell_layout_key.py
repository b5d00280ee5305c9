"""The cell file's ``[cell] layout`` key: the seam-tracking layout a task on that cell reads
(issue 26: the ABB welding cell names its own; droid.brain.cell.cell_layout.layout_for_cell)."""
from __future__ import annotations

import re
import subprocess
import sys

import pytest

from droid.brain.cell.cellfile import load_cell
from droid.cli import BadInput
from droid.brain.cell.cell_layout import BUNDLED_LAYOUT, layout_for_cell
from tests.brain.cellutil import ROOT, make_cell_file


def with_layout(tmp_path, name, value):
    path = make_cell_file(tmp_path, name)
    text = re.sub(r"(?m)^(name = .*)$", lambda m: m.group(1) + f"\nlayout = {value}", path.read_text(), count=1)
    path.write_text(text)
    return path


def test_no_key_reads_the_bundled_layout(tmp_path, cell_name):
    cell = load_cell(make_cell_file(tmp_path, cell_name))
    assert cell.layout is None
    assert layout_for_cell(cell).source == str(BUNDLED_LAYOUT)


def test_the_abb_cell_names_its_layout_also_from_a_copy_elsewhere(tmp_path, cell_name):
    cell = load_cell(ROOT / "cells" / "abb_weld.toml")
    lay = layout_for_cell(cell)
    assert (lay.tool_robot, lay.holder_robot, lay.sensor) == ("abb", "gmf1", "mvs")
    # a test's renamed copy in tmp: the bare name is found among the bundled cells
    copy = load_cell(make_cell_file(tmp_path, cell_name, source=ROOT / "cells" / "abb_weld.toml"))
    assert copy.layout == cell.layout
    # an explicit --layout wins over the cell's
    assert layout_for_cell(copy, BUNDLED_LAYOUT).tool_robot == "arm1"


def test_a_layout_beside_the_cell_file_wins(tmp_path, cell_name):
    (tmp_path / "mine.toml").write_text((ROOT / "cells" / "abb_weld_layout.toml").read_text()
                                        .replace('name = "abb_weld"', 'name = "mine"'))
    cell = load_cell(with_layout(tmp_path, cell_name, '"mine.toml"'))
    assert cell.layout == (tmp_path / "mine.toml").resolve()
    assert layout_for_cell(cell).name == "mine"


@pytest.mark.parametrize("value, message", [('"nowhere.toml"', "no such file"), ("3", "layout must be str")])
def test_a_bad_layout_key_is_one_line_and_exit_2(tmp_path, cell_name, value, message):
    path = with_layout(tmp_path, cell_name, value)
    with pytest.raises(BadInput, match=message):
        load_cell(path)
    out = subprocess.run([sys.executable, "-m", "droid.tasks.seamtrack", "8", "--cell", str(path)],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1 and message in out.stderr, out.stderr
