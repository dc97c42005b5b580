"""The benchmark command's plumbing (not its timings): cells, episodes, the Markdown section."""

from __future__ import annotations

import json

import pytest

from tamedpuma.app import (
    bench,
    bench_baseline,
    bench_parts,
    bench_report,
    bench_timing,
    bench_worker,
    bench_workers,
)
from tamedpuma.app.bench_fabrics import ROOT


def test_controller_cells_are_ordered_statistics():
    rows = bench_timing.time_controller("fabrics", counts=(0, 4), calls=20, budget_s=1.0)
    assert [(r["method"], r["n_obstacles"]) for r in rows] == [("fabrics", 0), ("fabrics", 4)]
    for r in rows:
        assert 0 < r["p10_ms"] <= r["median_ms"] <= r["p90_ms"]
        assert 5 <= r["n_calls"] <= 20


def test_budget_stops_a_cell_early():
    rows = bench_timing.time_controller("fabrics", counts=(2,), calls=100000, budget_s=0.05)
    assert 5 <= rows[0]["n_calls"] < 100000


def test_episode_rows_and_overheads_are_relative_to_none():
    rows = bench_workers.time_episodes("fabrics", repeats=2, overrides=["scenario.max_steps=20"],
                               trees={"now": ROOT, "before": ROOT})
    by = {r["recorder"]: r for r in rows}
    assert set(by) == set(bench_workers.RECORDERS)
    assert by["none"]["overhead_vs_none"] == 0.0
    for r in rows:
        assert r["steps"] == r["before_steps"] <= 20 and r["realtime_factor"] > 0
        assert r["repeats"] == 2 and r["wall_p10_s"] <= r["wall_s"] <= r["wall_p90_s"]
        assert 0 < r["wall_s"] < r["run_wall_s"]  # the episode is part of the run
        assert r["overhead_vs_none"] == pytest.approx(r["wall_s"] / by["none"]["wall_s"] - 1,
                                                      abs=1e-3)
        assert r["speedup"] == pytest.approx(r["before_wall_s"] / r["wall_s"], rel=1e-2)
        assert 0 < r["controller_s"] < r["wall_s"]
        if r["recorder"] != "none":  # the recorders' own time, measured inside the episode
            assert 0 < r["recorder_own_share"] and r["recorder_own_s"]
    assert 0 < by["none"]["physics_s"] < by["none"]["wall_s"]
    section = bench_report.markdown_section({
        "date": "d", "controller": [], "episodes": rows,
        "episode_baseline": {"tree": "/tmp/before", "commit": "0" * 40},
        "machine": {"cpu_model": "c", "cores": 2, "python": "3", "numpy": "2"}})
    assert "| mcap+rerun | " in section and "commit `0000000`" in section
    assert "the simulator alone" in section


def test_command_writes_json_and_keeps_other_sections(tmp_path):
    (tmp_path / "BENCHMARKS.md").write_text("# Benchmarks\n\n## Fabrics\nkeep\n\n## Controller "
                                            "step\nold figures\n\n## Z\nz\n")
    (tmp_path / "README.md").write_text("readme\n")
    code = bench.main(["--methods", "fabrics", "nope", "--counts", "2", "--calls", "10",
                       "--budget", "0.5", "--episodes", "0", "--skip-fabrics", "--parts",
                       "--steps-table1", "0", "--steps-seeds", "--root", str(tmp_path)])
    assert code == 0
    report = json.loads((tmp_path / "benchmarks" / "bench.json").read_text())
    assert [r["n_obstacles"] for r in report["controller"]] == [2]
    assert report["errors"][0]["method"] == "nope"
    text = (tmp_path / "BENCHMARKS.md").read_text()
    assert "keep" in text and "## Z\nz" in text and "old figures" not in text
    assert text.count("## Controller step") == 1 and "| fabrics | 2 |" in text
    assert (tmp_path / "README.md").read_text() == "readme\n"  # the bench edits no other file
    assert sorted(p.name for p in tmp_path.rglob("*")) == [
        "BENCHMARKS.md", "README.md", "bench.json", "benchmarks"]


def test_one_command_also_regenerates_the_fabrics_section(tmp_path, monkeypatch):
    """Without --skip-fabrics the "Fabrics" section (ours against the reference planner) is
    rewritten by the same command; with no reference Python its figures are cited as dated."""
    monkeypatch.delenv("TAMEDPUMA_REFERENCE_PYTHON", raising=False)
    (tmp_path / "BENCHMARKS.md").write_text("# Benchmarks\n\n## Fabrics\nold\n\n## Z\nz\n")
    code = bench.main(["--methods", "fabrics", "--counts", "2", "--calls", "20", "--budget",
                       "0.5", "--episodes", "0", "--parts", "--steps-table1", "0",
                       "--steps-seeds", "--root", str(tmp_path)])
    assert code == 0
    text = (tmp_path / "BENCHMARKS.md").read_text()
    fabrics = text.split("## Fabrics")[1].split("## ")[0]
    assert "old" not in fabrics and "python -m tamedpuma.bench" in fabrics
    assert "dated" in fabrics and "## Z\nz" in text
    saved = json.loads((tmp_path / "benchmarks" / "fabrics.json").read_text())
    assert [r["n_obstacles"] for r in saved["results"]] == [2, 10, 100, 1000]
    assert saved["reference_live"] == {}


