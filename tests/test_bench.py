"""The benchmark command's plumbing (not its timings): cells, episodes, the Markdown section."""

from __future__ import annotations

import json

import pytest

from tamedpuma.app import bench


def test_controller_cells_are_ordered_statistics():
    rows = bench.time_controller("fabrics", counts=(0, 4), calls=20, budget_s=1.0)
    assert [(r["method"], r["n_obstacles"]) for r in rows] == [("fabrics", 0), ("fabrics", 4)]
    for r in rows:
        assert 0 < r["p10_ms"] <= r["median_ms"] <= r["p90_ms"]
        assert 5 <= r["n_calls"] <= 20


def test_budget_stops_a_cell_early():
    rows = bench.time_controller("fabrics", counts=(2,), calls=100000, budget_s=0.05)
    assert 5 <= rows[0]["n_calls"] < 100000


def test_episode_rows_and_overheads_are_relative_to_none():
    rows = bench.time_episodes("fabrics", repeats=1, overrides=["scenario.max_steps=20"])
    by = {r["recorder"]: r for r in rows}
    assert set(by) == set(bench.RECORDERS)
    assert by["none"]["overhead_vs_none"] == 0.0
    for r in rows:
        assert r["steps"] <= 20 and r["realtime_factor"] > 0
        assert r["overhead_vs_none"] == pytest.approx(r["wall_s"] / by["none"]["wall_s"] - 1,
                                                      abs=1e-3)


def test_command_writes_json_and_keeps_other_sections(tmp_path):
    (tmp_path / "BENCHMARKS.md").write_text("# Benchmarks\n\n## Fabrics\nkeep\n\n## Controller "
                                            "step\nold figures\n\n## Z\nz\n")
    code = bench.main(["--methods", "fabrics", "nope", "--counts", "2", "--calls", "10",
                       "--budget", "0.5", "--episodes", "0", "--root", str(tmp_path)])
    assert code == 0
    report = json.loads((tmp_path / "benchmarks" / "bench.json").read_text())
    assert [r["n_obstacles"] for r in report["controller"]] == [2]
    assert report["errors"][0]["method"] == "nope"
    text = (tmp_path / "BENCHMARKS.md").read_text()
    assert "keep" in text and "## Z\nz" in text and "old figures" not in text
    assert text.count("## Controller step") == 1 and "| fabrics | 2 |" in text


def test_bad_arguments_exit_2(capsys):
    assert bench.main(["--counts", "-1", "--no-write"]) == 2
    assert capsys.readouterr().err.startswith("error:")
