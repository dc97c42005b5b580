"""Shared fixtures: the default robot, its kinematics, the shared/ data folder and a recorder
of the controller's scalars."""

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


class ScalarLog:
    """A recorder keeping every step's controller scalars (``rows``: one dict per step)."""

    def __init__(self):
        self.rows = []

    def open(self, info):
        pass

    def write(self, rec):
        self.rows.append(dict(rec.scalars))

    def close(self, complete, summary):
        pass


@pytest.fixture
def scalar_log():
    return ScalarLog()


@pytest.fixture
def point_scale_forcing(monkeypatch):
    """The metric forcing's constants at the point robot's scale: the task metric w = 20 and no
    elbow objective (the iiwa's w = 100 outweighs the point's 0.2 m barrier metric until the
    point touches it)."""
    from tamedpuma.methods import _tamed

    monkeypatch.setattr(_tamed, "TASK_WEIGHT", 20.0)
    monkeypatch.setattr(_tamed, "NULL_METRIC", 0.0)
