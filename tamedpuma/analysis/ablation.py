"""The ablation from its run summaries: ``python -m tamedpuma.analysis.ablation RUNS_DIR
[--out DIR]`` (after ``+experiment=ablation`` and ``+experiment=ablation_random``).

The runs carry method labels ``fpm`` / ``cpm`` (the defaults, the base) and ``<method>-<addition>``
(the defaults without that addition; ``conf/ablation/<method>/<addition>.yaml``), and
``<method>-churn``: a neutral change whose lost and gained scenarios measure the churn any
change brings. Each ablated row is compared with its base **on the same scenarios** (task and
scenario name; suite ``table1`` or ``random`` from the name), on the runs with obstacles:

- the rates of both criteria and of converged (paper criterion, with and without orientation)
  with 95 % Wilson score intervals;
- paired on converged (paper), converged with the goal orientation and whole-body success: the
  scenarios the removal **loses** (the base succeeds, the ablated run does not) and **gains**,
  and McNemar's exact two-sided p;
- safety: the runs that touch an obstacle, touch the ground or drive a joint past its limit
  (each counted), and the scenarios where the ablated run does any of these and the base's does
  not (**new unsafe**); and the runs that leave the goal ball after first reaching it;
- the verdict, the worst over the outcomes: ``pays`` (the removal loses significantly,
  p < 0.05, or makes more new unsafe runs than the neutral change does), ``costs`` (it gains
  significantly), ``within churn`` (lost and gained no more than the neutral change's), else
  ``unclear``.

Writes ``ablation.md`` / ``.csv`` (one row per method and addition, both suites pooled and per
suite), ``ablation_pairs.csv`` (every lost or gained scenario) and ``ablation.png`` (Δ converged
per addition with its interval).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from tamedpuma.analysis import stats
from tamedpuma.analysis.runs import parse_and_load, runs_parser

BASES = ("fpm", "cpm")
#: the paired outcomes, in the order the verdict looks at them
OUTCOMES = ("converged_paper", "orientation_converged_paper", "success_whole_body")
#: the safety events a run is counted for (any of them makes it unsafe)
UNSAFE = ("obstacle_contact", "ground_contact", "joint_limit")
ALPHA = 0.05


def suite_of(scenario: str) -> str:
    """``random`` for a generated scenario (``random_<task>_<kind>_<seed>``), else ``table1``."""
    return "random" if str(scenario).startswith("random_") else "table1"


def split_label(label: str) -> tuple[str, str] | None:
    """(base method, removed addition) of an ablation label: ``fpm`` → (fpm, none),
    ``cpm-eps`` → (cpm, eps); None for a label of another method."""
    base, _, addition = str(label).partition("-")
    if base not in BASES:
        return None
    return base, addition or "none"


def scored_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """The runs with obstacles of the two methods' ablations, with ``base``, ``addition``,
    ``suite`` and the paired key; outcomes as 0/1 (a summary without one: NaN)."""
    parts = runs["method_label"].map(split_label)
    keep = parts.notna() & (runs["n_obstacles"] > 0)
    out = runs[keep].copy()
    out["base"] = [p[0] for p in parts[keep]]
    out["addition"] = [p[1] for p in parts[keep]]
    out["suite"] = out["scenario"].map(suite_of)
    out["key"] = out["suite"] + "/" + out["task"] + "/" + out["scenario"].astype(str)
    for column in (*OUTCOMES, "success_paper", "left_after_reach"):
        out[column] = out[column].astype(float) if column in out else np.nan
    for column in ("obstacle_contact", "ground_contact"):
        out[column] = out[column].fillna(False).astype(bool) if column in out else False
    steps = (out["joint_limit_violation_steps"].fillna(0) if "joint_limit_violation_steps" in out
             else pd.Series(0, index=out.index))
    out["joint_limit"] = steps.astype(float) > 0
    out["unsafe"] = out[list(UNSAFE)].any(axis=1).astype(float)
    return out


def paired(base: pd.DataFrame, ablated: pd.DataFrame, outcome: str) -> dict:
    """Lost / gained scenarios of ``outcome`` between the base's and the ablated runs on the
    scenarios both ran (by key), with McNemar's exact p."""
    joined = pd.merge(base[["key", outcome]], ablated[["key", outcome]], on="key",
                      suffixes=("_base", "_ablated")).set_index("key").dropna()
    before, after = joined[f"{outcome}_base"] > 0.5, joined[f"{outcome}_ablated"] > 0.5
    lost = sorted(joined.index[before & ~after])
    gained = sorted(joined.index[~before & after])
    return {"n": len(joined), "lost": lost, "gained": gained,
            "p": stats.mcnemar_exact(len(lost), len(gained)),
            "delta": float(after.mean() - before.mean()) if len(joined) else np.nan}


def verdict(pair: dict, churn: dict | None) -> str:
    """pays / costs / within churn / unclear (see the module) of one paired outcome."""
    lost, gained = len(pair["lost"]), len(pair["gained"])
    if pair["p"] < ALPHA:
        return "pays" if lost > gained else "costs"
    if churn is not None and churn["n"] > 0:
        noise = len(churn["lost"]) + len(churn["gained"])
        if lost <= noise and gained <= noise:
            return "within churn"
    return "unclear"


def _rate(values: pd.Series) -> str:
    return str(stats.rate_interval(values))


