"""The cell-level collision guard between the arms (issue 41, thesis §7.3; docs/guard.md)."""
