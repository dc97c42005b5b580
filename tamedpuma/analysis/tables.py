"""Table 1 from run logs: ``python -m tamedpuma.analysis.tables RUNS_DIR [--out DIR]``.

One row per method label (``method.label`` of the run's config, else the method name: the CPM
forms ``cpm``, ``cpm_literal`` and ``cpm_original`` are separate rows), scored on the runs with
obstacles:

- success under both criteria side by side (``tamedpuma/metrics.py``): **paper** (within 0.05 m
  of the goal within the horizon, no body sphere penetrating an obstacle sphere) and **whole
  body** (also no PyBullet robot–obstacle or robot–ground contact, no joint-limit violation);
  each also with orientation (≤ 0.2 rad after the settle time);
- converged under both criteria (the hand comes to rest inside the goal ball after the reach),
  converged with the goal orientation, and the runs that left the ball after first reaching it;
- time to success [s] (mean ± std over the paper-criterion successes);
- controller time [ms] over *every step of every run*: mean ± std, median, p99; the first step of
  each run (the warm-up) is included and also shown on its own (mean / max over runs);
- the whole-body failures by class (sphere_penetration, obstacle_contact, ground_contact,
  joint_limit, stall, time, late);
- the path difference to PUMA [m] over obstacle-free runs of the same task and scenario.

Writes ``table1.md``, ``table1.tex`` and ``runs.csv`` to the output folder.
"""

from __future__ import annotations

import sys
from collections import Counter

import numpy as np
import pandas as pd

from tamedpuma.analysis.path_difference import path_difference
from tamedpuma.analysis.runs import add_scoring_flags, parse_and_load, runs_parser, scored_runs
from tamedpuma.analysis.summaries import step_stats

METHOD_ORDER = ["puma", "modulation_ik", "fabrics", "fpm", "cpm", "fpm_literal", "cpm_literal",
                "cpm_original"]


def _labels(runs: pd.DataFrame) -> pd.Series:
    if "method_label" in runs:
        return runs["method_label"].fillna(runs["method"])
    return runs["method"]


def path_differences(runs: pd.DataFrame, paths: dict, reference: str = "puma") -> pd.Series:
    """Per obstacle-free run: path difference [m] to the reference method's run of the same
    task and scenario (NaN where there is none)."""
    labels = _labels(runs)
    free = runs[runs["n_obstacles"] == 0]
    ref = {(r["task"], r["scenario"]): paths[r["path"]] for idx, r in free.iterrows()
           if labels[idx] == reference}
    out = pd.Series(np.nan, index=runs.index, name="path_difference_m")
    for idx, r in free.iterrows():
        key = (r["task"], r["scenario"])
        if key in ref:
            out[idx] = path_difference(paths[r["path"]], ref[key])
    return out


def _pm(values: pd.Series, digits: int = 2) -> str:
    """'mean ± std' of the values, 'value (1 run)' for one, '—' for none."""
    values = pd.Series(values).dropna()
    if values.empty:
        return "—"
    if len(values) == 1:
        return f"{values.iloc[0]:.{digits}f} (1 run)"
    return f"{values.mean():.{digits}f} ± {values.std(ddof=0):.{digits}f}"


def column_rate(runs: pd.DataFrame, column: str) -> pd.Series:
    """Per run, a boolean outcome as 0/1 (NaN where the column is missing: a summary written
    before that outcome was recorded)."""
    if column not in runs:
        return pd.Series(np.nan, index=runs.index)
    return runs[column].astype(float)


def left_count(runs: pd.DataFrame) -> str:
    """'k of n': the runs that left the goal ball after first reaching it ('—' if unknown)."""
    if "left_after_reach" not in runs or runs["left_after_reach"].isna().all():
        return "—"
    return f"{int(runs['left_after_reach'].fillna(False).astype(bool).sum())} of {len(runs)}"


def _mean_or_dash(values: pd.Series) -> str:
    values = pd.Series(values).dropna()
    return f"{values.mean():.2f}" if len(values) else "—"


def converged_cells(runs: pd.DataFrame) -> dict[str, str]:
    """The converged columns of every table: converged under both criteria, converged with
    the goal orientation (paper criterion) and the runs that left the ball after reaching."""
    paper = _mean_or_dash(column_rate(runs, "converged_paper"))
    body = _mean_or_dash(column_rate(runs, "converged_whole_body"))
    return {"converged (paper / whole body)": f"{paper} / {body}",
            "converged with orientation (paper)":
                _mean_or_dash(column_rate(runs, "orientation_converged_paper")),
            "left the ball after reaching": left_count(runs)}


def failure_counts(failures: pd.Series) -> str:
    """'stall 2, ground_contact 1' (most frequent first), '—' when none."""
    counts = Counter(f for f in failures if isinstance(f, str) and f)
    return ", ".join(f"{k} {v}" for k, v in counts.most_common()) or "—"


def ordered_labels(labels) -> list[str]:
    present = set(labels)
    return [m for m in METHOD_ORDER if m in present] + sorted(present - set(METHOD_ORDER))


def cpu_cell(runs: pd.DataFrame) -> str:
    """The controller step's CPU time (its thread's: the work, without the slices the operating
    system gave other processes): the median of the runs' medians and the largest step [ms];
    '—' for logs that do not record it."""
    if "compute_cpu_ms_max" not in runs:
        return "—"
    med = pd.to_numeric(runs["compute_cpu_ms_median"], errors="coerce").dropna()
    top = pd.to_numeric(runs["compute_cpu_ms_max"], errors="coerce").dropna()
    if not len(top):
        return "—"
    return f"{med.median():.2f} / {top.max():.2f}"


