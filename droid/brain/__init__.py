"""droid.brain — see DESIGN §7."""
