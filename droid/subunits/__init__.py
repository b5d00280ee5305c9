"""droid.subunits — see DESIGN §7."""