def ablation_rows(scored: pd.DataFrame, suite: str) -> tuple[list[dict], list[dict]]:
    """The table's rows for one suite (``all``: both pooled) and the lost/gained pairs."""
    data = scored if suite == "all" else scored[scored["suite"] == suite]
    rows, pairs = [], []
    for base in [b for b in BASES if (data["base"] == b).any()]:
        runs = data[data["base"] == base]
        reference = runs[runs["addition"] == "none"]
        if reference.empty:
            continue
        churn = {o: paired(reference, runs[runs["addition"] == "churn"], o)
                 for o in (*OUTCOMES, "unsafe")}
        for addition in ["none", *sorted(set(runs["addition"]) - {"none"})]:
            r = runs[runs["addition"] == addition]
            row = {"method": base, "removed": addition, "suite": suite, "scenarios": len(r),
                   "success (paper)": _rate(r["success_paper"]),
                   "success (whole body)": _rate(r["success_whole_body"]),
                   "converged (paper)": _rate(r["converged_paper"]),
                   "converged with orientation": _rate(r["orientation_converged_paper"]),
                   "contacts (obstacle / ground / joint limit)": " / ".join(
                       str(int(r[c].sum())) for c in UNSAFE),
                   "left the ball": int(r["left_after_reach"].fillna(0).sum())}
            if addition != "none":
                row.update(_paired_cells(reference, r, churn, addition, pairs, base, suite))
            rows.append(row)
    return rows, pairs


def _paired_cells(reference, r, churn, addition, pairs, base, suite) -> dict:
    cells, verdicts = {}, []
    for outcome in OUTCOMES:
        pair = paired(reference, r, outcome)
        name = outcome.replace("_", " ")
        cells[f"{name}: lost / gained (p)"] = (f"{len(pair['lost'])} / {len(pair['gained'])} "
                                               f"({pair['p']:.3f})")
        verdicts.append(verdict(pair, churn[outcome] if addition != "churn" else None))
        pairs += [{"method": base, "removed": addition, "suite": suite, "outcome": outcome,
                   "change": change, "scenario": key}
                  for change in ("lost", "gained") for key in pair[change]]
    # "gained" of the unsafe flag: unsafe where the base was not (the churn's row: its own noise)
    new, noise = paired(reference, r, "unsafe")["gained"], churn["unsafe"]["gained"]
    cells["new unsafe"] = str(len(new))
    verdicts.append("pays" if len(new) > len(noise) else "within churn")
    pairs += [{"method": base, "removed": addition, "suite": suite, "outcome": "unsafe",
               "change": "new", "scenario": key} for key in new]
    order = ("pays", "costs", "unclear", "within churn")
    cells["verdict"] = "—" if addition == "churn" else min(verdicts, key=order.index)
    return cells


def ablation_table(scored: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(the table: both suites pooled, then each suite; the lost/gained pairs)."""
    rows, pairs = [], []
    for suite in ("all", *sorted(scored["suite"].unique())):
        r, p = ablation_rows(scored, suite)
        rows += r
        pairs += p
    return pd.DataFrame(rows), pd.DataFrame(pairs)


SUITE_TITLES = {"all": "Both suites, paired on every scenario",
                "table1": "Table 1 (the 30 scenarios with their obstacles)",
                "random": "Randomized suite (generated scenarios with their obstacles)"}


def sectioned_markdown(table: pd.DataFrame) -> str:
    """``ablation.md``: one table per suite (both pooled first) under its own heading, the
    suite column dropped; ``ablation.csv`` keeps every row with its suite."""
    parts = []
    for suite in table["suite"].unique():
        rows = table[table["suite"] == suite].drop(columns="suite")
        parts += [f"#### {SUITE_TITLES.get(suite, suite)}", "",
                  rows.to_markdown(index=False, disable_numparse=True), ""]
    return "\n".join(parts)


def ablation_figure(scored: pd.DataFrame, out: Path) -> Path:
    """Δ converged (paper) of each removal against its base, both suites pooled, per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bases = [b for b in BASES if (scored["base"] == b).any()]
    fig, axes = plt.subplots(1, len(bases), figsize=(6 * len(bases), 7), squeeze=False)
    for ax, base in zip(axes[0], bases):
        runs = scored[scored["base"] == base]
        reference = runs[runs["addition"] == "none"]
        names = sorted(set(runs["addition"]) - {"none"})
        deltas = [paired(reference, runs[runs["addition"] == n], "converged_paper")["delta"]
                  for n in names]
        ax.barh(names, deltas, color=["tab:red" if d < 0 else "tab:green" for d in deltas])
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_title(f"{base.upper()}: converged (paper) without each addition − defaults")
        ax.set_xlabel("Δ converged rate (paired scenarios)")
    fig.tight_layout()
    path = out / "ablation.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = runs_parser(__doc__, "output folder (default: RUNS)")
    got = parse_and_load(parser, argv, summaries=True)
    if got is None:
        return 2
    args, (runs, _) = got
    scored = scored_runs(runs)
    if scored.empty or not (scored["addition"] == "none").any():
        print(f"error: no base run (method label fpm or cpm, with obstacles) below {args.runs}",
              file=sys.stderr)
        return 2
    table, pairs = ablation_table(scored)
    out = args.out or args.runs
    table = table.fillna("—")
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "ablation.csv", index=False)  # every row with its suite
    text = sectioned_markdown(table)
    (out / "ablation.md").write_text(text)
    pairs.to_csv(out / "ablation_pairs.csv", index=False)
    figure = ablation_figure(scored, out)
    print(text)
    print(f"{len(scored)} runs scored; ablation.md, ablation.csv, ablation_pairs.csv, "
          f"{figure.name} in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
