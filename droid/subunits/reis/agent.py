"""droid-reis-agent NAME: the reis subunit server (thesis §4.1.8).

The generic agent (droid.subunits.agent) under the thesis's name: it
copies the Brain's command into the motion controller's Command record,
replies with its Status record and relays the heartbeat tick to the
planner.
"""
from __future__ import annotations

import sys

from droid.subunits.agent import agent_program

PROG = "droid-reis-agent"
main = agent_program(PROG, __name__)


if __name__ == "__main__":
    sys.exit(main())
