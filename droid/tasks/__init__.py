"""droid.tasks — see DESIGN §7."""
