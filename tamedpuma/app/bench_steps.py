"""The controller's step time inside real episodes: a section of ``python -m tamedpuma.bench``
(``--steps``: this section alone).

Each (method, scenario) pair runs one whole episode through the sweep's own ``run_one`` (the
same config, model lookup, scenario and simulator as ``python -m tamedpuma.sweep``, without
recorders) and reads back every step's controller time from the run's ``summary.json``
(``step_compute_ms``): what the user's runs spend, with the stalls, engagements and warm-up they
hold. Per method the steps of all its episodes are pooled: median, p99, p99.9 and max [ms], the
steps over the control period (20 ms) and over the 10 ms bound, and the runs holding
one; each run's own median, p99 and max are checked against the summary's ``compute_ms_*``
fields (the same array: they agree to the summary's rounding). Beside them, in the same run, the
reference ``fabrics`` planner's ``compute_action`` at 2 obstacles (live under
``--reference-python``; its dated figure otherwise, with a note saying so) and our vanilla
fabric on the same prepared states (:mod:`tamedpuma.app.bench_fabrics`), and each method's
median as a ratio to the reference. The reference is timed twice: on prepared states, one call
after another, and driving the robot in a PyBullet episode of its own (where PyBullet is
installed beside it), each call timed between the physics steps as our steps are. The physics
between two steps evicts a step's code and data from the CPU's caches, and the two planners
pay for it differently (a controller made of many small compiled and Python calls more than
one generated function), so the in-episode ratio is the like-for-like one; both are reported.

Scenarios: the first ``--steps-table1`` scenarios of each Table-1 task (with their obstacles, as
``+experiment=table1`` runs them) and the randomized suite's seeds ``--steps-seeds`` of both
tasks and both start kinds (as ``+experiment=random``).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

from tamedpuma.analysis.summaries import BOUND_MS, PERIOD_MS, step_stats

METHODS = ("puma", "fabrics", "fpm", "cpm", "modulation_ik")
TASKS = ("tomato", "pouring")
START_KINDS = ("near_table1", "anywhere")
SECTION = "Controller step in episodes"
COMMAND = "python -m tamedpuma.bench --steps"
#: the statistics of :func:`~tamedpuma.analysis.summaries.step_stats` the report holds
REPORT_KEYS = ("steps", "median_ms", "p99_ms", "p99_9_ms", "max_ms", "over_period", "over_bound")
#: control periods of the reference's own PyBullet episode (12 s at 20 ms: it reaches the goal)
REFERENCE_EPISODE_STEPS = 600


def table1_cases(per_task: int) -> list[tuple[str, list[str]]]:
    """(label, overrides) of the first ``per_task`` Table-1 scenarios of each task, with their
    obstacles."""
    return [(f"table1/{task}_{i:02d}", ["+experiment=table1", f"case={task}_{i:02d}",
                                        "without_obstacles=false"])
            for task in TASKS for i in range(per_task)]


def random_cases(seeds) -> list[tuple[str, list[str]]]:
    """(label, overrides) of the randomized suite's ``seeds`` for both tasks and start kinds,
    with obstacles."""
    return [(f"random/{task}/{kind}/{seed}",
             ["+experiment=random", f"task={task}", f"scenario.start_kind={kind}",
              f"scenario.random_seed={seed}", "without_obstacles=false"])
            for seed in seeds for task in TASKS for kind in START_KINDS]


def report_stats(runs) -> dict:
    """:func:`~tamedpuma.analysis.summaries.step_stats` of ``runs`` (per run, its steps' times
    [ms]), the :data:`REPORT_KEYS` alone."""
    st = step_stats(runs)
    return {k: st[k] for k in REPORT_KEYS if k in st}


def summary_mismatch(summary: dict, stats: dict) -> float:
    """The largest relative difference [1] between ``stats`` (from the run's per-step times) and
    the summary's own ``compute_ms_median``, ``_p99`` and ``_max``."""
    worst = 0.0
    for key in ("median", "p99", "max"):
        ours, theirs = stats[f"{key}_ms"], summary.get(f"compute_ms_{key}")
        if theirs is None:
            return float("inf")
        worst = max(worst, abs(ours - theirs) / max(abs(theirs), 1e-9))
    return worst


def run_summary(overrides: list[str]) -> dict:
    """One run of the sweep config with ``overrides`` through the sweep's ``run_one``, without
    recorders, in a temporary folder: its ``summary.json`` as read back from the file (what a
    sweep's run holds: a non-finite number is null there, e.g. the clearance of a run without
    obstacles)."""
    from tamedpuma.app.compose import compose
    from tamedpuma.app.sweep import run_one

    cfg = compose("sweep", [*overrides, "recorder=none"])
    with tempfile.TemporaryDirectory(prefix="tamedpuma-steps-") as tmp:
        run_dir = Path(tmp) / "run"
        run_dir.mkdir()
        run_one(cfg, run_dir)
        return json.loads((run_dir / "summary.json").read_text())


def run_case(method: str, overrides: list[str], extra=()) -> dict:
    """One episode of ``method`` with ``overrides`` (:func:`run_summary`): its outcome and the
    statistics of the per-step controller times its ``summary.json`` records, checked against
    the summary's own figures."""
    summary = run_summary([*overrides, f"method={method}", *extra])
    ms = summary["step_compute_ms"]
    stats = report_stats([ms])
    return {"method": method, "success": summary.get("success_paper"),
            "stop_reason": summary.get("stop_reason"), **stats,
            "cpu": report_stats([summary["step_compute_cpu_ms"]]),
            "summary_mismatch": summary_mismatch(summary, stats), "ms": ms,
            "cpu_ms": summary["step_compute_cpu_ms"]}


def pooled(rows: list[dict]) -> dict:
    """Per method: runs, the pooled step statistics (wall time; ``cpu``: the step thread's CPU
    time), the runs with a step over the period and over the bound, and the worst summary
    mismatch."""
    out = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method]
        stats = report_stats([r["ms"] for r in mine])
        cpu = report_stats([r["cpu_ms"] for r in mine])
        out[method] = {"runs": len(mine), **stats, "cpu": cpu,
                       "runs_over_period": sum(r["over_period"] > 0 for r in mine),
                       "runs_over_bound": sum(r["over_bound"] > 0 for r in mine),
                       "successes": sum(bool(r["success"]) for r in mine),
                       "summary_mismatch": max(r["summary_mismatch"] for r in mine)}
    return out


