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


def _write(root: Path, label: str, scenario: str, converged: bool, whole_body: bool = True,
           oriented: bool | None = None, contact: bool = False):
    folder = root / label / scenario
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text(json.dumps({
        "method": label.split("-")[0], "method_label": label, "task": "tomato",
        "scenario": scenario, "n_obstacles": 2, "success_paper": True,
        "success_whole_body": whole_body, "converged_paper": converged,
        "converged_whole_body": converged and whole_body,
        "orientation_converged_paper": converged if oriented is None else oriented,
        "obstacle_contact": contact, "ground_contact": False,
        "joint_limit_violation_steps": 0, "left_after_reach": False,
        "step_compute_ms": [1.0, 1.0]}))


def _suite(root: Path, label: str, failing: set[int], prefix: str = "random_tomato_anywhere_",
           unoriented: frozenset = frozenset(), contacts: frozenset = frozenset()):
    for k in range(N):
        _write(root, label, f"{prefix}{2000 + k}", k not in failing,
               oriented=k not in failing and k not in unoriented, contact=k in contacts)


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


def test_a_loss_of_orientation_or_of_safety_alone_pays(tmp_path):
    """The verdict is the worst over converged, converged with orientation, whole body and
    safety: a removal that converges as often but loses the goal orientation significantly, or
    touches obstacles where the defaults and the neutral change do not, pays."""
    _suite(tmp_path, "cpm", failing=set())
    _suite(tmp_path, "cpm-churn", failing=set(), contacts=frozenset({5}))  # 1 new unsafe run
    _suite(tmp_path, "cpm-turns", failing=set(), unoriented=frozenset(range(7)))
    _suite(tmp_path, "cpm-touches", failing=set(), contacts=frozenset({1, 2, 3}))
    _suite(tmp_path, "cpm-once", failing=set(), contacts=frozenset({9}))
    assert ablation.main([str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    rows = pd.read_csv(tmp_path / "out" / "ablation.csv").set_index(["removed", "suite"])
    assert rows.loc[("turns", "random"), "verdict"] == "pays"
    assert rows.loc[("turns", "random"),
                    "orientation converged paper: lost / gained (p)"].startswith("7 / 0")
    assert rows.loc[("touches", "random"), "verdict"] == "pays"
    assert str(rows.loc[("touches", "random"), "new unsafe"]) == "3"
    contacts = rows.loc[("touches", "random"), "contacts (obstacle / ground / joint limit)"]
    assert contacts == "3 / 0 / 0"
    assert rows.loc[("once", "random"), "verdict"] == "within churn"  # as many as the churn
    pairs = pd.read_csv(tmp_path / "out" / "ablation_pairs.csv")
    new = pairs[(pairs.removed == "touches") & (pairs.outcome == "unsafe")
                & (pairs.suite == "random")]
    assert len(new) == 3 and set(new.change) == {"new"}


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


def test_one_command_runs_both_halves_then_the_analysis(tmp_path):
    """``python -m tamedpuma.ablation`` runs the Table-1 and the randomized half into one
    folder and pairs them there (two rows on one scenario of each suite, one core)."""
    from tamedpuma.app import ablation as command

    argv = [f"output_root={tmp_path}", "ablation=fpm/none,fpm/churn", "hydra.launcher.n_jobs=1",
            "--table1", "case=tomato_00", "--random", "scenario.random_seed=range(2000,2001)",
            "--random", "task=tomato", "--random", "scenario.start_kind=near_table1"]
    assert command.main(argv) == 0
    rows = pd.read_csv(tmp_path / "ablation" / "ablation.csv")
    assert set(rows.suite) == {"all", "table1", "random"}
    assert set(rows.removed) == {"none", "churn"}
    assert (rows[rows.suite == "all"].scenarios == 2).all()
    assert "#### Table 1" in (tmp_path / "ablation" / "ablation.md").read_text()


def test_the_ablation_command_refuses_bad_options_in_one_line(capsys):
    from tamedpuma.app import ablation as command

    assert command.main(["--only", "both"]) == 2
    assert command.main(["--random", "output_root=elsewhere"]) == 2
    assert command.main(["--frobnicate"]) == 2
    assert command.main(["--table1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("error: ") for line in err)
    assert command.parse(["output_root=x", "--random", "task=tomato"]) == (
        ["table1", "random"], {"table1": ["output_root=x"],
                               "random": ["output_root=x", "task=tomato"]})
