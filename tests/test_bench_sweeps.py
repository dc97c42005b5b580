"""The bench's sweep figures (Table 1, the randomized suite) are read from the summaries the runs
wrote and judged against the speed targets and the step bound: synthetic summaries, no sweep."""

import json
from pathlib import Path

import pytest

from tamedpuma.app import bench, bench_sweeps


def _summary(path, method, steps, ms, build, episode, simulator=0.0, longest=None, p99=None,
             cpu=None):
    path.mkdir(parents=True)
    (path / "summary.json").write_text(json.dumps(
        {"method": method, "method_label": method, "steps": steps,
         "step_compute_ms": [ms] * steps, "compute_ms_max": ms if longest is None else longest,
         "compute_ms_p99": ms if p99 is None else p99,
         "compute_cpu_ms_max": ms if cpu is None else cpu,
         "wall_s": {"build": build, "episode": episode, "simulator": simulator}}))


def test_the_profile_sums_the_runs_per_method_and_keeps_the_longest_step(tmp_path):
    _summary(tmp_path / "tomato" / "a", "fpm", 1000, 0.5, 0.2, 1.5, 0.5, longest=4.0, cpu=1.0)
    _summary(tmp_path / "pouring" / "b", "fpm", 500, 0.5, 0.3, 1.0, 0.25, longest=12.0, p99=0.9)
    _summary(tmp_path / "tomato" / "c", "modulation_ik", 100, 2.0, 0.5, 0.6)
    (tmp_path / "tomato" / "d").mkdir()
    (tmp_path / "tomato" / "d" / "summary.json").write_text("{truncated")  # skipped
    prof = bench_sweeps.sweep_profile(tmp_path)
    fpm = prof["methods"]["fpm"]
    assert fpm["runs"] == 2 and fpm["steps"] == 1500
    assert abs(fpm["controller_s"] - 0.75) < 1e-9 and abs(fpm["episode_s"] - 2.5) < 1e-9
    assert abs(fpm["simulator_s"] - 0.75) < 1e-9
    assert fpm["max_step_ms"] == 12.0 and fpm["max_step_cpu_ms"] == 1.0
    assert fpm["max_p99_ms"] == 0.9 and fpm["runs_over_bound"] == 1
    assert prof["total"]["runs"] == 3 and abs(prof["total"]["build_s"] - 1.0) < 1e-9


