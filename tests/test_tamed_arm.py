"""The PUMA-driven methods (puma, fpm, cpm) on the KUKA arm, with a tiny trained model: the
potential's joint-space gradient, one-override switching through the sweep, checkpoint errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tamedpuma.app import train
from tamedpuma.methods._policy import PoseTask
from tamedpuma.puma.primitive import load_primitive
from tamedpuma.recording import read_mcap

REPO = Path(__file__).resolve().parents[1]
GOAL_P = np.array([0.58, -0.214, 0.115])
GOAL_Q = np.array([-0.5459, 0.5806, -0.4112, 0.4426])


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny_tomato")
    assert train.main(["task=tomato", "puma=tiny", f"out_dir={out}", "progress=false",
                       "evaluate=false"]) == 0
    return out / "puma.pt"


def test_potential_gradient_in_joint_space_matches_finite_differences(tiny_checkpoint,
                                                                      kinematics, robot_spec):
    """∂ψ/∂q = ∂ψ/∂p J_v + ∂ψ/∂θ J_ω, the orientation part included, against central FD."""
    task = PoseTask(load_primitive(tiny_checkpoint))
    rng = np.random.default_rng(0)
    h = 1e-6
    zeros = np.zeros(7)
    for _ in range(10):
        q = rng.uniform(robot_spec.q_min * 0.8, robot_spec.q_max * 0.8)
        _, grad = task.potential(kinematics.evaluate(q, zeros), GOAL_P, GOAL_Q)
        fd = np.zeros(7)
        for i in range(7):
            dq = np.zeros(7)
            dq[i] = h
            hi = task.potential(kinematics.evaluate(q + dq, zeros), GOAL_P, GOAL_Q)[0]
            lo = task.potential(kinematics.evaluate(q - dq, zeros), GOAL_P, GOAL_Q)[0]
            fd[i] = (hi - lo) / (2 * h)
        np.testing.assert_allclose(grad, fd, rtol=1e-4, atol=1e-6 * max(1, np.abs(fd).max()))
        # the check covers the orientation part: it is a sizeable share of the gradient
        state = kinematics.evaluate(q, zeros)
        _, _, d_theta = task.primitive.potential(state.ee_position, state.ee_quaternion,
                                                 GOAL_P, GOAL_Q)
        orientation_part = d_theta @ state.ee_jacobian[3:]
        assert np.linalg.norm(orientation_part) > 1e-3 * np.linalg.norm(grad)


def _sweep(*args):
    return subprocess.run([sys.executable, "-m", "tamedpuma.sweep", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("method, scalars", [
    ("puma", {"task_acc_norm"}),
    ("fpm", {"energy_fabric", "alpha", "min_clearance_m"}),
    ("cpm", {"psi", "psi_rate", "energy_total", "alpha", "beta", "dissipation"}),
])
def test_each_method_is_one_override_away(tmp_path, tiny_checkpoint, method, scalars):
    proc = _sweep(f"method={method}", f"method.checkpoint={tiny_checkpoint}",
                  f"output_root={tmp_path}", "recorder=mcap", "scenario.max_steps=40",
                  "stop_on_success=false")
    assert proc.returncode == 0, proc.stderr
    (log_path,) = tmp_path.glob("*/episode.mcap")
    log = read_mcap(log_path)
    assert log.n_steps == 40 and log.complete
    assert scalars | {"compute_time_ms", "clearance_m"} <= set(log.scalars.columns)
    assert np.isfinite(log.joints.to_numpy()).all()


def test_missing_checkpoint_is_a_one_line_error_with_the_train_command(tmp_path):
    proc = _sweep("method=fpm", "method.checkpoint=runs/puma/nowhere/puma.pt",
                  f"output_root={tmp_path}")
    assert proc.returncode == 2
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith("error: no PUMA checkpoint") and "python -m tamedpuma.train" in line
    assert "Traceback" not in proc.stderr
