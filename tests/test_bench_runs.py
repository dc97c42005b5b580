"""The bench's whole-command figures (training, Table 1) are read from what the commands wrote,
and judged against the speed targets: synthetic reports and summaries, no training or sweep."""

import json
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


def _summary(path, method, steps, ms, build, episode, simulator=0.0):
    path.mkdir(parents=True)
    (path / "summary.json").write_text(json.dumps(
        {"method": method, "method_label": method, "steps": steps,
         "step_compute_ms": [ms] * steps,
         "wall_s": {"build": build, "episode": episode, "simulator": simulator}}))


def test_the_table1_profile_sums_the_runs_per_method(tmp_path):
    _summary(tmp_path / "tomato" / "a", "fpm", 1000, 0.5, 0.2, 1.5, 0.5)
    _summary(tmp_path / "pouring" / "b", "fpm", 500, 0.5, 0.3, 1.0, 0.25)
    _summary(tmp_path / "tomato" / "c", "modulation_ik", 100, 2.0, 0.5, 0.6)
    (tmp_path / "tomato" / "d").mkdir()
    (tmp_path / "tomato" / "d" / "summary.json").write_text("{truncated")  # skipped
    prof = bench_runs.table1_profile(tmp_path)
    fpm = prof["methods"]["fpm"]
    assert fpm["runs"] == 2 and fpm["steps"] == 1500
    assert abs(fpm["controller_s"] - 0.75) < 1e-9 and abs(fpm["episode_s"] - 2.5) < 1e-9
    assert abs(fpm["simulator_s"] - 0.75) < 1e-9
    assert prof["total"]["runs"] == 3 and abs(prof["total"]["build_s"] - 1.0) < 1e-9
    item = {"wall_s": 10.0, "returncode": 0, "cores": 2, "profile": prof, "tables_wall_s": 1.0}
    lines = bench_runs.table1_lines(item)
    # judged per run: 10 s for 3 runs is 1400 s per 420
    assert "**not met**" in lines[1] and "1400 s per 420" in lines[1]
    assert "20 core-s" in lines[1] and "simulator's steps (PyBullet's physics" in lines[1]
    # cores × wall = episodes + set-up + the rest: 20 = 3.1 + 1.0 + 15.9
    assert "the other 16 s" in lines[1]
    assert [ln.split("|")[1].strip() for ln in lines if ln.startswith("| ")
            and "method" not in ln] == ["fpm", "modulation_ik"]
    item["wall_s"] = 1.5  # 210 s per 420 runs
    assert "**met**" in bench_runs.table1_lines(item)[1]


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
