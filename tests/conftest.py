"""Shared fixtures: the default robot, its kinematics, the shared/ data folder, a recorder
of the controller's scalars and a minimal pair of saved benchmark reports."""

from __future__ import annotations

import json
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


def real_model(task: str) -> Path | None:
    """The real-data second-order model of ``task`` the tests run with, or None where there is
    none: ``$TAMEDPUMA_MODELS/<task>/puma.pt`` where that variable is set (None if that file is
    missing), else the model a run with ``method.model=real`` takes
    (:func:`tamedpuma.puma.store.resolve`: the models cache, then ``runs/puma``)."""
    import os

    from tamedpuma.errors import CheckpointError
    from tamedpuma.puma import store

    root = os.environ.get("TAMEDPUMA_MODELS")
    if root:
        path = Path(root) / task / "puma.pt"
        return path if path.is_file() else None
    try:
        return store.resolve(task, 2, model="real").path
    except CheckpointError:
        return None


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


@pytest.fixture
def saved_bench_reports(tmp_path):
    """A minimal ``benchmarks/bench.json`` and ``benchmarks/fabrics.json`` under ``tmp_path`` (what
    ``python -m tamedpuma.bench --render`` reads): the saved bench report (a dict)."""
    machine = {"cpu_model": "c", "cores": 2, "python": "3", "numpy": "2"}
    report = {"date": "d", "command": "python -m tamedpuma.bench --table1",
              "controller": [{"method": "fpm", "n_obstacles": 2, "median_ms": 0.5,
                              "p10_ms": 0.4, "p90_ms": 0.6, "n_calls": 9,
                              "first_call_ms": 1.0}], "machine": machine}
    fabrics = {"date": "d", "results": [{"n_obstacles": 2, "median_ms": 0.1, "p10_ms": 0.1,
                                         "p90_ms": 0.1, "mean_ms": 0.1, "n_calls": 5,
                                         "first_call_ms": 1.0}],
               "build_ms": 0.1, "kinematics_median_ms": 0.02, "reference_live": {},
               "reference_note": None, "machine": {**machine, "blas": "b"}}
    (tmp_path / "benchmarks").mkdir()
    (tmp_path / "benchmarks" / "bench.json").write_text(json.dumps(report))
    (tmp_path / "benchmarks" / "fabrics.json").write_text(json.dumps(fabrics))
    return report