def reference_note(live: bool, note: str | None) -> str:
    """How the reference figure was obtained, in one sentence for the report."""
    from tamedpuma.app import bench_fabrics

    if live:
        return "timed live in this run"
    why = note or (f"no Python with the reference `fabrics` package was given "
                   f"(--reference-python or ${bench_fabrics.REFERENCE_ENV}; .ci/run builds one "
                   "with fabrics==0.10.0)")
    return (f"not timed in this run: {why}; its dated figure "
            f"({bench_fabrics.CITED_DATE}, {bench_fabrics.CITED_SOURCE}) is cited instead, so "
            "the ratios compare figures from two different loads")


def reference_at_two(reference_python, calls: int = 2000,
                     episode_steps: int = REFERENCE_EPISODE_STEPS) -> dict:
    """The reference planner's and our vanilla fabric's median [ms] at 2 obstacles, timed now
    (the reference live where ``reference_python`` has it, else its dated figure), and the
    reference's median step driving the robot in PyBullet for ``episode_steps`` periods, timed
    between the physics steps as our steps are in an episode (None where it was not measured,
    ``reference_episode_note`` saying why)."""
    from tamedpuma.app import bench_fabrics

    report = bench_fabrics.run(counts=(2,), calls=calls, reference_python=reference_python,
                               reference_counts=(2,), episode_steps=episode_steps)
    ours = next(r for r in report["results"] if r["n_obstacles"] == 2)
    live = report["reference_live"].get("2")
    ref = live["median_ms"] if live else bench_fabrics.CITED_REFERENCE_MS[2]
    episode = (live or {}).get("episode") or {"skipped": "the reference was not run live"}
    return {"reference_median_ms": ref, "reference_live": bool(live),
            "reference_note": reference_note(bool(live), report.get("reference_note")),
            "reference_episode_median_ms": episode.get("median_ms"),
            "reference_episode": episode,
            "reference_episode_note": episode.get("skipped"),
            "fabric_median_ms": ours.get("median_ms"),
            "reference_cited_1000_ms": bench_fabrics.CITED_REFERENCE_MS[1000]}


def cases(table1_per_task: int, seeds) -> list[tuple[str, list[str]]]:
    """The Table-1 scenarios and randomized-suite seeds timed."""
    return table1_cases(table1_per_task) + random_cases(seeds)


def run(methods=METHODS, table1_per_task: int = 1, seeds=(2000,), reference_python=None,
        extra=(), log=print) -> dict:
    """Every method on every case (one process, one episode at a time), the reference beside
    them in the same run; the report (``benchmarks/steps.json``)."""
    from tamedpuma.app.bench_fabrics import machine_info

    timed = cases(table1_per_task, seeds)
    machine = machine_info()
    reference = reference_at_two(reference_python)
    rows = []
    for label, overrides in timed:
        for method in methods:
            row = run_case(method, overrides, extra)
            row["case"] = label
            rows.append(row)
            log(f"steps: {label} {method}: median {row['median_ms']:.3f} ms, max "
                f"{row['max_ms']:.2f} ms, success {row['success']}")
    methods_out = pooled(rows)
    in_episode = reference["reference_episode_median_ms"]
    for m in methods_out.values():
        m["ratio_to_reference"] = m["median_ms"] / reference["reference_median_ms"]
        m["ratio_to_reference_episode"] = m["median_ms"] / in_episode if in_episode else None
    if hasattr(os, "getloadavg"):
        machine["load_average_1min_end"] = round(os.getloadavg()[0], 2)
    return {"benchmark": "controller step inside whole episodes (run_one, no recorders)",
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "period_ms": PERIOD_MS, "bound_ms": BOUND_MS, "cases": [c for c, _ in timed],
            "overrides": list(extra), "reference": reference, "methods": methods_out,
            "runs": [{k: v for k, v in r.items() if k not in ("ms", "cpu_ms")} for r in rows],
            "machine": machine}


