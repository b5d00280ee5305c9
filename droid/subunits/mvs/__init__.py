"""droid.subunits.mvs — programs and drivers of subunit class mvs."""
