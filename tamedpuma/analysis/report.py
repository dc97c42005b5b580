"""One Markdown page from run logs: ``python -m analysis.report RUNS_DIR [--out DIR]``.

``report.md`` holds: what was read (and what was not: the completeness of every Hydra sweep
below RUNS, i.e. missing job folders, folders without a readable log, truncated or interrupted
runs), Table 1 (:mod:`tamedpuma.analysis.tables`), success and timing per method with 95%
bootstrap intervals, the figures (:mod:`tamedpuma.analysis.figures`), and every failing run with
its stop reason, failure class and the command that replays it. An incomplete or damaged sweep
is reported, never a crash.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pandas as pd
import yaml

from tamedpuma.analysis.figures import make_figures, method_summary
from tamedpuma.analysis.runs import (
    add_scoring_flags,
    parse_and_load,
    runs_parser,
    scored_runs,
    split_incomplete,
)
from tamedpuma.analysis.sweep_values import sweep_size
from tamedpuma.analysis.tables import _labels, path_differences, table1


def _sweep_size(multirun_yaml: Path) -> int | None:
    """Jobs a Hydra multirun asked for: the product of the value counts of its comma-list
    overrides (command line, else ``hydra.sweeper.params``); None if unreadable."""
    try:
        cfg = yaml.safe_load(multirun_yaml.read_text()) or {}
        hydra = cfg.get("hydra", {})
        params = dict((hydra.get("sweeper") or {}).get("params") or {})
        for item in (hydra.get("overrides") or {}).get("task") or []:
            key, _, value = str(item).partition("=")
            params[key.lstrip("+~")] = value
        return sweep_size(str(v) for v in params.values())
    except (OSError, yaml.YAMLError, AttributeError, TypeError):
        return None




def completeness(root: Path, runs: pd.DataFrame) -> list[dict]:
    """One entry per Hydra sweep below ``root`` (folders holding ``multirun.yaml``): expected
    jobs, job folders present, and the problems: ``missing`` job numbers, ``no_log`` folders
    (no readable MCAP: the job failed before or while writing), ``truncated`` runs (a log left
    ``.active`` or unreadable to the end) and ``interrupted`` ones (closed as incomplete)."""
    out = []
    read = set(runs["path"]) if len(runs) else set()
    for manifest in sorted(root.rglob("multirun.yaml")):
        sweep = manifest.parent
        jobs = {}
        for d in sweep.iterdir():
            head = d.name.split("_", 1)[0]
            if d.is_dir() and head.isdigit():
                jobs[int(head)] = d
        expected = _sweep_size(manifest)
        missing = sorted(set(range(expected)) - set(jobs)) if expected else []
        no_log, truncated, interrupted = [], [], []
        for _, d in sorted(jobs.items()):
            logs = [p for p in (d / "episode.mcap", d / "episode.mcap.active") if p.is_file()]
            if not logs or not any(str(p) in read for p in logs):
                no_log.append(d)
                continue
            row = runs[runs["path"] == str(logs[0])].iloc[0]
            if logs[0].name.endswith(".active") or row.get("read_error"):
                truncated.append(d)
            elif not row["complete"]:
                interrupted.append(d)
        out.append({"sweep": sweep, "expected": expected, "present": len(jobs),
                    "missing": missing, "no_log": no_log, "truncated": truncated,
                    "interrupted": interrupted})
    return out


def _count(n: int, noun: str) -> str:
    """``1 run``, ``2 runs``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _rel(path: Path | str, base: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(base.resolve()))
    except ValueError:
        return str(path)


def failing_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """Runs that failed under either criterion or did not finish, with what stopped them."""
    if runs.empty:
        return runs
    bad = runs[~runs["success_paper"].astype(bool) | ~runs["success_whole_body"].astype(bool)
               | ~runs["complete"].astype(bool)]
    return bad.assign(method_label=_labels(runs)[bad.index])


def _completeness_lines(root: Path, runs: pd.DataFrame) -> list[str]:
    """The "Completeness" section: every sweep's missing jobs and bad logs, unreadable logs."""
    lines = ["## Completeness", ""]
    sweeps = completeness(root, runs)
    if not sweeps:
        lines += ["No Hydra sweep (`multirun.yaml`) below this folder: single runs only.", ""]
    for s in sweeps:
        expected = s["expected"] if s["expected"] is not None else "?"
        lines.append(f"- `{_rel(s['sweep'], root)}`: {s['present']} of {expected} job folders")
        if s["missing"]:
            lines.append(f"  - missing jobs: {', '.join(map(str, s['missing']))}")
        for key, what in (("no_log", "no readable log (failed)"),
                          ("truncated", "truncated log (killed or damaged)"),
                          ("interrupted", "interrupted (closed incomplete)")):
            for d in s[key]:
                lines.append(f"  - {what}: `{_rel(d, root)}`")
        if not (s["missing"] or s["no_log"] or s["truncated"] or s["interrupted"]):
            lines.append("  - complete")
    for p in runs.attrs.get("skipped", []):
        lines.append(f"- unreadable log: `{_rel(p, root)}`")
    lines.append("")
    return lines


