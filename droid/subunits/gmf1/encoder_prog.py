"""droid-gmf1-encoder NAME: the GMF1 encoder program (thesis §4.2.5), the shell of :class:`EncoderCore`.

"The Encoder program operates at 120Hz using an independent timer so as to
isolate it from the rest of the DROID system."  Here: a
:class:`~droid.brain.runtime.rt.PeriodicTimer` (absolute deadlines) at the subunit's
``encoder_hz`` (120); each cycle reads the two encoder cards (the subunit's
``encoders`` URLs, :mod:`droid.subunits.gmf1.quad04`), runs
:class:`~droid.subunits.gmf1.encoder_core.EncoderCore` and writes
encoder_pos, x, y, z, R (global frame), updated_ns and, after homing, homed
into the controller's Status record.

Cards that are missing, unreadable, unpowered, or replaced under the program
(droid-sim restarted) are a device fault: the pose stops refreshing, the cards
are reopened with back-off, and a replaced card loses the home reference
(homed := 0, home again).

Options: ``--rate HZ`` overrides the cell file.  Exit: 0 on SIGTERM/SIGINT;
2 on a bad cell file or card URL; 1 if the databases are missing.
"""
from __future__ import annotations

import sys
import time

from droid.brain.db.databases import open_local
from droid.brain.runtime.program import ErrorLine, Presence, Stop, close_all, notify_ready, presence_key, subunit_program
from droid.brain.runtime.rt import PeriodicTimer, now_ns, try_sched_fifo
from droid.cli import BadInput, rate_hz, run
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T
from droid.subunits.gmf1.config import ENCODER_HZ_RANGE, gmf1_config
from droid.subunits.gmf1.encoder_core import EncoderCore
from droid.subunits.gmf1.quad04 import CardUnavailable, open_bank
from droid.subunits.gmf1.station import EncoderStation

PROG = "droid-gmf1-encoder"
REOPEN_MIN_S = 0.1
REOPEN_MAX_S = 2.0
CHECK_EVERY_S = 1.0  # how often to check that the cards are still the objects we mapped


class CardSession:
    """The open bank of cards, reopened with back-off after a failure."""

    def __init__(self, urls) -> None:
        self.urls = list(urls)
        self.bank = None
        self.next_open = 0.0
        self.backoff = REOPEN_MIN_S
        self.next_check = 0.0
        self.last_error = ""
        self.opens = 0
        self.identities = None  # what the last opened cards were
        self.changed = False  # the newest open found other objects than before

    def get(self, now_s: float):
        if self.bank is None and now_s >= self.next_open:
            try:
                self.bank = open_bank(self.urls)
                self.opens += 1
                ids = [c.identity for c in self.bank.cards]
                self.changed = self.identities is not None and ids != self.identities
                self.identities = ids
                self.backoff = REOPEN_MIN_S
                self.next_check = now_s + CHECK_EVERY_S
            except (CardUnavailable, BadInput) as exc:
                self._failed(now_s, str(exc))
        if self.bank is not None and now_s >= self.next_check:
            self.next_check = now_s + CHECK_EVERY_S
            if self.bank.replaced():
                self.drop(now_s, "encoder cards replaced or removed")
            elif not self.bank.powered:
                self.drop(now_s, "encoder cards not powered")
        return self.bank

    def _failed(self, now_s: float, why: str) -> None:
        self.last_error = why
        self.next_open = now_s + self.backoff
        self.backoff = min(self.backoff * 2, REOPEN_MAX_S)

    def drop(self, now_s: float, why: str) -> None:
        if self.bank is not None:
            self.bank.close()
            self.bank = None
        self._failed(now_s, why)

    def close(self) -> None:
        if self.bank is not None:
            self.bank.close()
            self.bank = None


@run
def main(argv=None) -> int:
    def options(ap):
        ap.add_argument("--rate", type=rate_hz(*ENCODER_HZ_RANGE), default=None, metavar="HZ",
                        help="read rate [Hz] (default: the cell file's encoder_hz, 120)")

    args, cell, sub = subunit_program(PROG, "Read the GMF1 encoder cards at 120 Hz and keep the Status pose fresh.",
                                      argv, arm=True, options=options, example="gmf1")
    cfg = gmf1_config(cell, sub)
    rate = args.rate or cfg.encoder_hz
    model = load_robot(sub.robot).with_base(pose_to_T(*sub.base))
    core = EncoderCore(model, rate)
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    status = open_local(cell, sub, "ctrl_status")
    station = EncoderStation(core, status)
    cards = CardSession(cfg.encoders)
    presence = None
    timer = None
    try:
        presence = Presence(cell.name, presence_key(PROG, sub.name), f"{PROG} {sub.name}")
        timer = PeriodicTimer(int(round(1e9 / rate)))
        presence.ready()
        notify_ready(args.ready_fd)
        errors = ErrorLine(PROG)
        had_bank = False
        while not Stop.requested:
            if not timer.wait(0.5):
                continue
            t_s = time.monotonic()
            bank = cards.get(t_s)
            if bank is not None and not had_bank:
                core.restart()
                if cards.changed:
                    status.update(homed=0)  # other cards (or power-cycled ones): the home reference is gone
            had_bank = bank is not None
            if bank is None:
                station.fault()
            else:
                try:
                    station.cycle(bank, now_ns())
                except (OSError, ValueError) as exc:
                    cards.drop(t_s, f"read failed: {exc}")
                    station.fault()
                    had_bank = False
            errors.update(cards.last_error)
            presence.beat(0, timer.cycles, timer.overruns, timer.lateness_max_ns)
        print(f"{PROG}: {station.refreshes} refreshes, {core.homings} homings, {timer.overruns} overruns, "
              f"worst lateness {timer.lateness_max_ns / 1e3:.0f} us", file=sys.stderr)
    finally:
        close_all(cards, timer, status, presence)
    return 0


if __name__ == "__main__":
    sys.exit(main())
