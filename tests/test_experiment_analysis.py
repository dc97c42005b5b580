"""The analyses of the scaling, disturbance and randomized experiments on synthetic run summaries:
pooled step-time statistics, bootstrap intervals, tables and the figure."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tamedpuma.analysis import disturbance, scaling
from tamedpuma.analysis.summaries import bootstrap_ci, load_summaries, step_stats
from tamedpuma.metrics import run_metrics

REPO = Path(__file__).resolve().parents[1]


def _summary(folder: Path, method: str, n_obstacles: int, step_ms: float, success: bool,
             disturbance_name: str = "none", onset: float | None = None):
    n = 300
    t = np.arange(n) * 0.02
    pos = np.where(np.arange(n) >= 200, 0.01, 0.5) if success else np.full(n, 0.5)
    m = run_metrics(t=t, position_error=pos, orientation_error=np.zeros(n),
                    clearance=np.full(n, 0.1), obstacle_contact=np.zeros(n, bool),
                    ground_contact=np.zeros(n, bool), q=np.zeros((n, 7)), q_min=-np.ones(7),
                    q_max=np.ones(7), compute_ms=np.full(n, step_ms), tolerance=0.05,
                    disturbance_time=onset,
                    ee_position=np.zeros((n, 3)))
    folder.mkdir(parents=True)
    steps = [10 * step_ms] + [step_ms] * (n - 1)  # a slow first (warm-up) step
    (folder / "summary.json").write_text(json.dumps({
        "method": method, "method_label": method, "task": "tomato", "scenario": "s",
        "n_obstacles": n_obstacles, "disturbance": disturbance_name, **m.as_dict(),
        "step_compute_ms": steps}))


def test_bootstrap_interval_contains_the_rate_and_narrows_with_more_scenarios():
    assert bootstrap_ci(np.ones(50)) == (1.0, 1.0)
    small = bootstrap_ci(np.r_[np.ones(10), np.zeros(10)])
    large = bootstrap_ci(np.r_[np.ones(200), np.zeros(200)])
    assert small[0] < 0.5 < small[1] and large[0] < 0.5 < large[1]
    assert large[1] - large[0] < 0.5 * (small[1] - small[0])
    # the normal approximation of a binomial proportion: ±1.96 sqrt(p(1-p)/n)
    assert large[1] - large[0] == pytest.approx(2 * 1.96 * np.sqrt(0.25 / 400), rel=0.1)


def test_step_stats_count_every_step_of_every_run():
    st = step_stats([np.array([9.0, 1.0, 1.0]), np.array([5.0, 3.0])])
    assert st["steps"] == 5 and st["median_ms"] == 3.0 and st["first_mean_ms"] == 7.0
    assert st["mean_ms"] == pytest.approx(19 / 5)


def test_scaling_table_and_figure_from_summaries(tmp_path):
    runs = tmp_path / "runs"
    for count, ms in ((2, 0.5), (1000, 2.0)):
        for k, ok in enumerate((True, False)):
            _summary(runs / f"{count}" / f"fpm_{k}", "fpm", count, ms, ok)
        _summary(runs / f"{count}" / "puma_0", "puma", count, 0.3, True)
    frame, times = load_summaries(runs)
    table = scaling.scaling_table(frame, times).set_index(["method", "obstacles"])
    assert table.loc[("fpm", 1000), "median_ms"] == pytest.approx(2.0)
    assert table.loc[("fpm", 1000), "p99_ms"] == pytest.approx(2.0)  # 2 warm-up steps of 600
    assert table.loc[("fpm", 1000), "first_step_ms"] == pytest.approx(20.0)
    assert table.loc[("fpm", 2), "success_paper"] == 0.5 and table.loc[("fpm", 2), "runs"] == 2
    assert scaling.main([str(runs), "--out", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "scaling.png").stat().st_size > 10_000
    text = (tmp_path / "out" / "scaling.md").read_text()
    assert "| puma |" in text.splitlines()[2] and "1000 obstacles" in text
    assert "| fpm | 1/2, 4.0 s, converged 1; stall 1 | 1/2, 4.0 s, converged 1; stall 1 |" in text
    assert table.loc[("fpm", 2), "failures"] == "stall 1"
    assert table.loc[("puma", 2), "time_to_success_s"] == pytest.approx(4.0)


def test_timing_only_runs_count_in_the_times_and_not_in_the_success(tmp_path):
    """Runs cut short by scenario.max_steps (Modulation-IK at 1000 obstacles): --timing-only."""
    runs, cut = tmp_path / "runs", tmp_path / "cut"
    _summary(runs / "2" / "mik_0", "modulation_ik", 2, 1.0, True)
    _summary(cut / "1000" / "mik_0", "modulation_ik", 1000, 300.0, False)
    out = tmp_path / "out"
    assert scaling.main([str(runs), "--timing-only", str(cut), "--out", str(out)]) == 0
    table = pd.read_csv(out / "scaling.csv").set_index(["method", "obstacles"])
    row = table.loc[("modulation_ik", 1000)]
    assert row["runs"] == 0 and row["timed_runs"] == 1 and np.isnan(row["success_paper"])
    assert row["median_ms"] == pytest.approx(300.0)
    assert table.loc[("modulation_ik", 2), "success_whole_body"] == 1.0
    text = (out / "scaling.md").read_text()
    assert "300.00 / 300.00 ms (timing only: 1 × 300 steps)" in text
    assert "not measured (timing only)" in text


def test_disturbance_table_reports_recovery_from_the_onset(tmp_path):
    runs = tmp_path / "runs"
    _summary(runs / "push" / "fpm", "fpm", 2, 1.0, True, "push", onset=1.0)
    _summary(runs / "push" / "puma", "puma", 2, 1.0, False, "push", onset=1.0)
    frame, _ = load_summaries(runs)
    table = disturbance.disturbance_table(frame).set_index("method")
    assert table.loc["fpm", "recovery [s]"] == "3.00 (1 run)"  # reached at 4 s, pushed at 1 s
    assert table.loc["puma", "success (whole body)"] == "0.00"
    assert table.loc["puma", "whole-body failures"] == "stall 1"


@pytest.mark.parametrize("module", ["analysis.scaling", "analysis.disturbance",
                                    "analysis.random_suite"])
def test_an_empty_folder_is_a_one_line_error(tmp_path, module):
    proc = subprocess.run([sys.executable, "-m", module, str(tmp_path)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.startswith("error: ")
    assert proc.stderr.count("\n") == 1


def test_summaries_without_step_times_are_skipped(tmp_path):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "summary.json").write_text(json.dumps({"method": "fpm"}))
    frame, _ = load_summaries(tmp_path)
    assert frame.empty and len(frame.attrs["skipped"]) == 1
    assert isinstance(frame, pd.DataFrame)


def test_random_suite_splits_the_rates_by_kind_of_start():
    from tamedpuma.analysis.random_suite import by_start_table, start_kind

    assert start_kind("random_tomato_near_table1_2004") == "near_table1"
    assert start_kind("random_pouring_anywhere_17") == "anywhere"
    assert start_kind("random_panda_reach_near_table1_3") == "near_table1"
    assert start_kind("tomato_03") == start_kind("random_tomato_sideways_3") == "other"
    rows = []
    for seed in range(10):  # near_table1: 10 of 10 succeed; anywhere: 4 of 10
        for kind, ok in (("near_table1", True), ("anywhere", seed < 4)):
            for n_obstacles in (2, 0):  # the obstacle-free twins are not scored
                rows.append({"task": "tomato", "method_label": "fpm", "n_obstacles": n_obstacles,
                             "scenario": f"random_tomato_{kind}_{seed}",
                             "success_paper": ok or n_obstacles == 0,
                             "success_whole_body": ok and seed != 0,
                             "orientation_success_paper": ok and seed % 2 == 0})
    table = by_start_table(pd.DataFrame(rows)).set_index("start")
    assert list(table.index) == ["near_table1", "anywhere"]
    assert (table["scenarios"] == 10).all()
    near, anywhere = table.loc["near_table1"], table.loc["anywhere"]
    assert near["success (paper) [95% CI]"] == "1.00 [0.72, 1.00]"  # Wilson: 10 of 10
    assert anywhere["success (paper) [95% CI]"].startswith("0.40 [")
    assert anywhere["success (whole body) [95% CI]"].startswith("0.30 [")
    assert near["with orientation (paper) [95% CI]"].startswith("0.50 [")


def test_random_suite_pools_every_step_of_the_runs_with_obstacles_per_method():
    from tamedpuma.analysis.random_suite import step_table

    runs = pd.DataFrame([
        {"path": "a", "method_label": "fpm", "n_obstacles": 2},
        {"path": "b", "method_label": "fpm", "n_obstacles": 1},
        {"path": "c", "method_label": "fpm", "n_obstacles": 0},  # obstacle-free twin: not pooled
        {"path": "d", "method_label": "cpm", "n_obstacles": 2}])
    times = {"a": np.full(999, 0.5), "b": np.array([0.5, 12.0, 25.0]),
             "c": np.array([90.0]), "d": np.array([1.0, 2.0, 3.0])}
    table = step_table(runs, times).set_index("method")
    assert list(table.index) == ["fpm", "cpm"]
    fpm = table.loc["fpm"]
    assert fpm["runs"] == 2 and fpm["steps"] == 1002 and fpm["max"] == 25.0
    assert fpm["median [ms]"] == 0.5
    assert fpm["steps > 10 ms"] == 2 and fpm["steps > 20 ms (the period)"] == 1
    assert fpm["runs with a step over the period"] == 1
    assert table.loc["cpm", "median [ms]"] == 2.0 and table.loc["cpm", "steps > 10 ms"] == 0
