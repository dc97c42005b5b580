"""Obstacle-count scaling from a sweep's summaries:
``python -m analysis.scaling RUNS_DIR [--out DIR] [--timing-only DIR]`` (after
``+experiment=scaling``).

Per method label and obstacle count (the scenario's own plus clutter, as run): the runs, success
under both criteria (``tamedpuma/metrics.py``), the median time to success [s], the whole-body
failure classes, and the controller time over every step of those runs (median and p99 [ms]; the
first step of each run is included). Writes ``scaling.md`` (two tables: time and success; time
to success and failures), ``scaling.csv`` and ``scaling.png`` (time and success against the
count, one line per method). Runs that did not complete (e.g. ``clutter.keep_clear=path`` without
a successful reference run) are listed by reason, not counted.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from tamedpuma.analysis.runs import parse_and_load, runs_or_error, runs_parser
from tamedpuma.analysis.summaries import step_stats
from tamedpuma.analysis.tables import column_rate, ordered_labels


def scaling_table(runs: pd.DataFrame, times: dict) -> pd.DataFrame:
    """One row per (method label, obstacle count): runs, success (paper / whole body), median
    time to success [s], failure classes, pooled controller time median and p99 [ms], mean first
    step [ms], steps timed. Runs with a true ``timing_only`` column (episodes cut short by
    ``scenario.max_steps``: Modulation-IK at 1000 obstacles) count in the times only: a cell of
    them alone has no success (NaN) and ``runs`` = 0, ``timed_runs`` their number."""
    timing_only = (runs["timing_only"].fillna(False).astype(bool) if "timing_only" in runs
                   else pd.Series(False, index=runs.index))
    rows = []
    for label in ordered_labels(runs["method_label"]):
        r = runs[runs["method_label"] == label]
        for count in sorted(r["n_obstacles"].unique()):
            timed = r[r["n_obstacles"] == count]
            c = timed[~timing_only[timed.index]]
            st = step_stats([times[p] for p in timed["path"] if p in times])
            ok = c[c["success_whole_body"].astype(bool)]
            nan = float("nan")  # also the times of a cell without steps
            rows.append({"method": label, "obstacles": int(count), "runs": len(c),
                         "timed_runs": len(timed),
                         "success_paper": c["success_paper"].mean() if len(c) else nan,
                         "success_whole_body": (c["success_whole_body"].mean() if len(c)
                                                else nan),
                         "converged_paper": column_rate(c, "converged_paper").mean(),
                         "time_to_success_s": (float(ok["time_to_success_s"].median())
                                               if len(ok) else nan),
                         "failures": failure_counts(c["failure_whole_body"]),
                         "median_ms": st.get("median_ms", nan), "p99_ms": st.get("p99_ms", nan),
                         "first_step_ms": st.get("first_mean_ms", nan), "steps": st["steps"]})
    return pd.DataFrame(rows)


def failure_counts(classes: pd.Series) -> str:
    """'joint_limit 2, time 1' from the runs' whole-body failure classes ('' = success)."""
    counts = classes[classes.fillna("") != ""].value_counts()
    return ", ".join(f"{name} {n}" for name, n in sorted(counts.items()))


def _grid(table: pd.DataFrame, cell) -> str:
    """Methods as rows, obstacle counts as columns; ``cell(row)`` writes one cell ('—' where a
    method has no row at that count)."""
    counts = sorted(table["obstacles"].unique())
    lines = ["| method | " + " | ".join(f"{c} obstacles" for c in counts) + " |",
             "|---|" + "---|" * len(counts)]
    for label in ordered_labels(table["method"]):
        cells = []
        for c in counts:
            row = table[(table["method"] == label) & (table["obstacles"] == c)]
            cells.append("—" if row.empty else cell(row.iloc[0]))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _outcome_cell(r) -> str:
    if r.runs == 0:
        return "not measured (timing only)"
    wins = round(r.success_whole_body * r.runs)
    cell = f"{wins}/{r.runs}"
    if wins:
        cell += f", {r.time_to_success_s:.1f} s"
    if r.converged_paper == r.converged_paper:  # not NaN: the summaries record it
        cell += f", converged {round(r.converged_paper * r.runs)}"
    if r.failures:
        cell += f"; {r.failures}"
    return cell