def test_bad_arguments_exit_2(capsys):
    assert bench.main(["--counts", "-1", "--no-write"]) == 2
    assert capsys.readouterr().err.startswith("error:")


def test_baseline_rows_get_before_figures_and_ratios():
    cell = {"p10_ms": 0.1, "p90_ms": 0.3, "n_calls": 9, "first_call_ms": 1.0}
    rows = [{"method": "fpm", "n_obstacles": 2, "median_ms": 0.2, **cell},
            {"method": "fpm", "n_obstacles": 10, "median_ms": 0.25, **cell}]
    before = [{"method": "fpm", "n_obstacles": 2, "median_ms": 0.5, "p10_ms": 0.4,
               "p90_ms": 0.6, "n_calls": 7}]
    bench_baseline.attach_baseline(rows, before)
    assert rows[0]["speedup"] == pytest.approx(2.5) and rows[0]["before_p90_ms"] == 0.6
    assert "speedup" not in rows[1]
    section = bench_report.markdown_section({"date": "d", "controller": rows, "baseline": {
        "tree": "/tmp/before", "commit": None}, "machine": {
        "cpu_model": "c", "cores": 2, "python": "3", "numpy": "2",
        "load_averages_start": [1.0, 2.0, 3.0]}})
    assert "| fpm | 2 | 0.200 |" in section and "| 0.500 | 0.400 | 0.600 | 2.5× |" in section
    assert "| fpm | 10 | 0.250 |" in section and "1.00 / 2.00 / 3.00" in section
    assert "in `/tmp/before` (`--baseline /tmp/before`)" in section  # not a git checkout


def test_report_is_found_after_other_output():
    text = 'noise\n{"not": 1}\n{\n  "controller": [\n    {\n      "a": 1\n    }\n  ]\n}\n'
    assert bench.report_from_stdout(text) == {"controller": [{"a": 1}]}


def test_a_baseline_checkout_is_timed_by_its_own_code(capsys, monkeypatch):
    """This checkout as its own baseline: both sides timed by their workers, the ratio given."""
    monkeypatch.delenv("TAMEDPUMA_REFERENCE_PYTHON", raising=False)  # our code only: no reference
    code = bench.main(["--methods", "fabrics", "--counts", "2", "--calls", "10", "--budget",
                       "0.3", "--episodes", "0", "--parts", "--steps-table1", "0",
                       "--steps-seeds", "--baseline", str(ROOT), "--no-write"])
    assert code == 0
    report = bench.report_from_stdout(capsys.readouterr().out)
    assert not report["errors"] and report["baseline"]["tree"] == str(ROOT.resolve())
    row = report["controller"][0]
    assert row["before_median_ms"] > 0 and row["speedup"] > 0


