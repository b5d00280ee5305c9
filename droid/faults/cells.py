"""Cell files for fault experiments: the Reis alone, on one host behind a fault proxy
(the campaign), or split over two hosts (network namespaces, tcp)."""
from __future__ import annotations


def campaign_cell_text(name: str, run_dir: str) -> str:
    """A one-host cell with the Reis alone, its agent link behind a fault proxy."""
    return f'''
[cell]
name = "{name}"
run_dir = "{run_dir}"
heartbeat_hz = 60.0
stale_ticks = 3
sched_fifo = true

[brain]
host = "brain"

[world]
enabled = true
host = "arm1"
rate_hz = 1000.0
seed = 1

[world.devices.arm1]
type = "reis_vme"
subunit = "arm1"

[subunits.arm1]
class = "arm6r"
robot = "reis_v15"
host = "arm1"
programs = ["droid-watchdog", "droid-servo", "droid-servo-agent", "droid-reis-agent", "droid-planner"]
vme = "shm://droid.{{cell}}.arm1.vme"
servo = "ipc://{{run}}/arm1.servo"
servo_status = "ipc://{{run}}/arm1.servostat"

[interpose]
"ipc://{{run}}/arm1.agent" = "ipc://{{run}}/arm1.agent.inner"
'''


def two_host_cell_text(name: str, run_dir: str, brain_addr: str, arm_addr: str) -> str:
    """arm1 (Reis) on host arm1 with the world; the Brain on host brain; tcp between them."""
    return f'''
[cell]
name = "{name}"
run_dir = "{run_dir}"
heartbeat_hz = 60.0
stale_ticks = 3
sched_fifo = true

[brain]
host = "brain"
heartbeat = "tcp://{brain_addr}:5551"
names = "tcp://{brain_addr}:5550"

[world]
enabled = true
host = "arm1"
rate_hz = 1000.0
seed = 1

[world.devices.arm1]
type = "reis_vme"
subunit = "arm1"

[subunits.arm1]
class = "arm6r"
robot = "reis_v15"
host = "arm1"
agent = "tcp://{arm_addr}:5552"
relay = "ipc://{{run}}/arm1.relay"
programs = ["droid-watchdog", "droid-servo", "droid-servo-agent", "droid-reis-agent", "droid-planner"]
vme = "shm://droid.{{cell}}.arm1.vme"
servo = "ipc://{{run}}/arm1.servo"
servo_status = "ipc://{{run}}/arm1.servostat"
'''


def seam_campaign_cell_text(name: str, run_dir: str) -> str:
    """The built-in seam-tracking cell (both arms, the MVS and tool sensors) with arm1's
    agent link behind a fault proxy, as in :func:`campaign_cell_text`."""
    import re

    from droid.brain.cellfile import builtin_cell_path

    text = builtin_cell_path().read_text()
    text, n = re.subn(r'(?m)^name = "[^"]*"', f'name = "{name}"\nrun_dir = "{run_dir}"', text, count=1)
    if n != 1:
        raise RuntimeError("the built-in cell has no [cell] name line")
    return text + '''
[interpose]
"ipc://{run}/arm1.agent" = "ipc://{run}/arm1.agent.inner"
'''
