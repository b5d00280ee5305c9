"""droid.brain — see docs/design.md §7."""
