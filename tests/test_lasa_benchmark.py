"""The LASA benchmark's configuration and table: the ψ-compatibility hinge's step is a share of
each shape's workspace, and the table names each shape's worst demonstration."""

import numpy as np
import pytest

from tamedpuma.app.compose import compose_dict
from tamedpuma.puma import lasa_benchmark, pipeline, training


def _hinge_strength(p) -> float:
    """compat_weight × the step / the workspace size: the hinge's gradient grows with its step,
    so this is its weight against the imitation and stability terms, free of the data's unit."""
    size = float(np.max(np.subtract(p.workspace.high, p.workspace.low)))
    return p.train_cfg.compat_weight * training.compat_step(p.train_cfg, p.workspace) / size


@pytest.fixture(scope="module")
def lasa_shape():
    cfg = compose_dict("train", ["task=lasa", "puma=lasa", "task.shape=LShape"])
    return cfg, pipeline.prepare(cfg, log=lambda m: None)


def test_the_compat_hinge_judges_the_states_the_evaluation_judges(lasa_shape):
    """The hinge's states are uniform in the box beyond the ball the evaluation leaves out, and
    no direction meets the hinge within half a step of the goal: that ball holds those states."""
    _, p = lasa_shape
    size = float(np.max(np.subtract(p.workspace.high, p.workspace.low)))
    assert p.train_cfg.compat_uniform > 0
    assert p.train_cfg.compat_exclude * size == pytest.approx(p.eval_cfg.compat_min_dist)
    assert 0 < training.compat_step(p.train_cfg, p.workspace) <= p.eval_cfg.compat_min_dist


def test_the_compat_hinge_weighs_on_lasa_as_on_the_robot(lasa_shape):
    """The robot's 0.01 m step is 1% of its workspace; read as 0.01 mm on LASA's 60 mm box it
    gave the hinge 1/60 of that weight (59.5% ψ-compatible on LShape)."""
    _, p = lasa_shape
    robot = pipeline.prepare(compose_dict("train", ["task=tomato"]), log=lambda m: None)
    assert 0.5 < _hinge_strength(p) / _hinge_strength(robot) < 2.0


def test_the_table_shows_each_shapes_worst_demonstration():
    row = {"shape": "Angle", "rmse": 4.0, "dtw": 1.5, "dtw_max": 2.5, "frechet": 3.0,
           "grid_starts": 400, "grid_not_converged": 0, "random_converged_fraction": 1.0,
           "compatible_fraction": 0.998, "pos_tol": 0.6, "train_seconds": 44.0}
    other = {**row, "shape": "LShape", "dtw_max": 1.5, "grid_not_converged": 2}
    lines = lasa_benchmark.markdown([row, other]).splitlines()
    assert "worst demo DTW/point [mm]" in lines[0]
    assert lines[0].count("|") == lines[1].count("|") == lines[2].count("|")
    assert lines[2] == "| Angle | 4.00 | 1.50 | 2.50 | 3.00 | 0/400 | 100.0% | 99.8% | 44 |"
    assert lines[-1] == ("| **mean (2 shapes)** | 4.00 | 1.50 | 2.00 | 3.00 | 2/800 | 100.0% | "
                         "99.8% | 44 |")
