"""droid.kinematics — transforms, DH forward kinematics, analytic IK, gearing (imports nothing else of droid)."""
