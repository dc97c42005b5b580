"""The bench's training figures are read from what the command wrote, and judged against the
speed targets: synthetic reports, no training."""

import sys

from tamedpuma.app import bench_runs


def _report(conv=1.0, dtw=0.008, comp=0.997, iterations=1200, worst=0.02):
    return {"iterations": 2400, "iterations_run": iterations, "pipeline_seconds": 120.0,
            "pipeline_cpu_seconds": 118.0,
            "evaluation": {"convergence": {"converged_fraction": conv, "starts": 1000,
                                           "final_pos_error_max": 0.001},
                           "imitation": {"dtw": dtw, "dtw_max": worst},
                           "compatibility": {"compatible_fraction": comp, "samples": 2000}}}


def _row(task="tomato", seed=0, wall=70.0, code=0, **kw):
    return {"task": task, "seed": seed, "wall_s": wall, "returncode": code,
            **bench_runs.training_figures(_report(**kw))}


def test_training_figures_are_read_from_the_report():
    row = bench_runs.training_figures(_report(conv=0.999, dtw=0.021))
    assert row["converged_fraction"] == 0.999 and row["dtw_m"] == 0.021
    assert row["starts"] == 1000 and row["iterations"] == 1200 and row["iterations_max"] == 2400
    assert bench_runs.training_figures({})["dtw_m"] is None  # a report without evaluation


def test_each_training_target_is_judged():
    assert bench_runs.training_verdict(_row()) == []
    assert bench_runs.training_verdict(_row(conv=0.999))[0].startswith("converged 99.9%")
    assert bench_runs.training_verdict(_row(dtw=0.0101)) == ["DTW 1.01 cm"]
    assert bench_runs.training_verdict(_row(worst=0.031)) == ["worst demonstration 3.10 cm"]
    assert bench_runs.training_verdict(_row(comp=0.994)) == ["ψ-compatible 99.4%"]
    assert bench_runs.training_verdict(_row(wall=91.0)) == ["91 s wall"]
    failed = {"task": "tomato", "seed": 0, "wall_s": 3.0, "returncode": 2, "error": "bad"}
    assert bench_runs.training_verdict(failed) == ["the command failed (bad)"]


def test_the_training_line_names_every_miss_and_the_table_every_run():
    rows = [_row(), _row(seed=1), _row("pouring", 0, wall=85.0),
            _row("pouring", 1, wall=200.0, conv=0.998)]
    line = bench_runs.training_target_line(rows)
    assert "**not met**" in line and "pouring seed 1: converged 99.8%" in line
    assert "200 s wall" in line and "tomato seeds 0/1" in line
    assert "**met**" in bench_runs.training_target_line(rows[:3])
    table = bench_runs.training_lines(rows)
    assert sum(ln.startswith("| tomato") or ln.startswith("| pouring") for ln in table) == 4


def test_a_failing_command_reports_its_last_error_line():
    item = bench_runs.timed_command(["-c", "import sys; sys.exit('no such task: x')"])
    assert item["returncode"] == 1 and item["error"] == "no such task: x"
    assert item["command"].startswith("python -c") and sys.executable


def test_the_training_table_gives_the_cost_of_an_iteration():
    row = _row("pouring", 2, wall=250.0)  # 118 s CPU over 1200 iterations
    (line,) = [ln for ln in bench_runs.training_lines([row]) if ln.startswith("| pouring")]
    assert "| 1200 (of 2400) | 98 |" in line and "missed: 250 s wall" in line
    assert "1200 × 98" in bench_runs.training_target_line([row])


def test_training_uses_the_authors_demonstrations_where_they_are(monkeypatch, tmp_path):
    from tamedpuma.puma import download

    monkeypatch.setattr(download, "find_root", lambda folders=(): None)
    assert bench_runs.demos_override("pouring") == []  # synthetic, said in the row
    monkeypatch.setattr(download, "find_root", lambda folders=(): tmp_path)
    assert bench_runs.demos_override("pouring") == [f"task.demos={tmp_path / 'pouring_v2'}"]
    rows = [{**_row("pouring"), "demos": "/data/pouring_v2"}]
    assert "pouring: /data/pouring_v2" in bench_runs.training_lines(rows)[1]
