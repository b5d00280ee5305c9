"""droid.subunits.reis — programs and drivers of subunit class reis."""
