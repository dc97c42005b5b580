"""The in-episode step benchmark's statistics and scenario lists
(:mod:`tamedpuma.app.bench_steps`); one short episode checks that its figures are the summary's."""

import numpy as np
import pytest

from tamedpuma.analysis.summaries import step_stats
from tamedpuma.app import bench_steps


def test_step_statistics_count_the_steps_over_the_period_and_the_bound():
    ms = np.r_[np.full(997, 1.0), 12.0, 25.0, 400.0]
    s = step_stats([ms])
    assert s["steps"] == 1000 and s["median_ms"] == 1.0 and s["max_ms"] == 400.0
    assert s["over_period"] == 2 and s["over_bound"] == 3
    assert s["p99_ms"] == pytest.approx(1.0) and 25.0 < s["p99_9_ms"] < 400.0
    assert step_stats([]) == step_stats([[]]) == {"steps": 0}


def test_the_pooled_figures_hold_every_step_of_every_run():
    runs = [{"method": "fpm", "ms": [1.0, 2.0, 30.0], "cpu_ms": [0.9, 1.9, 4.0],
             "over_period": 1, "over_bound": 1, "success": True, "summary_mismatch": 0.0},
            {"method": "fpm", "ms": [1.0, 1.0], "cpu_ms": [0.9, 11.0], "over_period": 0,
             "over_bound": 0, "success": False, "summary_mismatch": 1e-6}]
    out = bench_steps.pooled(runs)["fpm"]
    assert out["runs"] == 2 and out["steps"] == 5 and out["max_ms"] == 30.0
    assert out["runs_over_period"] == 1 and out["successes"] == 1
    assert out["summary_mismatch"] == 1e-6
    assert out["cpu"]["steps"] == 5 and out["cpu"]["max_ms"] == 11.0
    assert out["cpu"]["over_bound"] == 1 and out["cpu"]["median_ms"] == 1.9
    assert tuple(out["cpu"]) == bench_steps.REPORT_KEYS  # the report keeps its keys


def test_a_mismatch_with_the_summary_is_reported():
    stats = step_stats([[1.0, 2.0, 3.0]])
    same = {"compute_ms_median": 2.0, "compute_ms_p99": stats["p99_ms"], "compute_ms_max": 3.0}
    assert bench_steps.summary_mismatch(same, stats) == 0.0
    assert bench_steps.summary_mismatch({**same, "compute_ms_max": 6.0}, stats) == 0.5
    assert bench_steps.summary_mismatch({}, stats) == np.inf


def test_the_cases_are_the_experiments_own():
    table1 = bench_steps.table1_cases(2)
    assert [c for c, _ in table1] == ["table1/tomato_00", "table1/tomato_01",
                                      "table1/pouring_00", "table1/pouring_01"]
    assert "+experiment=table1" in table1[0][1] and "without_obstacles=false" in table1[0][1]
    rand = bench_steps.random_cases([2000])
    assert len(rand) == 4 and "scenario.random_seed=2000" in rand[0][1]


@pytest.mark.slow
def test_an_episode_s_step_figures_are_its_summary_s():
    row = bench_steps.run_case("fabrics", ["+experiment=table1", "case=tomato_00",
                                           "without_obstacles=false"])
    assert row["steps"] == len(row["ms"]) > 10
    assert row["summary_mismatch"] < 1e-3
    assert row["cpu"]["steps"] == row["steps"] and len(row["cpu_ms"]) == row["steps"]
    # the thread's CPU time is part of the step's wall time (to the clocks' accounting, which
    # charges the thread a few microseconds of the clock reads themselves)
    assert all(c <= w + 0.05 for c, w in zip(row["cpu_ms"], row["ms"]))


def test_without_the_reference_the_report_says_its_figure_is_cited(monkeypatch):
    note = bench_steps.reference_note(False, None)
    assert note.startswith("not timed in this run") and "TAMEDPUMA_REFERENCE_PYTHON" in note
    assert "cited" in note and bench_steps.reference_note(True, None) == "timed live in this run"
    report = {"cases": ["table1/tomato_00"], "date": "d", "period_ms": 20.0, "bound_ms": 10.0,
              "reference": {"reference_median_ms": 0.25, "reference_note": note,
                            "fabric_median_ms": 0.1},
              "methods": {"fpm": {"runs": 1, **step_stats([[0.5, 0.5, 25.0]]),
                                  "cpu": step_stats([[0.4, 0.4, 3.0]]),
                                  "ratio_to_reference": 2.0, "runs_over_period": 1,
                                  "summary_mismatch": 0.0}},
              "machine": {"cpu_model": "c", "load_average_1min": 1.0}}
    section = bench_steps.markdown_section(report)
    assert section.startswith("## Controller step in episodes") and note in section
    assert "| fpm | 1 | 3 | 0.500 | 2.00 | — |" in section and "| 25.00 | 1 | 1 | 1 |" in section
    assert "| fpm | 0.400 |" in section and "| 3.00 | 0 |" in section
    assert "driving the robot in PyBullet not timed (not measured)" in section


def test_the_ratio_to_the_reference_in_its_episode_is_reported_beside_the_other():
    episode = {"steps": 600, "median_ms": 0.4, "p99_ms": 0.6, "max_ms": 0.9,
               "ee_distance_start_m": 0.7, "ee_distance_end_m": 0.001, "finite": True}
    report = {"cases": ["table1/tomato_00"], "date": "d", "period_ms": 20.0, "bound_ms": 10.0,
              "reference": {"reference_median_ms": 0.25, "reference_note": "timed live",
                            "reference_episode_median_ms": 0.4, "reference_episode": episode,
                            "fabric_median_ms": 0.1},
              "methods": {"fpm": {"runs": 1, **step_stats([[0.5, 0.5, 0.6]]),
                                  "ratio_to_reference": 2.0, "ratio_to_reference_episode": 1.25,
                                  "runs_over_period": 0, "summary_mismatch": 0.0}},
              "machine": {"cpu_model": "c", "load_average_1min": 1.0}}
    section = bench_steps.markdown_section(report)
    assert "| fpm | 1 | 3 | 0.500 | 2.00 | 1.25 |" in section
    assert "episode of 600 periods" in section and "0.400 ms median, max 0.90 ms" in section
