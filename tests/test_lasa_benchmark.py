"""The LASA benchmark's configuration and table: the ψ-compatibility hinge's step is a length in
LASA's millimetres, and the table names each shape's worst demonstration."""

import numpy as np
import pytest

from tamedpuma.app.compose import compose_dict
from tamedpuma.puma import lasa_benchmark, pipeline


def _hinge_strength(train: dict, size: float) -> float:
    """compat_weight × compat_eps / the workspace size: the hinge's gradient grows with its step,
    so this is its weight against the imitation and stability terms, free of the data's unit."""
    return train["compat_weight"] * train["compat_eps"] / size


@pytest.fixture(scope="module")
def lasa_shape():
    cfg = compose_dict("train", ["task=lasa", "puma=lasa", "task.shape=LShape"])
    return cfg, pipeline.prepare(cfg, log=lambda m: None)


def test_the_compat_step_is_inside_the_convergence_tolerance(lasa_shape):
    """No direction meets the hinge within half a step of the goal (every step leaves that ball
    outwards): the step stays well inside the tolerance the convergence is judged by."""
    cfg, p = lasa_shape
    assert 0 < cfg["puma"]["train"]["compat_eps"] <= 0.25 * p.eval_cfg.pos_tol


def test_the_compat_hinge_weighs_on_lasa_as_on_the_robot(lasa_shape):
    """The robot's 0.01 m step is 1% of its workspace; read as 0.01 mm on LASA's 60 mm box it
    gave the hinge 1/60 of that weight (59.5% ψ-compatible on LShape)."""
    cfg, p = lasa_shape
    lasa = _hinge_strength(cfg["puma"]["train"],
                           float(np.max(np.subtract(p.workspace.high, p.workspace.low))))
    robot = compose_dict("train", ["task=tomato"])
    ws = robot["task"]["workspace"]
    size = float(np.max(np.subtract(ws["position_high"], ws["position_low"])))
    assert 0.5 < lasa / _hinge_strength(robot["puma"]["train"], size) < 2.0


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
