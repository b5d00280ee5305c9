"""The GMF1 subunit's own keys in the cell file's ``[subunits.NAME]`` table (thesis §4.2).

Keys (with defaults)::

    serial = "{run}/NAME.tty"     # the KAREL server's port: a device path (/dev/ttyS0),
                                  # a pty link made by droid-sim, or any pyserial URL
                                  # (socket://host:port, loop://, ...)
    baud = 9600                   # thesis §4.2.4
    encoders = ["shm://droid.{cell}.NAME.quad0", "shm://droid.{cell}.NAME.quad1"]
                                  # the two CIO-QUAD04 cards (droid.subunits.gmf1.quad04 URLs)
    encoder_hz = 120.0            # thesis §4.2.5: "at a rate of 120Hz"
    reply_timeout_s = 1.0         # a request unanswered this long is a device fault
    done_margin_s = 1.0           # a move not DONE by its planned end + this margin (and +25 %) is a fault

Unknown keys are refused with the file and key named.
"""
from __future__ import annotations

from dataclasses import dataclass

from droid.brain.cell.cellfile import Cell, Subunit
from droid.cli import BadInput, file_number
from droid.numbers import Range, baud_range
from droid.subunits.gmf1.karel_wire import BAUD, MIN_BAUD
from droid.subunits.gmf1.quad04 import check_url

#: The encoder read rates a GMF1 accepts [Hz] ([subunits.X] encoder_hz, droid-gmf1-encoder --rate).
ENCODER_HZ_RANGE = (1.0, 2000.0)
KEYS = ("serial", "baud", "encoders", "encoder_hz", "reply_timeout_s", "done_margin_s")


@dataclass(frozen=True)
class Gmf1Config:
    serial: str
    baud: int
    encoders: tuple[str, str]
    encoder_hz: float
    reply_timeout_s: float
    done_margin_s: float


def default_encoder_urls(cell_name: str, sub_name: str) -> list[str]:
    return [f"shm://droid.{cell_name}.{sub_name}.quad{i}" for i in range(2)]


def gmf1_config(cell: Cell, sub: Subunit) -> Gmf1Config:
    """Read and validate the subunit's GMF1 keys (BadInput naming file and key)."""
    o = dict(sub.options)
    where = f"{cell.path}: [subunits.{sub.name}]"
    unknown = sorted(set(o) - set(KEYS))
    if unknown:
        raise BadInput(f"{where} unknown key(s) for a GMF1 subunit: {', '.join(unknown)} "
                       f"(known: {', '.join(KEYS)})")
    serial = o.get("serial", f"{cell.run_dir}/{sub.name}.tty")
    if not isinstance(serial, str) or not serial:
        raise BadInput(f"{where} serial must be a non-empty string (a device path or pyserial URL)")
    baud = file_number(o.get("baud", BAUD), baud_range(MIN_BAUD), where, "baud")
    encoders = o.get("encoders", default_encoder_urls(cell.name, sub.name))
    if not isinstance(encoders, list) or len(encoders) != 2 or not all(isinstance(u, str) for u in encoders):
        raise BadInput(f"{where} encoders must be a list of 2 card URLs (shm://NAME or mem://PATH?offset=N)")
    try:
        for u in encoders:
            check_url(u)
    except BadInput as exc:
        raise BadInput(f"{where} encoders: {exc}") from None
    vals = {}
    for key, default, rng in (("encoder_hz", 120.0, Range(*ENCODER_HZ_RANGE, "Hz")),
                              ("reply_timeout_s", 1.0, Range(0.05, 60.0, "s")),
                              ("done_margin_s", 1.0, Range(0.0, 600.0, "s"))):
        vals[key] = file_number(o.get(key, default), rng, where, key)
    return Gmf1Config(serial=serial, baud=baud, encoders=(encoders[0], encoders[1]), **vals)
