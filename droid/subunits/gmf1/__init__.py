"""droid.subunits.gmf1 — programs and drivers of subunit class gmf1."""
