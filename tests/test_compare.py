"""``python -m tamedpuma.analysis.compare``: rates with intervals per entry and suite, the
scenarios one entry solves and the other does not, McNemar's exact p, the figure, and the
refusal of runs of different suite versions."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from tamedpuma.analysis import compare, stats


def _summary(folder: Path, method: str, scenario: str, solved: bool, *, suite=None,
             task: str = "tomato", n_obstacles: int = 1, whole_body: bool | None = None,
             converged: bool | None = None):
    run = folder / f"{method}_{task}_{scenario}_{n_obstacles}"
    run.mkdir(parents=True)
    summary = {"status": "complete", "method": method, "method_label": method, "task": task,
               "scenario": scenario, "n_obstacles": n_obstacles, "disturbance": "none",
               "success_paper": solved,
               "success_whole_body": solved if whole_body is None else whole_body,
               "step_compute_ms": [1.0, 1.0]}
    if converged is not None:  # summaries written before the converged criterion have none
        summary["converged_paper"] = converged
    if suite is not None:
        summary["suite"] = suite
    (run / "summary.json").write_text(json.dumps(summary))


SUITE = {"name": "random", "version": 1}


@pytest.fixture
def two_sweeps(tmp_path):
    a, b = tmp_path / "ours", tmp_path / "theirs"
    for i in range(12):  # fpm solves 0-9, pink_cbf 0-3 and 10-11
        name = f"random_tomato_near_table1_{2000 + i}"
        _summary(a, "fpm", name, i < 10, suite=SUITE)
        _summary(b, "pink_cbf", name, i < 4 or i >= 10, suite=SUITE, converged=i < 3)
        _summary(b, "pink_cbf", name, True, suite=SUITE, n_obstacles=0)  # obstacle-free: left out
    _summary(b, "pink_cbf", "tomato_03", True, suite={"name": "table1", "version": 1})
    return a, b


def test_the_paired_comparison_names_the_scenarios_and_the_exact_p(two_sweeps, tmp_path, capsys):
    a, b = two_sweeps
    out = tmp_path / "out"
    assert compare.main([str(a), str(b), "--out", str(out)]) == 0
    table = pd.read_csv(out / "compare.csv")
    row = table[(table["suite"] == "random")].iloc[0]
    assert (row["A"], row["B"], row["paired scenarios"]) == ("fpm", "pink_cbf", 12)
    p = stats.mcnemar_exact(6, 2)
    assert row["success paper: only A / only B (p)"] == f"6 / 2 ({p:.3g})"
    # converged: A's summaries record none, so no scenario is paired on it (not a loss)
    assert row["converged paper: only A / only B (p)"] == "0 / 0 (1)"
    pairs = pd.read_csv(out / "compare_pairs.csv")
    paper = pairs[pairs["outcome"] == "success_paper"]
    assert sorted(paper[paper["solved by"] == "B"]["scenario"]) == [
        f"tomato/random_tomato_near_table1_{s}/1/none" for s in (2010, 2011)]
    assert len(paper[paper["solved by"] == "A"]) == 6
    rates = pd.read_csv(out / "compare_rates.csv").set_index(["suite", "entry"])
    assert rates.loc[("random", "fpm"), "scenarios"] == 12
    assert rates.loc[("random", "pink_cbf"), "success paper [95% CI]"].startswith("0.50 [")
    assert rates.loc[("random", "pink_cbf"), "converged paper [95% CI]"].startswith("0.25 [")
    assert rates.loc[("random", "fpm"), "converged paper [95% CI]"] == "—"
    assert rates.loc[("table1", "pink_cbf"), "scenarios"] == 1
    assert (out / "compare.png").stat().st_size > 1000
    assert "fpm" in capsys.readouterr().out


def test_the_same_method_in_two_folders_is_two_entries(tmp_path):
    a, b = tmp_path / "before", tmp_path / "after"
    for i in range(3):
        _summary(a, "cpm", f"s{i}", True, suite=SUITE)
        _summary(b, "cpm", f"s{i}", i != 1, suite=SUITE)
    assert compare.main([str(a), str(b)]) == 0
    row = pd.read_csv(a / "compare.csv").iloc[0]
    assert (row["A"], row["B"]) == ("cpm@before", "cpm@after")  # in the order given
    assert row["success paper: only A / only B (p)"] == "1 / 0 (1)"


def test_one_folder_pairs_its_methods(tmp_path):
    for i in range(4):
        _summary(tmp_path, "fpm", f"s{i}", True, suite=SUITE)
        _summary(tmp_path, "fabrics", f"s{i}", i < 2, suite=SUITE)
    assert compare.main([str(tmp_path)]) == 0
    row = pd.read_csv(tmp_path / "compare.csv").iloc[0]
    assert (row["A"], row["B"], row["success paper: only A / only B (p)"]) == (
        "fabrics", "fpm", "0 / 2 (0.5)")


@pytest.mark.parametrize("other", [{"name": "random", "version": 2}, None])
def test_different_suite_versions_are_refused_in_one_line(two_sweeps, tmp_path, capsys, other):
    a, _ = two_sweeps
    c = tmp_path / "old"
    _summary(c, "cpm", "random_tomato_near_table1_2000", True, suite=other)
    assert compare.main([str(a), str(c)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different suite versions" in err[0]
    assert "ours (version 1)" in err[0] and f"old (version {'2' if other else 'none'})" in err[0]


def test_a_missing_folder_is_one_line(tmp_path, capsys):
    assert compare.main([str(tmp_path / "nothing"), str(tmp_path)]) == 2
    assert capsys.readouterr().err.count("\n") == 1
