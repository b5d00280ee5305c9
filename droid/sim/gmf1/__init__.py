"""The GM Fanuc S400 world: its KAREL controller on a serial line and its encoder cards (thesis §2.4, §4.2)."""
