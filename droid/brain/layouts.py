"""Deprecated: the record layouts are :mod:`droid.brain.db.layouts` (droid.brain._moved says why this stays)."""
from droid.brain._moved import warn_moved
from droid.brain.db.layouts import *  # noqa: F401,F403 -- its public names

warn_moved(__name__, "droid.brain.db.layouts")
