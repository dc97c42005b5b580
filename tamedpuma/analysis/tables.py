"""Rebuild the paper's Table 1 from run logs: ``python -m analysis.tables RUNS_DIR [--out DIR]``.

Per method: success rate, time to success [s] (mean ± std over successes), controller time [ms]
(mean ± std of the per-run means; median of the per-run medians; worst per-run p99), and the path
difference to PUMA [m] over obstacle-free runs of the same task and scenario.
Writes ``table1.md``, ``table1.tex`` and ``runs.csv`` to the output folder.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from tamedpuma.analysis.path_difference import path_difference
from tamedpuma.analysis.runs import load_runs

METHOD_ORDER = ["puma", "modulation_ik", "fabrics", "fpm", "cpm"]


def path_differences(runs: pd.DataFrame, paths: dict, reference: str = "puma") -> pd.Series:
    """Per obstacle-free run: path difference [m] to the reference method's run of the same
    task and scenario (NaN where there is none)."""
    free = runs[runs["n_obstacles"] == 0]
    ref = {(r.task, r.scenario): paths[r.path] for r in free.itertuples()
           if r.method == reference}
    out = pd.Series(np.nan, index=runs.index, name="path_difference_m")
    for idx, r in free.iterrows():
        key = (r["task"], r["scenario"])
        if key in ref:
            out[idx] = path_difference(paths[r["path"]], ref[key])
    return out


def _pm(values: pd.Series, digits: int = 2) -> str:
    values = values.dropna()
    if values.empty:
        return "—"
    return f"{values.mean():.{digits}f} ± {values.std(ddof=0):.{digits}f}"


def table1(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per method (paper order first) from a runs frame with path differences."""
    rows = []
    methods = [m for m in METHOD_ORDER if m in set(runs["method"])]
    methods += sorted(set(runs["method"]) - set(methods))
    for method in methods:
        r = runs[runs["method"] == method]
        scored = r[r["n_obstacles"] > 0] if (r["n_obstacles"] > 0).any() else r
        ok = scored[scored["success"]]
        rows.append({
            "method": method,
            "runs": len(scored),
            "success": f"{scored['success'].mean():.2f}",
            "success (with orientation)": f"{scored['success_with_orientation'].mean():.2f}",
            "time-to-success [s]": _pm(ok["time_to_success_s"]),
            "computation [ms]": _pm(scored["compute_ms_mean"]),
            "computation median / p99 [ms]": (f"{scored['compute_ms_median'].median():.2f} / "
                                              f"{scored['compute_ms_p99'].max():.2f}"),
            "path difference to PUMA [m]": _pm(r["path_difference_m"]),
        })
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, help="folder holding run folders (searched recursively)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: RUNS)")
    args = parser.parse_args(argv)
    if not args.runs.is_dir():
        print(f"error: {args.runs} is not a folder", file=sys.stderr)
        return 2
    runs, paths = load_runs(args.runs)
    if runs.empty:
        print(f"error: no readable run logs (episode.mcap) below {args.runs}", file=sys.stderr)
        return 2
    runs["path_difference_m"] = path_differences(runs, paths)
    table = table1(runs)
    out = args.out or args.runs
    out.mkdir(parents=True, exist_ok=True)
    runs.to_csv(out / "runs.csv", index=False)
    (out / "table1.md").write_text(table.to_markdown(index=False, disable_numparse=True) + "\n")
    (out / "table1.tex").write_text(table.to_latex(index=False))
    print(table.to_markdown(index=False, disable_numparse=True))
    skipped = runs.attrs.get("skipped", [])
    print(f"{len(runs)} runs read, {len(skipped)} skipped; tables in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
