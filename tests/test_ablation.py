"""The ablation's analysis on synthetic run summaries: pairing on the same scenarios, McNemar's
exact test, the verdicts against the neutral change, the table and its figure."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from tamedpuma.analysis import ablation
from tamedpuma.analysis.stats import mcnemar_exact
from tamedpuma.analysis.summaries import load_summaries

N = 20  # scenarios per suite


def _write(root: Path, label: str, scenario: str, converged: bool, whole_body: bool = True):
    folder = root / label / scenario
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text(json.dumps({
        "method": label.split("-")[0], "method_label": label, "task": "tomato",
        "scenario": scenario, "n_obstacles": 2, "success_paper": True,
        "success_whole_body": whole_body, "converged_paper": converged,
        "converged_whole_body": converged and whole_body,
        "orientation_converged_paper": converged, "step_compute_ms": [1.0, 1.0]}))


def _suite(root: Path, label: str, failing: set[int], prefix: str = "random_tomato_anywhere_"):
    for k in range(N):
        _write(root, label, f"{prefix}{2000 + k}", k not in failing)


def test_mcnemar_exact_is_the_two_sided_binomial_tail():
    assert mcnemar_exact(0, 0) == 1.0
    assert mcnemar_exact(0, 6) == pytest.approx(2 / 64)
    assert mcnemar_exact(6, 0) == mcnemar_exact(0, 6)
    assert mcnemar_exact(1, 1) == 1.0
    assert mcnemar_exact(2, 10) == pytest.approx(2 * (1 + 12 + 66) / 4096)


def test_removals_are_paired_on_scenarios_and_judged_against_the_churn(tmp_path):
    _suite(tmp_path, "fpm", failing={0, 1})
    _suite(tmp_path, "fpm-churn", failing={0, 2})           # loses 2, gains 0: the churn
    _suite(tmp_path, "fpm-pays", failing={0, 1, *range(10, 17)})  # loses 7
    _suite(tmp_path, "fpm-neutral", failing={1, 3})          # loses 1, gains 1
    _suite(tmp_path, "fpm-costs", failing=set())             # gains 2: not significant
    _write(tmp_path, "fpm-pays", "tomato_00", True)          # a scenario the base lacks: unpaired
    assert ablation.main([str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    rows = pd.read_csv(tmp_path / "out" / "ablation.csv").set_index(["removed", "suite"])
    assert rows.loc[("pays", "random"), "verdict"] == "pays"
    assert rows.loc[("pays", "random"), "converged paper: lost / gained (p)"].startswith("7 / 0")
    assert rows.loc[("neutral", "random"), "verdict"] == "within churn"
    assert rows.loc[("costs", "random"), "verdict"] == "within churn"  # 0 lost, 2 gained
    assert rows.loc[("churn", "random"), "verdict"] == "—"
    pairs = pd.read_csv(tmp_path / "out" / "ablation_pairs.csv")
    lost = pairs[(pairs.removed == "pays") & (pairs.change == "lost")
                 & (pairs.outcome == "converged_paper") & (pairs.suite == "random")]
    assert sorted(lost.scenario) == sorted(f"random/tomato/random_tomato_anywhere_{2000 + k}"
                                           for k in range(10, 17))
    assert (tmp_path / "out" / "ablation.png").stat().st_size > 10_000


def test_a_removal_that_gains_significantly_costs(tmp_path):
    _suite(tmp_path, "cpm", failing=set(range(8)))
    _suite(tmp_path, "cpm-x", failing=set())
    scored = ablation.scored_runs(load_summaries(tmp_path)[0])
    table, _ = ablation.ablation_table(scored)
    row = table[(table.removed == "x") & (table.suite == "all")].iloc[0]
    assert row["verdict"] == "costs"


def test_no_base_run_is_a_one_line_error(tmp_path, capsys):
    _suite(tmp_path, "fabrics", failing=set())
    assert ablation.main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: no base run")


ROWS = sorted(f"{m.name}/{p.stem}" for m in (Path(__file__).resolve().parents[1] / "tamedpuma"
                                             / "conf" / "ablation").iterdir() if m.is_dir()
              for p in m.glob("*.yaml"))


@pytest.mark.parametrize("row", ROWS)
def test_every_ablation_row_builds_its_controller(row):
    """Each row of ``+experiment=ablation`` composes and builds the controller it runs (a row
    whose settings contradict each other fails every one of its runs)."""
    from tamedpuma.app.compose import compose
    from tamedpuma.app.sweep import build

    cfg = compose("sweep", [f"+ablation={row}", "+case=tomato_00"])
    built = build(cfg)
    base, _, removed = row.partition("/")
    assert built.run.method.name == base
    assert cfg.method.label == (base if removed == "none" else f"{base}-{removed}")
    assert built.controller is not None