def _intervals_lines(runs: pd.DataFrame) -> list[str]:
    """The success and timing table with 95% bootstrap intervals per method."""
    summary = method_summary(runs)
    lines = ["## Success and timing, 95% bootstrap intervals", "",
             "Value [2.5%, 97.5%] over the runs with obstacles (percentile bootstrap, 4000 "
             "resamples, seed 0).", ""]
    table = pd.DataFrame({
        "method": summary["method"], "runs": summary["runs"],
        "success (paper)": summary["success_paper"].map(str),
        "success (whole body)": summary["success_whole_body"].map(str),
        "time to success [s]": summary["time_to_success_s"].map(str),
        "controller time, median per run [ms]": summary["compute_ms_median"].map(str)})
    return lines + [table.to_markdown(index=False, disable_numparse=True), ""]


def _failing_lines(runs: pd.DataFrame) -> list[str]:
    """The "Failing runs" section: each with its stop reason, failure class and replay command."""
    lines = ["## Failing runs", ""]
    bad = failing_runs(runs)
    if bad.empty:
        return lines + ["None.", ""]
    rows = []
    for r in bad.itertuples():
        run_dir = Path(r.path).parent
        tts = r.time_to_success_s
        rows.append({
            "method": r.method_label, "task": r.task, "scenario": r.scenario,
            "seed": r.seed, "obstacles": r.n_obstacles,
            "stop reason": r.stop_reason or "—",
            "failure (paper / whole body)":
                f"{r.failure_paper or '—'} / {r.failure_whole_body or '—'}",
            "min clearance [m]": f"{r.min_clearance_m:.3f}",
            "time to success [s]": "—" if not math.isfinite(tts) else f"{tts:.2f}",
            "replay": f"`python -m tamedpuma.replay {run_dir}`"})
    return lines + [pd.DataFrame(rows).to_markdown(index=False, disable_numparse=True), ""]


def render(root: Path, runs: pd.DataFrame, paths: dict, times: dict, out: Path,
           figures: bool = True, include_incomplete: bool = False) -> str:
    """The report's Markdown (figures written to ``out/figures``). Incomplete runs are listed
    under "Completeness" and scored only with ``include_incomplete``
    (:func:`~tamedpuma.analysis.runs.split_incomplete`, the rule of every analysis)."""
    lines = [f"# Report: `{root}`", ""]
    skipped = runs.attrs.get("skipped", [])
    lines += [f"{_count(len(runs), 'run')} read from their MCAP logs; "
              f"{_count(len(skipped), 'log')} unreadable.", ""]
    lines += _completeness_lines(root, runs)
    scored, incomplete = split_incomplete(runs, include_incomplete)
    if len(incomplete):
        how = "scored as they are" if include_incomplete else "not scored"
        lines += [f"{_count(len(incomplete), 'incomplete run')} (killed, interrupted or "
                  f"truncated: listed above) {'is' if len(incomplete) == 1 else 'are'} {how}.",
                  ""]
    if scored.empty:
        lines += ["No readable run: nothing to tabulate." if runs.empty else
                  "No complete run: nothing to tabulate (`--include-incomplete` scores the "
                  "incomplete ones).", ""]
        return "\n".join(lines)

    runs = scored.copy()
    runs["path_difference_m"] = path_differences(runs, paths)
    lines += ["## Table 1", "", table1(runs, times).to_markdown(index=False,
                                                                 disable_numparse=True), ""]
    lines += _intervals_lines(runs)
    if figures:
        written = make_figures(runs, paths, out / "figures")
        lines += ["## Figures", ""]
        for p in written:
            if p.suffix == ".png":
                lines += [f"![{p.stem}]({_rel(p, out)})", ""]
    lines += _failing_lines(runs)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = add_scoring_flags(runs_parser(__doc__, "output folder (default: RUNS)"))
    parser.add_argument("--no-figures", action="store_true", help="tables only")
    got = parse_and_load(parser, argv, allow_empty=True)
    if got is None:
        return 2
    args, (runs, paths, times) = got
    if scored_runs(runs, args) is None:  # runs of different models in one row
        return 2
    out = args.out or args.runs
    out.mkdir(parents=True, exist_ok=True)
    text = render(args.runs, runs, paths, times, out, figures=not args.no_figures,
                  include_incomplete=args.include_incomplete)
    (out / "report.md").write_text(text + "\n")
    print(out / "report.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
