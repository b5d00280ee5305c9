"""Fixtures for the observe tests: a cell's Brain databases without any program (like a replay cell)."""
from __future__ import annotations

import pytest

from droid.brain.cell.cellfile import load_cell
from droid.brain.db.databases import create_databases
from tests.brain.cellutil import make_cell_file


@pytest.fixture
def db_cell(tmp_path, cell_name):
    """(cell, cell file path): the built-in sim cell renamed, its databases created, removed after."""
    path = make_cell_file(tmp_path, cell_name)
    cell = load_cell(path)
    dbs = create_databases(cell)
    for db in dbs:
        db.close()
    try:
        yield cell, path
    finally:
        from droid.brain.db.shmdb import remove_cell_objects

        remove_cell_objects(cell.name)