def _timing_cell(r) -> str:
    if r.runs == 0:
        return (f"{r.median_ms:.2f} / {r.p99_ms:.2f} ms (timing only: "
                f"{r.timed_runs} × {r.steps // max(r.timed_runs, 1)} steps)")
    return (f"{r.median_ms:.2f} / {r.p99_ms:.2f} ms "
            f"({r.success_paper:.2f}, {r.success_whole_body:.2f}; n={r.runs})")


def outcome_markdown(table: pd.DataFrame) -> str:
    """Methods as rows, counts as columns: 'successes/runs, median time to success, converged
    runs; failures'."""
    return _grid(table, _outcome_cell)


def markdown(table: pd.DataFrame) -> str:
    """Methods as rows, counts as columns: 'median / p99 ms (paper, whole-body success)'."""
    return _grid(table, _timing_cell)


def figure(table: pd.DataFrame, path: Path) -> None:
    """Controller time (median solid, p99 dashed) and success (paper) against the count."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_t, ax_s) = plt.subplots(1, 2, figsize=(11, 4.2))
    for label in ordered_labels(table["method"]):
        r = table[table["method"] == label].sort_values("obstacles")
        line, = ax_t.plot(r["obstacles"], r["median_ms"], "o-", label=label)
        ax_t.plot(r["obstacles"], r["p99_ms"], "--", color=line.get_color())
        ax_s.plot(r["obstacles"], r["success_paper"], "o-", color=line.get_color(), label=label)
        ax_s.plot(r["obstacles"], r["success_whole_body"], "x:", color=line.get_color())
    ax_t.set(xscale="log", yscale="log", xlabel="obstacles", ylabel="controller time [ms]",
             title="median (solid) and p99 (dashed) per step")
    ax_s.set(xscale="log", xlabel="obstacles", ylabel="success rate", ylim=(-0.05, 1.05),
             title="success: paper (solid), whole body (dotted)")
    ax_t.legend(fontsize=8)
    for ax in (ax_t, ax_s):
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _reason(summary_path: str) -> str:
    """A failed run's recorded reason (its summary.json), or '?'."""
    import json

    try:
        return str(json.loads(Path(summary_path).read_text()).get("reason", "?"))
    except (OSError, ValueError):
        return "?"


def main(argv: list[str] | None = None) -> int:
    parser = runs_parser(__doc__, "output folder (default: RUNS)")
    parser.add_argument("--timing-only", type=Path, action="append", default=[],
                        metavar="DIR", help="runs cut short by scenario.max_steps: their "
                        "controller times count, their success does not (repeatable)")
    got = parse_and_load(parser, argv, summaries=True)
    if got is None:
        return 2
    args, (runs, times) = got
    skipped = list(runs.attrs.get("skipped", []))
    for folder in args.timing_only:
        extra = runs_or_error(folder, summaries=True)
        if extra is None:
            return 2
        frame, extra_times = extra
        skipped += frame.attrs.get("skipped", [])
        runs = pd.concat([runs.assign(timing_only=False), frame.assign(timing_only=True)],
                         ignore_index=True)
        times = {**times, **extra_times}
    table = scaling_table(runs, times)
    out = args.out or args.runs
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "scaling.csv", index=False)
    text = (markdown(table) + "\nWhole-body successes/runs, median time to success, failure "
            "classes:\n\n" + outcome_markdown(table))
    (out / "scaling.md").write_text(text)
    figure(table, out / "scaling.png")
    print(text)
    for path in skipped:
        print(f"not counted (no complete summary): {path}: {_reason(path)}")
    print(f"{len(runs)} runs read ({len(skipped)} not counted); scaling.md, scaling.csv, "
          f"scaling.png in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
