"""The GMF1 serial program's port: the cell's one serial port (:mod:`droid.brain.plumbing.serial_port`).

Kept as a module so the GMF1's station, shell and lockstep twin import the
port they use from their own package.
"""
from droid.brain.plumbing.serial_port import READ_ROUNDS, PortLink, serial_opener  # noqa: F401

__all__ = ["READ_ROUNDS", "PortLink", "serial_opener"]
