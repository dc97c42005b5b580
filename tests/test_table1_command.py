"""``python -m tamedpuma.sweep +experiment=table1``: one multirun over both tasks' scenarios, every
Table-1 method, with and without obstacles; it ends with the analysis of its own folder. Here on
two scenarios and the model-free methods (the full sweep is measured in BENCHMARKS.md)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from tamedpuma.app.config import CONF_DIR

REPO = Path(__file__).resolve().parents[1]


def _sweep(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "tamedpuma.sweep", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=timeout)


def test_the_experiment_covers_every_table1_method_both_tasks_and_all_30_scenarios():
    exp = yaml.safe_load((CONF_DIR / "experiment" / "table1.yaml").read_text())
    params = exp["hydra"]["sweeper"]["params"]
    methods = set(params["method"].split(","))
    configs = {p.stem for p in (CONF_DIR / "method").glob("*.yaml")}
    assert methods == configs - {"joint_attractor"}  # every method config but the skeleton's
    cases = str(params["case"]).split(",")
    assert sorted(cases) == sorted(f"{t}_{i:02d}" for t in ("tomato", "pouring")
                                   for i in range(15))
    for case in cases:  # each names its task and the scenario of that task
        task, index = case.split("_")
        assert yaml.safe_load((CONF_DIR / "case" / f"{case}.yaml").read_text())["defaults"] == [
            {"override /task": task}, {"override /scenario": f"{task}/{index}"}]
        assert (CONF_DIR / "scenario" / task / f"{index}.yaml").is_file()
    assert set(str(params["without_obstacles"]).split(",")) == {"false", "true"}
    assert exp["hydra"]["mode"] == "MULTIRUN"


def _check(proc, root: Path, runs: int, tmp_path: Path):
    assert proc.returncode == 0, proc.stderr[-2000:]
    sweep = root / "table1"
    assert len(list(sweep.rglob("episode.mcap"))) == runs
    for name in ("table1.md", "table1.tex", "runs.csv"):
        assert (sweep / name).is_file(), name
    # the printed table is the one `python -m analysis.tables` makes of the same folder
    again = subprocess.run([sys.executable, "-m", "analysis.tables", str(sweep), "--out",
                            str(tmp_path / "again")], cwd=REPO, capture_output=True, text=True,
                           timeout=120)
    assert again.returncode == 0, again.stderr
    table = (tmp_path / "again" / "table1.md").read_text()
    assert (sweep / "table1.md").read_text() == table
    printed = table.split("\n\n")[0]
    assert printed in proc.stdout
    assert "no trained model used" in table  # the table says where its models came from


@pytest.mark.slow
def test_a_small_table1_sweep_runs_in_parallel_and_ends_with_the_table(tmp_path):
    proc = _sweep("-m", "+experiment=table1", f"output_root={tmp_path}",
                  "case=tomato_00,pouring_05", "method=fabrics",
                  "hydra.callbacks.table1.build_models=false")
    _check(proc, tmp_path, 4, tmp_path)
    assert "table1: 4 runs" in proc.stdout and "[4/4]" in proc.stdout
    assert "n_jobs=-1" in proc.stdout + proc.stderr  # joblib on all cores
    for mode in ("True", "False"):
        assert (tmp_path / "table1" / "tomato" / f"fabrics_tomato_00_{mode}").is_dir()
        assert (tmp_path / "table1" / "pouring" / f"fabrics_pouring_05_{mode}").is_dir()


@pytest.mark.slow
def test_the_same_sweep_through_submitit_local(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    proc = _sweep("-m", "+experiment=table1", f"output_root={tmp_path}", "case=pouring_03",
                  "method=fabrics", "without_obstacles=false",
                  "hydra/launcher=submitit_local", "hydra.callbacks.table1.build_models=false")
    _check(proc, tmp_path, 1, tmp_path)
    assert "Submitit 'local'" in proc.stdout + proc.stderr
