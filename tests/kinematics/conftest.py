"""Fixtures for the kinematics tests."""
from __future__ import annotations

import pytest

from droid.kinematics import load_robot

from helpers_kin import offset_robot_toml


@pytest.fixture(scope="session")
def reis():
    return load_robot("reis_v15")


@pytest.fixture(scope="session")
def fanuc():
    return load_robot("fanuc_s400")


@pytest.fixture(scope="session")
def offset_robot(tmp_path_factory):
    path = tmp_path_factory.mktemp("robots") / "offset_test.toml"
    path.write_text(offset_robot_toml())
    return load_robot(str(path))