def lines(report: dict) -> list[str]:
    """The report as a Markdown table."""
    ref = report["reference"]
    note = ref.get("reference_note") or ("timed live in this run" if ref.get("reference_live")
                                         else "cited")
    out = [f"In-episode controller step ({len(report['cases'])} scenarios: "
           f"{', '.join(report['cases'])}; {report['date']}). Every step of every episode, as "
           "the run's summary.json records it (`step_compute_ms`: the wall time of "
           "`controller.step`; each run's median, p99 and max agree with the summary's "
           "`compute_ms_*` to a relative "
           f"{max((m['summary_mismatch'] for m in report['methods'].values()), default=0):.1g})."
           f" Reference: `fabrics` 0.10.0 `compute_action` on the iiwa at 2 obstacles "
           f"{ref['reference_median_ms']:.3f} ms on prepared states, one call after another "
           f"({note}); {_episode_line(ref)}; our vanilla fabric on the prepared states "
           f"{ref['fabric_median_ms']:.3f} ms.", "",
           f"| method | runs | steps | median [ms] | × reference | × reference in its episode | "
           f"p99 | p99.9 | max | steps > {report['period_ms']:.0f} ms (the period) | steps > "
           f"{report['bound_ms']:.0f} ms | runs > {report['period_ms']:.0f} ms |",
           "|---|" + "---:|" * 11]
    for name, m in report["methods"].items():
        in_episode = m.get("ratio_to_reference_episode")
        out.append(f"| {name} | {m['runs']} | {m['steps']} | {m['median_ms']:.3f} | "
                   f"{m['ratio_to_reference']:.2f} | "
                   f"{'—' if in_episode is None else f'{in_episode:.2f}'} | "
                   f"{m['p99_ms']:.2f} | {m['p99_9_ms']:.2f} | "
                   f"{m['max_ms']:.2f} | {m['over_period']} | {m['over_bound']} | "
                   f"{m['runs_over_period']} |")
    cpu = {name: m["cpu"] for name, m in report["methods"].items() if m.get("cpu", {}).get("steps")}
    if cpu:
        out += ["", "The same steps in the CPU time of the thread that ran them "
                "(`step_compute_cpu_ms`: the step's own work; the wall time above also holds the "
                "slices the operating system gave other processes):", "",
                "| method | median [ms] | p99 | p99.9 | max | steps > "
                f"{report['bound_ms']:.0f} ms |",
                "|---|" + "---:|" * 5]
        out += [f"| {name} | {c['median_ms']:.3f} | {c['p99_ms']:.2f} | {c['p99_9_ms']:.2f} | "
                f"{c['max_ms']:.2f} | {c['over_bound']} |" for name, c in cpu.items()]
    return out


def _episode_line(ref: dict) -> str:
    """The reference's in-episode figure, in words for the report."""
    episode = ref.get("reference_episode") or {}
    if ref.get("reference_episode_median_ms") is None:
        why = ref.get("reference_episode_note") or "not measured"
        return f"the reference driving the robot in PyBullet not timed ({why})"
    return (f"the reference driving the robot in PyBullet (its own episode of "
            f"{episode.get('steps')} periods, each call timed between the physics steps, as "
            f"our steps are) {ref['reference_episode_median_ms']:.3f} ms median, max "
            f"{episode.get('max_ms', float('nan')):.2f} ms, the hand "
            f"{episode.get('ee_distance_end_m', float('nan')):.3f} m from the goal at its end")


def markdown_section(report: dict) -> str:
    """The "## Controller step in episodes" section of BENCHMARKS.md."""
    from tamedpuma.app.bench_fabrics import code_line

    load = report["machine"].get("load_average_1min")
    return "\n".join([f"## {SECTION}", "", f"Regenerated by `{report.get('command', COMMAND)}` "
                      "(figures: `benchmarks/steps.json`).", "", *lines(report), "",
                      f"Machine: {report['machine']['cpu_model']}, load average {load} at the "
                      "start (a shared machine inflates the tail: compare the ratios).", "",
                      code_line(report["machine"]), ""])


def write(report: dict, root: Path) -> Path:
    """``root``/benchmarks/steps.json and its section of ``root``/BENCHMARKS.md."""
    from tamedpuma.app.bench_fabrics import update_markdown

    out = Path(root) / "benchmarks" / "steps.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    update_markdown(Path(root) / "BENCHMARKS.md", markdown_section(report), SECTION)
    return out
