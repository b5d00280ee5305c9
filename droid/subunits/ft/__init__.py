"""A six-axis force/torque sensor on Ethernet (thesis §7.3): the RDT driver and ``droid-ft``."""
