"""The force/torque sensor's twin: an ATI Net F/T answering RDT on UDP and its calibration page on HTTP."""
