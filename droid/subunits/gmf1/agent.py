"""droid-gmf1-agent NAME: the gmf1 subunit server (thesis §4.2.3).

The generic agent (droid.subunits.agent) under the thesis's name: it
copies the Brain's command into the motion controller's Command record,
replies with its Status record and relays the heartbeat tick to the
serial program.
"""
from __future__ import annotations

import sys

from droid.subunits.agent import agent_program

PROG = "droid-gmf1-agent"
main = agent_program(PROG, __name__)


if __name__ == "__main__":
    sys.exit(main())
