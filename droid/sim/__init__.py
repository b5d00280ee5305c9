"""droid.sim — see DESIGN §7."""
