"""The joystick subunit (thesis §2.6 Figure 2.10, §3.4): drivers and ``droid-joystick``."""
