"""Deprecated: the device registry is :mod:`droid.brain.cell.registry` (droid.brain._moved says why this stays)."""
from droid.brain._moved import warn_moved
from droid.brain.cell.registry import *  # noqa: F401,F403 -- its public names

warn_moved(__name__, "droid.brain.cell.registry")
