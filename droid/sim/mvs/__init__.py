"""The MVS twin: camera and DSP board, the tool-tip sensor, their world devices and lockstep chain (thesis §2.5, §5.3-5.4, §6.1)."""
