"""The randomized suite from its logs: ``python -m analysis.random_suite RUNS_DIR [--out DIR]``
(after ``+experiment=random``).

Per task and method label, on the runs with obstacles: success under both criteria
(``tamedpuma/metrics.py``) and success with orientation under the paper criterion (the goal
orientation also held after the settle time: the pose the task asks for) with 95 % Wilson score
intervals (:func:`tamedpuma.analysis.stats.rate_interval`), converged (the hand
comes to rest in the goal ball; with and without the goal orientation) with its interval and the
runs that left the ball after first reaching it, time to success [s]
(mean ± std over the paper-criterion successes), the path difference to PUMA [m] (mean ± std over
the obstacle-free runs of the same scenarios) and the whole-body failures by class
(sphere_penetration, obstacle_contact, ground_contact, joint_limit, stall, time, late); then the
same three rates per kind of start (``near_table1``, ``anywhere``: read from the scenario's name,
``random_<task>_<kind>_<seed>``). Writes ``random_suite.md``/``.csv``,
``random_suite_by_start.md``/``.csv`` and ``runs.csv``. Last, the controller's time per step
over every step of every run with obstacles, per method (both tasks pooled): median, p99, p99.9 and
max [ms], the steps over the 10 ms bound and over the 20 ms control period, and the runs holding
a step over the period (``random_suite_steps.md``/``.csv``); the time is the wall time of
``controller.step`` that each run's log records.
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd

from tamedpuma.analysis import stats
from tamedpuma.analysis.runs import parse_and_load, runs_parser, split_incomplete, write_table
from tamedpuma.analysis.summaries import PERIOD_MS, step_stats
from tamedpuma.analysis.tables import (
    _pm,
    column_rate,
    failure_counts,
    left_count,
    ordered_labels,
    path_differences,
)
from tamedpuma.worlds.random_scenarios import START_KINDS


def _rate(values) -> str:
    return str(stats.rate_interval(np.asarray(values, dtype=float)))


def start_kind(scenario: str) -> str:
    """The kind of start of a generated scenario's name ``random_<task>_<kind>_<seed>`` (one of
    :data:`~tamedpuma.worlds.random_scenarios.START_KINDS`), or ``other``."""
    stem, _, seed = str(scenario).rpartition("_")
    if stem.startswith("random_") and seed.isdigit():
        for kind in START_KINDS:  # the task's name may hold underscores too (panda_reach)
            if stem.endswith(f"_{kind}"):
                return kind
    return "other"


def _rates(scored: pd.DataFrame) -> dict[str, str]:
    return {"scenarios": len(scored),
            "success (paper) [95% CI]": _rate(scored["success_paper"].astype(float)),
            "success (whole body) [95% CI]": _rate(scored["success_whole_body"].astype(float)),
            "with orientation (paper) [95% CI]":
                _rate(scored["orientation_success_paper"].astype(float)),
            "converged (paper) [95% CI]": _rate(column_rate(scored, "converged_paper")),
            "converged with orientation (paper) [95% CI]":
                _rate(column_rate(scored, "orientation_converged_paper")),
            "left the ball after reaching": left_count(scored)}


def by_start_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per task, kind of start and method label, on the runs with obstacles: the three success
    rates of :func:`random_table` with their intervals (the scenarios of one kind resampled)."""
    scored = runs[runs["n_obstacles"] > 0].assign(start=runs["scenario"].map(start_kind))
    rows = []
    for task in sorted(scored["task"].unique()):
        t = scored[scored["task"] == task]
        for kind in [k for k in (*START_KINDS, "other") if (t["start"] == k).any()]:
            k = t[t["start"] == kind]
            for label in ordered_labels(k["method_label"]):
                rows.append({"task": task, "start": kind, "method": label,
                             **_rates(k[k["method_label"] == label])})
    return pd.DataFrame(rows)


def step_table(runs: pd.DataFrame, times: dict[str, np.ndarray]) -> pd.DataFrame:
    """Per method label, over every step of its runs with obstacles (both tasks): the
    controller time's median, p99, p99.9 and max [ms], the steps over the 10 ms bound and over
    the control period, and the runs with a step over the period; ``times``: per-step times
    [ms] by run path."""
    scored = runs[runs["n_obstacles"] > 0]
    rows = []
    for label in ordered_labels(scored["method_label"]):
        paths = [p for p in scored.loc[scored["method_label"] == label, "path"]
                 if p in times and len(times[p])]
        if not paths:
            continue
        st = step_stats([times[p] for p in paths])
        rows.append({"method": label, "runs": len(paths), "steps": st["steps"],
                     "median [ms]": round(st["median_ms"], 3), "p99": round(st["p99_ms"], 2),
                     "p99.9": round(st["p99_9_ms"], 2), "max": round(st["max_ms"], 2),
                     "steps > 10 ms": st["over_bound"],
                     f"steps > {PERIOD_MS:g} ms (the period)": st["over_period"],
                     "runs with a step over the period": sum(
                         bool(np.max(times[p]) > PERIOD_MS) for p in paths)})
    return pd.DataFrame(rows)


def random_table(runs: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for task in sorted(runs["task"].unique()):
        t = runs[runs["task"] == task]
        for label in ordered_labels(t["method_label"]):
            r = t[t["method_label"] == label]
            scored = r[r["n_obstacles"] > 0]
            ok = scored[scored["success_paper"]]
            rows.append({
                "task": task, "method": label, **_rates(scored),
                "time-to-success [s]": _pm(ok["time_to_success_s"]),
                "path difference to PUMA [m]": _pm(r["path_difference_m"], 3),
                "whole-body failures": failure_counts(scored["failure_whole_body"]),
            })
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    parser = runs_parser(__doc__, "output folder (default: RUNS)")
    parser.add_argument("--include-incomplete", action="store_true",
                        help="score killed/truncated runs too (default: listed and excluded)")
    got = parse_and_load(parser, argv)
    if got is None:
        return 2
    args, (every, paths, times) = got
    # incomplete runs are not scored: the rule of every analysis
    runs, incomplete = split_incomplete(every, args.include_incomplete)
    if runs.empty:
        print(f"error: no complete run below {args.runs} ({len(incomplete)} incomplete; "
              "--include-incomplete scores them)", file=sys.stderr)
        return 2
    runs["path_difference_m"] = path_differences(runs, paths)
    table = random_table(runs)
    out = args.out or args.runs
    text = write_table(table, out, "random_suite")
    text += "\nBy kind of start:\n\n" + write_table(by_start_table(runs), out,
                                                      "random_suite_by_start")
    text += "\nController time per step (every step of every run with obstacles):\n\n" + \
        write_table(step_table(runs, times), out, "random_suite_steps")
    runs.to_csv(out / "runs.csv", index=False)
    print(text)
    how = "scored" if args.include_incomplete else "not scored"
    print(f"{len(every)} runs read ({len(incomplete)} incomplete, {how}), "
          f"{len(every.attrs.get('skipped', []))} unreadable; tables in {out}")
    for path in incomplete["path"]:
        print(f"  incomplete: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
