"""The whole chain on the Franka Panda (robot=panda): a sweep that logs its run, the analysis of
the log and the replay's recording, each naming the Panda's joints and links (nothing outside
conf/robot names the iiwa's)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
PANDA = yaml.safe_load((REPO / "tamedpuma/conf/robot/panda.yaml").read_text())


@pytest.fixture(scope="module")
def panda_run(tmp_path_factory) -> Path:
    """One short logged Fabrics run (no model needed) of the Panda's reach task."""
    out = tmp_path_factory.mktemp("panda_runs")
    proc = subprocess.run(
        [sys.executable, "-m", "tamedpuma.sweep", "robot=panda", "task=panda_reach",
         "scenario=panda_reach/00", "method=fabrics", "recorder=mcap", "scenario.max_steps=40",
         f"output_root={out}"],
        cwd=out, env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True, text=True,
        timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (summary,) = out.glob("*/summary.json")
    return summary.parent


@pytest.mark.slow
def test_the_sweep_logs_the_panda(panda_run):
    from tamedpuma.recording import read_mcap

    log = read_mcap(panda_run / "episode.mcap")
    assert log.info["joint_names"] == PANDA["joint_names"]
    assert log.info["link_names"] == PANDA["link_names"]
    summary = json.loads((panda_run / "summary.json").read_text())
    assert summary["steps"] == 40
    assert yaml.safe_load(log.config_yaml)["robot"]["name"] == "panda"


@pytest.mark.slow
def test_the_analysis_reads_the_panda_log(panda_run):
    from tamedpuma.analysis.runs import joint_columns, run_row
    from tamedpuma.recording import read_mcap

    log = read_mcap(panda_run / "episode.mcap")
    assert joint_columns(log.joints) == [f"q_{i}" for i in range(len(PANDA["joint_names"]))]
    metrics, ee, ms = run_row(panda_run / "episode.mcap")
    summary = json.loads((panda_run / "summary.json").read_text())
    assert ee.shape == (40, 3) and ms.shape == (40,)
    assert metrics["joint_limit_violation_steps"] == summary["joint_limit_violation_steps"]
    np.testing.assert_allclose(metrics["final_position_error_m"],
                               summary["final_position_error_m"], rtol=1e-6)


@pytest.mark.slow
def test_the_replay_builds_the_panda_recording(panda_run):
    from tamedpuma.app import replay
    from tamedpuma.recording import read_rrd_joints

    assert replay.main([str(panda_run), "--build"]) == 0
    joints = read_rrd_joints(panda_run / "episode.rrd")
    assert set(PANDA["joint_names"]) <= set(joints.columns)


def test_the_replay_hides_the_collision_meshes_of_the_robot_it_shows():
    """The scene hides the collision meshes under the URDF's robot name (the Panda's, not a
    fixed iiwa path), and names none without a robot model."""
    from tamedpuma.recording.rerun_writer import replay_blueprint

    def hidden(blueprint):
        scene = blueprint.root_container.contents[0]
        return {path for path in scene.visualizer_overrides if "collision" in path}

    assert hidden(replay_blueprint(robot="panda")) == {"/world/panda/collision_geometries"}
    assert hidden(replay_blueprint()) == set()
