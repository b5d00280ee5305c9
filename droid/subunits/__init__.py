"""droid.subunits — see docs/design.md §7."""
