"""The joystick's twin: a Linux joystick device on a pseudo-terminal (thesis §2.6, §3.4)."""
