"""Deprecated: the subunit classes are :mod:`droid.brain.cell.classes` (droid.brain._moved says why this stays)."""
from droid.brain._moved import warn_moved
from droid.brain.cell.classes import *  # noqa: F401,F403 -- its public names

warn_moved(__name__, "droid.brain.cell.classes")
