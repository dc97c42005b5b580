"""A briefly trained primitive converges to the goal from random starts; ψ is mostly compatible."""

import numpy as np
import pytest

from tamedpuma.puma import data, evaluation, training
from tamedpuma.puma.network import NetConfig, StateSpec


@pytest.fixture(scope="module")
def lasa_model():
    demos = data.prepare(data.load_lasa("Angle", every=10), 0.03, smoothing=1.0)
    ws = training.Workspace.around(demos, 0.1)
    cfg = training.TrainConfig(iterations=200, batch_windows=32, window=8, stability_batch=32,
                               stability_horizon=6)
    res = training.train(demos, ws, StateSpec(2, False, 2), NetConfig(64, 32), cfg, seed=0,
                         progress=False)
    return res.net, demos, ws


def test_converges_from_random_starts(lasa_model):
    net, demos, ws = lasa_model
    size = float(np.max(np.subtract(ws.high, ws.low)))
    cfg = evaluation.EvalConfig(random_starts=1000, horizon=20.0, pos_tol=0.01 * size,
                                compat_samples=500, compat_min_dist=0.02 * size)
    conv = evaluation.convergence(net, ws, demos.dt, cfg)
    assert conv["starts"] == 1000 and conv["converged_fraction"] == 1.0, conv
    comp = evaluation.compatibility(net, ws, cfg)
    assert comp["compatible_fraction"] > 0.8, comp
    im = evaluation.imitation_metrics(net, demos)
    assert im["dtw"] < 0.1 * size  # roughly imitates after 200 iterations


def test_distance_metrics():
    a = np.stack([np.linspace(0, 1, 11), np.zeros(11)], 1)
    assert evaluation.dtw_per_point(a, a) == 0.0 and evaluation.frechet(a, a) == 0.0
    b = a + [0.0, 0.1]
    assert evaluation.frechet(a, b) == pytest.approx(0.1)
    assert evaluation.dtw_per_point(a, b) == pytest.approx(0.1)
    slow = np.repeat(a, 2, axis=0)  # same path, other timing: DTW and Fréchet ignore timing
    assert evaluation.dtw_per_point(slow, a) == pytest.approx(0.0)
    assert evaluation.frechet(slow, a) == pytest.approx(0.0)


def test_physical_time_control_rate_matches_model_rate(lasa_model):
    """The model is an ODE in seconds: integrating at 50 Hz (control) follows the 33 Hz path."""
    net, demos, ws = lasa_model
    p0 = demos.pos[0][:1]
    coarse, _ = evaluation.rollout_paths(net, p0, None, 100, 0.03)  # 3 s
    fine, _ = evaluation.rollout_paths(net, p0, None, 150, 0.02)  # 3 s
    size = float(np.max(np.subtract(ws.high, ws.low)))
    gap = np.abs(coarse[0, ::2] - fine[0, ::3]).max()  # same instants 0, 0.06, ..., 3 s
    assert gap < 0.05 * size, gap
