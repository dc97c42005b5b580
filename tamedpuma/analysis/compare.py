"""Paired comparison of sweeps: ``python -m tamedpuma.analysis.compare RUNS_A RUNS_B [...]
[--out DIR]``.

Each folder's run summaries (``summary.json``) are read; every (folder, method label) is one
*entry* (named by its method label, with ``@<folder>`` where two folders hold the same label).
On the runs with obstacles, per suite (the run's recorded suite, else ``table1`` or ``random``
from the scenario's name), the table gives each entry's success rates (paper and whole-body
criteria) and its converged rate (the hand at rest in the goal ball) with 95 % Wilson score
intervals (:func:`tamedpuma.analysis.stats.rate_interval`), and for every pair of entries
from different folders (every pair, with one folder) **on the scenarios both ran** (task,
scenario, obstacle count, disturbance): the scenarios one solves and the other does not, and
McNemar's exact two-sided p (:func:`tamedpuma.analysis.ablation.paired`).

Runs of one suite made with different suite versions (``suite.version`` in ``conf/experiment``,
recorded in each summary; none for runs made before versions) are not comparable: their seeds
and scenarios may differ. The command then prints one line naming both and exits with status 2.

Writes ``compare.md``/``.csv`` (the paired rows), ``compare_rates.md``/``.csv`` (the rates per
entry), ``compare_pairs.csv`` (every scenario one entry solves and the other does not) and
``compare.png`` (the rates with their intervals) into ``--out`` (default: the first folder).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from tamedpuma.analysis import stats
from tamedpuma.analysis.ablation import paired, suite_of
from tamedpuma.analysis.runs import runs_or_error, split_incomplete, write_table

#: the paired outcomes (0/1 per run), as in the tables: success under both criteria, and the
#: hand come to rest in the goal ball (paper criterion); a summary without one has NaN there
OUTCOMES = ("success_paper", "success_whole_body", "converged_paper")


def suite_columns(runs: pd.DataFrame) -> pd.DataFrame:
    """``suite_name`` and ``suite_version`` of each run: its summary's ``suite`` block, else
    (a run made before suites had versions) the suite from the scenario name and no version."""
    recorded = runs["suite"] if "suite" in runs else pd.Series([None] * len(runs), runs.index)
    names, versions = [], []
    for block, scenario in zip(recorded, runs["scenario"]):
        block = block if isinstance(block, dict) else {}
        names.append(block.get("name") or suite_of(scenario))
        versions.append(block.get("version"))
    return runs.assign(suite_name=names,
                       suite_version=pd.Series(versions, index=runs.index, dtype=object))


def version_problem(runs: pd.DataFrame) -> str | None:
    """One line naming two folders (or one) holding runs of one suite with different suite
    versions, or None."""
    for suite, group in runs.groupby("suite_name"):
        seen = group.drop_duplicates(["source", "suite_version"])
        versions = {_version(v) for v in seen["suite_version"]}
        if len(versions) > 1:
            where = ", ".join(f"{row.source} (version {_version(row.suite_version)})"
                              for row in seen.itertuples())
            return (f"runs of suite {suite} with different suite versions are not compared "
                    f"(their scenarios may differ): {where}")
    return None


def _version(value) -> str:
    """A recorded suite version as written (none: a run made before versions)."""
    if value is None or value != value:
        return "none"
    return str(int(value)) if isinstance(value, float) and value.is_integer() else str(value)


def entries(runs: pd.DataFrame) -> pd.DataFrame:
    """The runs with obstacles with ``entry`` (method label, ``@folder`` where the label is in
    more than one folder) and the pairing ``key``; outcomes as 0/1."""
    out = runs[runs["n_obstacles"] > 0].copy()
    label = out["method_label"].fillna(out["method"]).astype(str)
    folders = out.assign(_label=label).groupby("_label")["source"].nunique()
    out["entry"] = [lab if folders[lab] == 1 else f"{lab}@{src}"
                    for lab, src in zip(label, out["source"])]
    disturbance = out["disturbance"] if "disturbance" in out else "none"
    out["key"] = (out["task"].astype(str) + "/" + out["scenario"].astype(str) + "/"
                  + out["n_obstacles"].astype(str) + "/" + pd.Series(disturbance, out.index)
                  .fillna("none").astype(str))
    for column in OUTCOMES:
        out[column] = out[column].astype(float) if column in out else np.nan
    return out


def rate_rows(scored: pd.DataFrame) -> list[dict]:
    """Per suite and entry: the scenario count and both success rates with 95 % intervals."""
    rows = []
    for (suite, entry), r in scored.groupby(["suite_name", "entry"], sort=True):
        rates = {o: stats.rate_interval(r[o]) for o in OUTCOMES}
        rows.append({"suite": suite, "entry": entry, "scenarios": len(r),
                     **{f"{o.replace('_', ' ')} [95% CI]": str(rates[o]) for o in OUTCOMES},
                     **{f"_{o}": rates[o] for o in OUTCOMES}})
    return rows


def pair_rows(scored: pd.DataFrame, single_folder: bool) -> tuple[list[dict], list[dict]]:
    """Every pair of entries (from different folders, or any two with one folder) per suite on
    the scenarios both ran: n, the scenarios only one solves and McNemar's exact p, per
    outcome; and those scenarios one per row. A is the entry of the folder given first."""
    rows, scenarios = [], []
    for suite, data in scored.groupby("suite_name", sort=True):
        first = data.groupby("entry")[["order", "source"]].first()
        ordered = sorted(first.index, key=lambda e: (first.loc[e, "order"], e))
        source = first["source"]
        for a, b in itertools.combinations(ordered, 2):
            if source[a] == source[b] and not single_folder:
                continue
            both = set(data.loc[data["entry"] == a, "key"]) & set(
                data.loc[data["entry"] == b, "key"])
            row = {"suite": suite, "A": a, "B": b, "paired scenarios": len(both)}
            for outcome in OUTCOMES:
                # paired() counts B's losses (A solves, B not) and gains against A
                pair = paired(data[data["entry"] == a], data[data["entry"] == b], outcome)
                name = outcome.replace("_", " ")
                row[f"{name}: only A / only B (p)"] = (
                    f"{len(pair['lost'])} / {len(pair['gained'])} ({pair['p']:.3g})")
                scenarios += [{"suite": suite, "A": a, "B": b, "outcome": outcome,
                               "solved by": who, "scenario": key}
                              for who, change in (("A", "lost"), ("B", "gained"))
                              for key in pair[change]]
            rows.append(row)
    return rows, scenarios


def rates_figure(rates: list[dict], out: Path) -> Path:
    """Each entry's success rates per suite, with their 95 % intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    suites = sorted({r["suite"] for r in rates})
    fig, axes = plt.subplots(1, len(suites), figsize=(6 * len(suites), 1.2 + 0.45 * len(rates)),
                             squeeze=False)
    for ax, suite in zip(axes[0], suites):
        rows = [r for r in rates if r["suite"] == suite]
        y = np.arange(len(rows))
        for shift, outcome, color in zip((-0.2, 0.0, 0.2), OUTCOMES,
                                         ("tab:blue", "tab:orange", "tab:green")):
            value = np.array([r[f"_{outcome}"].value for r in rows])
            err = np.array([[r[f"_{outcome}"].value - r[f"_{outcome}"].low,
                             r[f"_{outcome}"].high - r[f"_{outcome}"].value] for r in rows]).T
            ax.errorbar(value, y + shift, xerr=err, fmt="o", color=color, capsize=3,
                        label=outcome.replace("_", " "))
        ax.set_yticks(y, [r["entry"] for r in rows])
        ax.set_xlim(-0.02, 1.02)
        ax.set_xlabel("rate (95 % Wilson interval)")
        ax.set_title(f"suite {suite}")
        ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    path = out / "compare.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def load(folders: list[Path], include_incomplete: bool = False) -> pd.DataFrame | None:
    """The runs of every folder with ``source`` (the folder's name, or its path where two
    names are alike) and the suite columns; None after a one-line error."""
    names = [f.name for f in folders]
    frames = []
    for order, folder in enumerate(folders):
        loaded = runs_or_error(folder, summaries=True)
        if loaded is None:
            return None
        runs, _ = split_incomplete(loaded[0], include_incomplete)
        source = folder.name if names.count(folder.name) == 1 else str(folder)
        frames.append(runs.assign(source=source, order=order))
    return suite_columns(pd.concat(frames, ignore_index=True))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tamedpuma.analysis.compare",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", help="folders holding run folders")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default: the first RUNS folder)")
    parser.add_argument("--include-incomplete", action="store_true",
                        help="score killed/truncated runs too (default: excluded)")
    args = parser.parse_args(argv)
    runs = load(args.runs, args.include_incomplete)
    if runs is None:
        return 2
    problem = version_problem(runs)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    scored = entries(runs)
    if scored.empty:
        print("error: no complete run with obstacles in " + ", ".join(map(str, args.runs)),
              file=sys.stderr)
        return 2
    rates = rate_rows(scored)
    pairs, scenarios = pair_rows(scored, single_folder=len(args.runs) == 1)
    out = args.out or args.runs[0]
    rate_table = pd.DataFrame(rates).drop(columns=[f"_{o}" for o in OUTCOMES])
    print(write_table(rate_table, out, "compare_rates"))
    if pairs:
        print(write_table(pd.DataFrame(pairs), out, "compare"))
    else:
        print("no two entries to pair (one method in one folder)")
    pd.DataFrame(scenarios, columns=["suite", "A", "B", "outcome", "solved by", "scenario"]
                 ).to_csv(out / "compare_pairs.csv", index=False)
    figure = rates_figure(rates, out)
    print(f"{len(scored)} runs with obstacles from {len(args.runs)} folder(s); compare.md, "
          f"compare_rates.md, compare_pairs.csv, {figure.name} in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
