"""droid.tasks — see docs/design.md §7."""
