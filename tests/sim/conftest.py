"""Fixtures shared by the droid-experiment tests."""
import pytest

from tests.sim.sweep20 import pool_reference


@pytest.fixture(scope="session")
def sweep20_reference(tmp_path_factory) -> str:
    """results.csv of one uninterrupted pool run of tests/sim/sweep20.py's plan (run once)."""
    return pool_reference(tmp_path_factory.mktemp("sweep20"))
