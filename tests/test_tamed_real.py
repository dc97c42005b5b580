"""FPM and CPM on the default scenarios with the real trained models (issue: "TamedPUMA FPM and
CPM"). Skipped unless `runs/puma/<task>/puma.pt` exists (train it first, see README)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from tamedpuma.analysis.path_difference import path_difference
from tamedpuma.app.config import load_group
from tamedpuma.episode import run_episode
from tamedpuma.methods import make
from tamedpuma.worlds.bullet import Simulator
from tamedpuma.worlds.scenarios import scenario_from_config

REPO = Path(__file__).resolve().parents[1]




class _PsiSpy:
    """Wraps a controller and keeps the ψ it logs at every step."""

    def __init__(self, controller):
        self.controller, self.psi = controller, []

    def reset(self, scenario):
        self.psi = []
        self.controller.reset(scenario)

    def step(self, obs):
        command = self.controller.step(obs)
        self.psi.append(command.scalars.get("psi", np.nan))
        return command


def _model(task) -> Path:
    """The trained model: $TAMEDPUMA_MODELS/<task>/puma.pt if that variable is set, else
    runs/puma/<task>/puma.pt (README's training commands)."""
    root = os.environ.get("TAMEDPUMA_MODELS")
    return Path(root) / task / "puma.pt" if root else REPO / "runs" / "puma" / task / "puma.pt"


def _method_cfg(name, task):
    from tamedpuma.app.train import compose

    cfg = compose("sweep", [f"method={name}", f"task={task}",
                            f"method.checkpoint={_model(task)}"])
    return cfg["method"]


def _scenario(spec, task, obstacles):
    cfg = load_group("scenario", "default")
    t = load_group("task", task)
    cfg["goal"].update(position=t["goal_position"], quaternion=t["goal_quaternion"])
    if not obstacles:
        cfg["obstacles"] = []
    return scenario_from_config(cfg, spec, task=task)


@pytest.mark.parametrize("task", ["tomato", "pouring"])
def test_fpm_and_cpm_follow_puma_and_avoid_on_the_default_scenarios(task, robot_spec,
                                                                     kinematics):
    if not _model(task).is_file():
        pytest.skip(f"no trained model at {_model(task)} (set TAMEDPUMA_MODELS or train one)")
    paths = {}
    for name in ("puma", "fpm", "cpm"):
        controller = _PsiSpy(make(name, _method_cfg(name, task), kinematics))
        with Simulator(robot_spec) as sim:
            free = run_episode(_scenario(robot_spec, task, False), controller, sim)
        paths[name] = free.ee_position
        assert free.metrics.success
        if name == "cpm":  # without obstacles ψ never rises (float32 network: relative 1e-6)
            psi = np.asarray(controller.psi)
            assert np.all(np.isfinite(psi)) and psi[-1] < 0.5 * psi[0]  # stopped 5 cm out
            assert np.max(np.diff(psi)) <= 1e-6 * psi[0]
        if name == "puma":
            continue
        assert path_difference(free.ee_position, paths["puma"]) <= 0.02
        with Simulator(robot_spec) as sim:
            run = run_episode(_scenario(robot_spec, task, True), controller, sim)
        m = run.metrics
        assert m.success and not m.collided and m.min_clearance_m > 0
        assert m.joint_limit_violation_steps == 0
        assert np.all(np.abs(run.q) <= robot_spec.q_max)
