"""Write tests/abb/data/egm_exchange.json: a few EGM datagrams both ways, captured off real UDP
sockets on 127.0.0.1 -- the controller twin (droid-sim's abb_egm device) sending EgmRobot to a
socket served by droid-egm's core, and the core's EgmSensor replies read off the twin's socket.

    .venv/bin/python -m tests.abb.make_egm_capture

Run once when the exchange changes on purpose; tests/abb/test_egm_schema.py decodes the file."""
from __future__ import annotations

import json
import select
import socket
from pathlib import Path

import numpy as np

from droid.brain.db.layouts import CTRL_COMMAND_LAYOUT, JSPACE, NORMAL_MODE, new_record
from droid.kinematics import load_robot
from droid.sim.abb.controller import AbbEgmDevice, EgmController, EgmTwinParams, open_socket
from droid.subunits.abb.egm_core import EgmCore

OUT = Path(__file__).resolve().parent / "data" / "egm_exchange.json"


def main() -> None:
    model = load_robot("abb_irb2400")
    pc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    pc.bind(("127.0.0.1", 0))
    ctrl = EgmController(model, EgmTwinParams(test_signals=True), [0.0, 10.0, 10.0, 0.0, 60.0, 0.0])
    dev = AbbEgmDevice("abb", ctrl, open_socket(0, "capture"), pc.getsockname(), model)
    real = dev.sock
    core = EgmCore(model, 12, 60.0)
    cmd = new_record(CTRL_COMMAND_LAYOUT)
    cmd["cmd_mode"], cmd["coord"], cmd["link_alive"] = NORMAL_MODE, JSPACE, 1
    log = []

    class Logged:  # the twin's socket, logging what it reads: droid-egm's replies as sent
        def recvfrom(self, n):
            data, src = real.recvfrom(n)
            log.append({"t_ms": round(dev.t_s * 1000, 3), "dir": "pc->robot", "hex": data.hex()})
            return data, src

        def __getattr__(self, name):
            return getattr(real, name)

    dev.sock = Logged()
    target = np.array([0.5, 10.0, 10.0, 0.0, 60.0, -0.5])
    tick = 0
    for k in range(1, 25):
        dev.advance(0.001)
        while select.select([pc], [], [], 0.2)[0]:
            data, src = pc.recvfrom(65536)
            log.append({"t_ms": round(dev.t_s * 1000, 3), "dir": "robot->pc", "hex": data.hex()})
            reply = core.datagram(data, src, int(dev.t_s * 1e9))
            if reply is not None:
                pc.sendto(*reply)
            if not select.select([pc], [], [], 0)[0]:
                break
        if k in (6, 9):  # two planner ticks: anchored where the arm stands, then a step toward the target
            tick += 1
            q = core.sample.feedback_deg if k == 6 else target
            cmd["brain_tick"] = cmd["planner_tick"] = tick
            cmd["encoder_cmd_int"] = np.rint(model.gearing.joints_to_counts(q)).astype(np.int32)
            core.cycle(cmd, int(dev.t_s * 1e9))
    dev.close()
    pc.close()
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text(json.dumps({
        "about": "EGM datagrams captured on 127.0.0.1 between droid-sim's abb_egm twin and droid-egm's "
                 "core (tests/abb/make_egm_capture.py); hex of each UDP payload, in receive order",
        "datagrams": log}, indent=1) + "\n")
    print(f"{OUT}: {len(log)} datagrams")


if __name__ == "__main__":
    main()
