"""The observe tests' fixture: a cell's Brain databases without any program."""
from tests.observe.conftest import db_cell  # noqa: F401
