"""The disturbance experiment from a sweep's summaries:
``python -m analysis.disturbance RUNS_DIR [--out DIR]`` (after ``+experiment=disturbance``).

Per disturbance (goal_change, push, obstacle_noise, impedance) and method label: the runs,
success under both criteria, converged (at rest in the goal ball), time to success [s] and
recovery time [s] (mean ± std over the successful runs; recovery = time to success − the
disturbance's onset, for the goal change and the push; the noise and the impedance chain act
throughout, so only time to success applies), and the whole-body failures by class. Writes
``disturbance.md`` and ``disturbance.csv``.
"""

from __future__ import annotations

import sys

import pandas as pd

from tamedpuma.analysis.runs import parse_and_load, runs_parser, write_table
from tamedpuma.analysis.tables import _pm, converged_cells, failure_counts, ordered_labels


def disturbance_table(runs: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for dist in sorted(runs["disturbance"].fillna("none").unique()):
        d = runs[runs["disturbance"].fillna("none") == dist]
        for label in ordered_labels(d["method_label"]):
            r = d[d["method_label"] == label]
            ok = r[r["success_whole_body"]]
            rows.append({
                "disturbance": dist, "method": label, "runs": len(r),
                "success (paper)": f"{r['success_paper'].mean():.2f}",
                "success (whole body)": f"{r['success_whole_body'].mean():.2f}",
                **converged_cells(r),
                "time-to-success [s]": _pm(ok["time_to_success_s"]),
                "recovery [s]": _pm(ok["recovery_time_s"]),
                "whole-body failures": failure_counts(r["failure_whole_body"]),
            })
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    parser = runs_parser(__doc__, "output folder (default: RUNS)")
    got = parse_and_load(parser, argv, summaries=True)
    if got is None:
        return 2
    args, (runs, _) = got
    table = disturbance_table(runs)
    out = args.out or args.runs
    text = write_table(table, out, "disturbance")
    print(text)
    print(f"{len(runs)} runs read; disturbance.md, disturbance.csv in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
