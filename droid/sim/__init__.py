"""droid.sim — see docs/design.md §7."""
