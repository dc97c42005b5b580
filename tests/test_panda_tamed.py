"""FPM and CPM drive the Franka Panda (robot=panda) to a goal past an obstacle without contact,
with a small PUMA model trained here on synthetic demonstrations in the Panda's workspace
(task=panda_reach, position-only, puma=small: about a CPU-minute)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tamedpuma.app import train

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def panda_model(tmp_path_factory):
    out = tmp_path_factory.mktemp("panda_reach")
    assert train.main(["task=panda_reach", "puma=small", "puma.orientation=false",
                       f"out_dir={out}", "progress=false", "evaluate=false"]) == 0
    return out / "puma.pt"


@pytest.mark.parametrize("method", ["fpm", "cpm"])
def test_panda_reaches_the_goal_past_an_obstacle_without_contact(panda_model, method, tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "tamedpuma.sweep", "robot=panda", "task=panda_reach",
         "scenario=panda_reach/00", f"method={method}", f"method.checkpoint={panda_model}",
         "recorder=none", f"output_root={tmp_path}"],
        cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    (summary_path,) = tmp_path.glob("*/summary.json")
    s = json.loads(summary_path.read_text())
    assert s["success_whole_body"], s
    assert s["min_clearance_m"] > 0 and not s["obstacle_contact"] and not s["sphere_penetration"]
    assert s["joint_limit_violation_steps"] == 0
