"""The experiment configs beyond Table 1 (scaling, disturbances, the randomized suite) compose
and run through the sweep (one short job each) and their analyses read the result."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _multirun(tmp_path, *overrides):
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.sweep", "-m", *overrides,
                           "method=joint_attractor", "recorder=none", "scenario.max_steps=30",
                           f"output_root={tmp_path}"], cwd=REPO, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    (summary,) = tmp_path.rglob("summary.json")
    return summary, json.loads(summary.read_text())


def test_scaling_fills_the_scene_to_the_total_count(tmp_path):
    path, summary = _multirun(tmp_path, "+experiment=scaling", "+case=pouring_03",
                              "clutter.total=100")
    assert summary["n_obstacles"] == 100 and summary["scenario"] == "pouring_03"
    assert path.parent.parent.name == "100"  # runs/scaling/<count>/<method>_<task>_<scenario>
    assert len(summary["step_compute_ms"]) == summary["steps"]
    # the run's own wall times (the bench's Table-1 profile): set-up and episode, the episode
    # at least the controller's own time
    wall = summary["wall_s"]
    assert wall["build"] > 0 and wall["episode"] >= sum(summary["step_compute_ms"]) / 1e3
    # of the episode, the simulator's steps (PyBullet's physics and the next observation)
    assert 0 < wall["simulator"] < wall["episode"] - sum(summary["step_compute_ms"]) / 1e3
    out = subprocess.run([sys.executable, "-m", "analysis.scaling", str(tmp_path / "scaling")],
                         cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "100 obstacles" in out.stdout


@pytest.mark.parametrize("name, control", [("push", "impedance"), ("impedance", "impedance"),
                                           ("goal_change", "velocity"),
                                           ("obstacle_noise", "velocity")])
def test_each_disturbance_is_one_config(tmp_path, name, control):
    path, summary = _multirun(tmp_path, "+experiment=disturbance", "+case=tomato_default",
                              f"disturbance={name}")
    assert summary["disturbance"] == name and summary["control"] == control
    assert path.parent.parent.name == name


def test_random_suite_runs_a_generated_scenario(tmp_path):
    _, summary = _multirun(tmp_path, "+experiment=random", "task=tomato",
                           "scenario.random_seed=2000", "scenario.start_kind=anywhere",
                           "without_obstacles=false")
    assert summary["scenario"] == "random_tomato_anywhere_2000" and summary["n_obstacles"] >= 1
