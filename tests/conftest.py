"""Shared fixtures: the default robot, its kinematics and the shared/ data folder."""

from __future__ import annotations

from pathlib import Path

import pytest

from tamedpuma.app.config import robot_config
from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def robot_spec():
    return robot_spec_from_config(robot_config("iiwa14"))


@pytest.fixture(scope="session")
def kinematics(robot_spec):
    return Kinematics(robot_spec)


@pytest.fixture(scope="session")
def shared_dir():
    if not SHARED.is_dir():
        pytest.skip("../shared (reference data) is absent on this machine")
    return SHARED