def _item(tmp_path, walls, name="table1"):
    _summary(tmp_path / "a", "fpm", 1000, 0.5, 0.2, 1.5, 0.5)
    _summary(tmp_path / "b", "fpm", 500, 0.5, 0.3, 1.0, 0.25)
    _summary(tmp_path / "c", "modulation_ik", 100, 2.0, 0.5, 0.6)
    prof = bench_sweeps.sweep_profile(tmp_path)
    return {"name": name, "wall_s": sorted(walls)[len(walls) // 2], "walls_s": walls,
            "returncode": 0, "cores": 2, "profile": prof, "tables_wall_s": 1.0,
            "bounds": bench_sweeps.merged_bounds([prof])}


def test_the_sweep_is_judged_per_run_on_the_median_wall_time(tmp_path):
    item = _item(tmp_path, [10.0, 9.0, 30.0])
    line = bench_sweeps.verdict_line(item)
    # 10 s for 3 runs is 1400 s per 420
    assert "**not met**" in line and "1400 s per 420" in line and "median of 3: 10, 9, 30 s" in line
    assert "20 core-s" in line and "simulator's steps (PyBullet's physics" in line
    # cores × wall = episodes + set-up + the rest: 20 = 3.1 + 1.0 + 15.9
    assert "the other 16 s" in line
    item["wall_s"] = 1.5  # 210 s per 420 runs
    assert "**met**" in bench_sweeps.verdict_line(item)
    item["returncode"] = 1
    assert "**not met**" in bench_sweeps.verdict_line(item)
    suite = dict(item, name="suite", returncode=0, wall_s=2.0)  # 2 s per 3 runs: 2667 s per 4000
    assert "**met**" in bench_sweeps.verdict_line(suite)
    assert "2667 s per 4000" in bench_sweeps.verdict_line(suite)
    table = bench_sweeps.method_table(item)
    assert [ln.split("|")[1].strip() for ln in table if ln.startswith("| ")
            and "method" not in ln] == ["fpm", "modulation_ik"]


def _bounds(**methods):
    return {"name": "table1", "walls_s": [1.0], "bounds": {
        m: {"runs": 2, "runs_over_bound": int(longest > 10), "max_step_ms": longest,
            "max_step_cpu_ms": longest / 2, "max_p99_ms": p99}
        for m, (longest, p99) in methods.items()}}


def test_the_step_bound_holds_every_bounded_method_to_its_longest_step():
    fine = dict(puma=(3.0, 0.3), fabrics=(2.0, 0.2), fpm=(5.0, 0.9), cpm=(6.0, 1.1))
    assert "**met**" in bench_sweeps.bound_line([_bounds(**fine)])
    # Modulation-IK is reported, not bounded
    line = bench_sweeps.bound_line([_bounds(**fine, modulation_ik=(40.0, 3.0))])
    assert "**met**" in line and "Not bounded (reported): modulation_ik 40.0 ms" in line
    slow = bench_sweeps.bound_line([_bounds(**fine), _bounds(**dict(fine, fpm=(12.0, 0.9)))])
    assert "**not met**" in slow and "fpm 1 of 4" in slow and "fpm 12.0 ms (CPU 6.0)" in slow
    assert "**not met**" in bench_sweeps.bound_line([_bounds(**dict(fine, cpm=(6.0, 2.5)))])
    # a bounded method that no sweep ran is not a pass
    assert "**not met**" in bench_sweeps.bound_line([_bounds(fpm=(5.0, 0.9), cpm=(6.0, 1.1))])
    assert bench_sweeps.bound_line([None, {}]) is None


def test_a_sweep_is_run_as_often_as_asked_each_into_its_own_folder(monkeypatch):
    folders, walls = [], iter([30.0, 10.0, 20.0])

    rechecked = []

    def fake(argv, timeout=None):
        if argv[1] == "analysis.tables":
            return {"wall_s": 0.5, "returncode": 0}
        if argv[1] == "tamedpuma.recheck":  # the slow step re-run: fast this time
            rechecked.append(argv[2])
            Path(argv[argv.index("--json") + 1]).write_text(json.dumps([
                {"run_dir": f"{argv[2]}/run3", "method": "fpm", "step": 4, "wall_ms": 12.0,
                 "cpu_ms": 11.0, "least_wall_ms": 0.3, "least_cpu_ms": 0.3,
                 "reproduced": False}]))
            return {"wall_s": 1.0, "returncode": 0}
        root = Path(argv[-1].removeprefix("output_root=")) / "table1"
        folders.append(root)
        _summary(root / f"run{len(folders)}", "fpm", 10, 0.2, 0.1, 0.3, 0.1,
                 longest=4.0 * len(folders))  # the third run: a 12 ms step
        return {"command": "python " + " ".join(argv), "wall_s": next(walls), "returncode": 0}

    monkeypatch.setattr(bench_sweeps, "timed_command", fake)
    monkeypatch.setattr(bench_sweeps, "job_overheads", lambda: {"compose_s": 0.1})
    item = bench_sweeps.time_sweep("table1", cores=2, repeats=3)
    assert len(set(folders)) == 3 and item["walls_s"] == [30.0, 10.0, 20.0]
    assert item["wall_s"] == 20.0 and item["returncode"] == 0
    assert item["profile"] is item["profiles"][2]  # the median repeat's
    assert item["bounds"]["fpm"]["max_step_ms"] == 12.0 and item["bounds"]["fpm"]["runs"] == 3
    assert "+experiment=table1" in item["command"]
    # only the repeat with a step over the bound is re-run, in its own folder
    assert rechecked == [str(folders[2])] and item["rechecks"][0]["run"] == "run3"
    line = bench_sweeps.bound_line([item])
    assert "**not met**" in line and "fpm 1 of 3" in line
    assert "0 of 1 such steps were slow again" in line
    assert "at most 0.30 ms there, so the time was the machine's" in line


@pytest.mark.parametrize("argv, message", [
    (["--sweeps"], "error: --sweeps needs --table1 N or --suite N"),
    (["--sweeps", "--table1", "1"], "error: --sweeps merges into the saved report"),
    (["--table1", "-1"], "error: --table1 and --suite take a number of repeats"),
])
def test_the_sweeps_options_refuse_what_they_cannot_do(tmp_path, capsys, argv, message):
    assert bench.main([*argv, "--root", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith(message)


def test_the_sweeps_alone_are_merged_into_the_saved_report(tmp_path, monkeypatch,
                                                          saved_bench_reports):
    saved = saved_bench_reports
    (tmp_path / "BENCHMARKS.md").write_text("# Benchmarks\n")
    timed = []

    def fake(name, cores, repeats):
        timed.append((name, repeats))
        item = _item(tmp_path / name, [200.0] * repeats, name)
        return dict(item, walls_s=[200.0] * repeats, wall_s=200.0)

    monkeypatch.setattr(bench_sweeps, "time_sweep", fake)
    assert bench.main(["--sweeps", "--table1", "3", "--root", str(tmp_path)]) == 0
    assert timed == [("table1", 3)]
    report = json.loads((tmp_path / "benchmarks" / "bench.json").read_text())
    assert report["controller"] == saved["controller"]  # the other sections kept
    assert report["table1"]["walls_s"] == [200.0] * 3 and "suite" not in report
    assert "--sweeps --table1 3" in report["table1"]["measured_by"]
    text = (tmp_path / "BENCHMARKS.md").read_text()
    assert "`+experiment=table1` ≤ 4 minutes per 420 runs on 2 cores: **not met**" in text
    assert "median of 3: 200, 200, 200 s" in text and "| fpm | 2 | 1500 |" in text