@pytest.mark.parametrize("where", ["no-such-folder", "."])
def test_a_baseline_that_is_no_checkout_is_one_line_error(capsys, tmp_path, monkeypatch, where):
    monkeypatch.chdir(tmp_path)  # "." : a folder without the worker module
    assert bench.main(["--methods", "fabrics", "--parts", "--baseline", where,
                       "--no-write"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: --baseline {where}") and err.count("\n") == 1


def test_the_worker_module_refuses_an_unknown_kind(capsys):
    assert bench_worker.main(["nope"]) == 2
    assert "usage: python -m tamedpuma.app.bench_worker" in capsys.readouterr().err


def test_parts_of_a_step_and_the_reference_network():
    rows = bench_parts.time_parts("fpm", 2, calls=3)
    by = {r["part"]: r for r in rows}
    assert {"step", "kinematics", "avoidance fabric", "its solve and energization",
            "network: acceleration"} <= set(by)
    assert all(r["us"] > 0 for r in rows)
    assert by["network: acceleration"]["reference_us"] > 0 and "reference_us" not in by[
        "kinematics"]
    section = bench_report.markdown_section({"date": "d", "controller": [], "parts": rows,
                                             "machine": {"cpu_model": "c", "cores": 2,
                                                         "python": "3", "numpy": "2"}})
    assert "| fpm | 2 | network: acceleration |" in section


def test_targets_are_met_or_explained_by_the_profile():
    """Each speed target in the report: "met", or its figure and the largest parts of
    that step at that obstacle count; the episode's real-time target with its physics bound."""
    controller = [
        {"method": "fpm", "n_obstacles": 2, "median_ms": 0.19, "p10_ms": 0.18, "speedup": 1.3},
        {"method": "fpm", "n_obstacles": 1000, "median_ms": 0.8, "p10_ms": 0.7}]
    parts = [{"method": "fpm", "n_obstacles": 1000, "part": p, "us": us}
             for p, us in (("step", 850.0), ("avoidance fabric", 340.0), ("kinematics", 18.0))]
    episodes = [{"recorder": "none", "overhead_vs_none": 0.0, "realtime_factor": 25.0,
                 "physics_s": 0.25, "controller_s": 0.2, "sim_s": 15.0, "steps": 750},
                {"recorder": "mcap", "overhead_vs_none": 0.08}]
    lines = "\n".join(bench_report.target_lines({"controller": controller, "parts": parts,
                                          "episodes": episodes}))
    assert "fpm, 2 obstacles, median ≤ 0.2 ms: **met** (0.190 ms, 1.3× faster" in lines
    assert "fpm, 1000 obstacles, median ≤ 0.6 ms: **not met**: 0.800 ms" in lines
    assert "avoidance fabric 340 µs, kinematics 18 µs" in lines
    assert "recorder mcap adds ≤ 10% to the episode: **met** (+8.0%)" in lines
    assert "**not met** (25.0× with recorder=none)" in lines and "60× real time at most" in lines


def test_side_by_side_workers_time_blocks_and_report_failures():
    rows = bench_workers.time_side_by_side("fabrics", (0, 3), calls=12, budget_s=1.0,
                                   trees={"a": ROOT, "b": ROOT}, block=5)
    for side in ("a", "b"):
        assert [r["n_obstacles"] for r in rows[side]] == [0, 3]
        assert all(r["n_calls"] == 12 and 0 < r["p10_ms"] <= r["p90_ms"] for r in rows[side])
    with pytest.raises(RuntimeError):
        bench_workers.time_side_by_side("no_such_method", (2,), calls=5, budget_s=0.5,
                                trees={"a": ROOT})


def test_method_variants_add_their_overrides(monkeypatch):
    from tamedpuma.fabrics import compiled

    assert bench_timing.method_overrides("fpm") == ("fpm", [])
    with pytest.raises(ValueError, match="unknown variant"):
        bench_timing.method_overrides("fpm+fortran")
    assert bench_timing.method_overrides("fabrics+numpy") == ("fabrics",
                                                       ["method.fabric.kernel=numpy"])
    monkeypatch.setattr(compiled, "AVAILABLE", True)
    assert bench_timing.method_overrides("fabrics+numba") == ("fabrics",
                                                       ["method.fabric.kernel=numba"])
    monkeypatch.setattr(compiled, "AVAILABLE", False)
    with pytest.raises(ValueError, match="numba is not installed"):
        bench_timing.method_overrides("fabrics+numba")


def test_render_rewrites_the_sections_from_the_saved_reports(tmp_path, capsys, request):
    assert bench.main(["--render", "--root", str(tmp_path)]) == 2  # nothing saved yet
    assert capsys.readouterr().err.startswith("error: --render needs the saved reports")
    request.getfixturevalue("saved_bench_reports")
    (tmp_path / "BENCHMARKS.md").write_text("# Benchmarks\n\n## Z\nz\n")
    # --no-write prints the sections and leaves the file as it is
    assert bench.main(["--render", "--no-write", "--root", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "| fpm | 2 | 0.500 |" in printed and "## Fabrics" in printed
    assert (tmp_path / "BENCHMARKS.md").read_text() == "# Benchmarks\n\n## Z\nz\n"
    assert bench.main(["--render", "--root", str(tmp_path)]) == 0
    text = (tmp_path / "BENCHMARKS.md").read_text()
    assert "| fpm | 2 | 0.500 |" in text and "## Fabrics" in text and "## Z\nz" in text


def test_a_rewritten_section_keeps_the_block_another_command_wrote(tmp_path):
    """``bench`` rewrites its "## Fabrics" section up to the next section or the next block
    another command owns (the learner table's ``<!-- result: learner -->``), never into it."""
    from tamedpuma.app.bench_fabrics import update_markdown

    page = tmp_path / "BENCHMARKS.md"
    block = "<!-- result: learner -->\n## PUMA training\n\nrows\n<!-- /result -->\n"
    page.write_text("# Benchmarks\n\n## Fabrics\n\nold\n\n" + block + "\n## Later\n\nkept\n")
    update_markdown(page, "## Fabrics\n\nnew\n")
    text = page.read_text()
    assert "old" not in text and "## Fabrics\n\nnew\n" in text
    assert block in text and text.endswith("## Later\n\nkept\n")


def test_every_benchmark_section_names_the_code_it_measured():
    """bench.json, fabrics.json and steps.json record the code revision (with the machine) and
    each BENCHMARKS.md section they write names it."""
    from tamedpuma.app.bench_fabrics import code_line, machine_info
    from tamedpuma.app.models import code_revision

    assert machine_info()["code_revision"] == code_revision()
    assert code_line({"code_revision": "0123456789abcdef0123"}) == "Code: `0123456`."
    assert code_line({}) == "Code: not recorded in this report."
    text = (ROOT / "BENCHMARKS.md").read_text()
    for section in ("## Controller step\n", "## Fabrics\n", "## Controller step in episodes\n"):
        body = text[text.index(section):]
        body = body[:body.find("\n## ", 1) if "\n## " in body[1:] else len(body)]
        assert "\nCode: `" in body, section
