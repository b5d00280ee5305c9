"""The observe tests' fixture (a cell's Brain databases without any program), and a leak check of
Fast DDS's shared-memory segments: a ROS 2 process that dies without shutting rclpy down leaves its
``/dev/shm/fastdds_*`` files behind (seen while droid-ros2 aborted at exit), so every test here must
leave none of its own."""
from __future__ import annotations

import os
import time

import pytest

from tests.observe.conftest import db_cell  # noqa: F401

SHM = "/dev/shm"


def fastdds_files() -> set[str]:
    try:
        return {n for n in os.listdir(SHM) if n.startswith(("fastdds_", "sem.fastdds_"))}
    except FileNotFoundError:
        return set()


@pytest.fixture(autouse=True)
def no_fastdds_leaks():
    before = fastdds_files()
    yield
    deadline = time.monotonic() + 5.0
    while (left := fastdds_files() - before) and time.monotonic() < deadline:
        time.sleep(0.2)  # a participant's segments go as its process ends
    assert not left, f"Fast DDS shared memory left in {SHM}: {sorted(left)}"