def table1(runs: pd.DataFrame, step_times: dict | None = None) -> pd.DataFrame:
    """One row per method label (paper order first) from a runs frame with path differences;
    ``step_times``: per-step controller times [ms] by run path (else the per-run summaries)."""
    rows = []
    labels = _labels(runs)
    for label in ordered_labels(labels):
        r = runs[labels == label]
        scored = r[r["n_obstacles"] > 0] if (r["n_obstacles"] > 0).any() else r
        ok = scored[scored["success_paper"]]
        if step_times is not None:
            st = step_stats([step_times[p] for p in scored["path"] if p in step_times])
        else:  # no per-step data: the per-run figures (documented as such)
            st = {"mean_ms": scored["compute_ms_mean"].mean(), "std_ms": float("nan"),
                  "median_ms": scored["compute_ms_median"].median(),
                  "p99_ms": scored["compute_ms_p99"].max(),
                  "first_mean_ms": scored["compute_ms_first"].mean(),
                  "first_max_ms": scored["compute_ms_first"].max()}
        timed = "median_ms" in st  # the statistics of no step hold the count alone
        rows.append({
            "method": label,
            "runs": len(scored),
            "success (paper)": f"{scored['success_paper'].mean():.2f}",
            "success (whole body)": f"{scored['success_whole_body'].mean():.2f}",
            "with orientation (paper / whole body)":
                f"{scored['orientation_success_paper'].mean():.2f} / "
                f"{scored['orientation_success_whole_body'].mean():.2f}",
            **converged_cells(scored),
            "time-to-success [s]": _pm(ok["time_to_success_s"]),
            "computation [ms] mean ± std (all steps)":
                f"{st['mean_ms']:.2f} ± {st['std_ms']:.2f}" if timed else "—",
            "median / p99 [ms]": (f"{st['median_ms']:.2f} / {st['p99_ms']:.2f}" if timed
                                  else "—"),
            "first step [ms] mean / max":
                f"{st['first_mean_ms']:.2f} / {st['first_max_ms']:.2f}" if timed else "—",
            "CPU time [ms] median / max": cpu_cell(scored),
            "whole-body failures": failure_counts(scored["failure_whole_body"]),
            "path difference to PUMA [m]": _pm(r["path_difference_m"]),
        })
    return pd.DataFrame(rows)


def model_notes(runs: pd.DataFrame) -> list[str]:
    """One line per trained model the runs used: which data it came from (synthetic: the shipped
    models; real: the authors' demonstrations), its origin and sha256."""
    if "model_sha256" not in runs:
        return []
    used = runs[runs["model_sha256"].fillna("") != ""]
    lines = []
    for key, group in used.groupby(["model_name", "model_data", "model_data_source",
                                    "model_origin", "model_sha256"], dropna=False):
        name, kind, source, origin, sha = key
        methods = ", ".join(sorted(set(group.get("method_label", group["method"]))))
        lines.append(f"model {name}: {kind} data ({source}), {origin}, sha256 {sha[:12]}; "
                     f"{len(group)} run{'' if len(group) == 1 else 's'} ({methods})")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = add_scoring_flags(runs_parser(__doc__, "output folder (default: RUNS)"))
    got = parse_and_load(parser, argv)
    if got is None:
        return 2
    args, (runs, paths, times) = got
    attrs = dict(runs.attrs)
    scored = scored_runs(runs, args)
    if scored is None:
        return 2
    runs, incomplete = scored
    if runs.empty:
        print(f"error: no complete run below {args.runs} ({len(incomplete)} incomplete; "
              "--include-incomplete scores them)", file=sys.stderr)
        return 2
    runs["path_difference_m"] = path_differences(runs, paths)
    table = table1(runs, times)
    out = args.out or args.runs
    out.mkdir(parents=True, exist_ok=True)
    runs.to_csv(out / "runs.csv", index=False)
    notes = model_notes(runs) or ["no trained model used"]
    md = table.to_markdown(index=False, disable_numparse=True)
    (out / "table1.md").write_text(md + "\n\n" + "".join(f"- {n}\n" for n in notes))
    (out / "table1.tex").write_text(table.to_latex(index=False)
                                    + "".join(f"% {n}\n" for n in notes))
    print(md)
    for n in notes:
        print(n)
    runs.attrs.update(attrs)
    print(footer(runs, incomplete, args.include_incomplete))
    for path in incomplete["path"]:
        print(f"  incomplete: {path}")
    for folder, reason in runs.attrs.get("failed", []):
        print(f"  failed: {folder}: {reason}")
    for path in runs.attrs.get("skipped", []):
        print(f"  unreadable: {path}")
    print(f"tables in {out}")
    return 0


def footer(runs: pd.DataFrame, incomplete: pd.DataFrame, included: bool) -> str:
    """The count line under the table: complete, incomplete (killed or truncated logs: excluded
    from the rates unless ``included``), failed (the run raised; no log) and unreadable runs."""
    n_complete = int(runs["complete"].astype(bool).sum())  # runs holds incomplete ones if included
    how = "included in the rates" if included else "excluded from the rates"
    return (f"runs: {n_complete} complete, {len(incomplete)} incomplete ({how}), "
            f"{len(runs.attrs.get('failed', []))} failed, "
            f"{len(runs.attrs.get('skipped', []))} unreadable")


if __name__ == "__main__":
    sys.exit(main())
