"""``python -m tamedpuma.bench``: the project's benchmarks in one command, written to files.

Sections (each regenerated, never typed in):

1. **Controller step** of every method at 2, 10, 100 and 1000 obstacles on prepared states
   (:mod:`tamedpuma.app.bench_timing`): the wall time of one whole ``controller.step(obs)`` on
   fixed states near the default tomato start, each method built exactly as ``tamedpuma.sweep``
   builds it. Median, p10, p90 [ms]; the first call at each count apart. Where the step's time
   goes, part by part (:mod:`tamedpuma.app.bench_parts`). With ``--baseline DIR`` the same cells
   are also timed in another checkout DIR (e.g. made with ``git worktree add DIR REV``), by its
   own code in a worker process, blocks of 100 calls alternating between the two
   (:mod:`tamedpuma.app.bench_workers`), so "before" and "after" share the machine's load.
2. **Controller step in episodes** (:mod:`tamedpuma.app.bench_steps`): every step of whole
   episodes of each method (Table-1 scenarios and randomized-suite scenarios) as their
   ``summary.json`` records it: median, p99, p99.9, max and the steps over the control period,
   beside the reference ``fabrics`` planner timed in the same run (``--reference-python``).
3. **Episode speed**: one FPM episode of the default scenario through the sweep's own
   ``run_one`` with each recorder setting: simulated seconds per wall second, and each
   recorder's overhead against ``recorder=none``.
4. **Fabrics**: the vanilla fabric at 2-1000 obstacles against the reference ``fabrics``
   planner, live where a Python with it is given, its dated figures cited otherwise
   (:mod:`tamedpuma.app.bench_fabrics`; ``--skip-fabrics`` leaves the section as it is).
5. **PUMA training**, the **Table-1 sweep** and the **randomized suite**: measured only on
   request (``--training``, ``--table1 [N]``, ``--suite [N]``: minutes each, the sweeps N times;
   :mod:`tamedpuma.app.bench_runs`, :mod:`tamedpuma.app.bench_sweeps`), with the longest step of
   every run they hold. ``--sweeps`` measures the sweeps alone and merges them into the saved
   ``benchmarks/bench.json``.

    python -m tamedpuma.bench                       # sections 1-4, writes the files below
    python -m tamedpuma.bench --methods fpm cpm --counts 2 1000 --skip-fabrics --no-write
    python -m tamedpuma.bench --steps --steps-table1 15 --steps-seeds 2000 2001  # episodes only
    python -m tamedpuma.bench --baseline /tmp/before   # also time another checkout, side by side
    python -m tamedpuma.bench --training --training-seeds 0 1 2 --table1   # everything
    python -m tamedpuma.bench --sweeps --table1 3 --suite 1   # the sweeps alone, into bench.json

Writes ``benchmarks/bench.json`` (every figure, machine, load averages at start and end),
``benchmarks/steps.json`` and ``benchmarks/fabrics.json``, and the "## Controller step",
"## Controller step in episodes" and "## Fabrics" sections of ``BENCHMARKS.md`` (other sections
are kept). It edits no other file.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from tamedpuma.app import bench_fabrics, bench_report, bench_runs, bench_steps, bench_sweeps
from tamedpuma.app.bench_baseline import (
    BaselineError,
    attach_baseline,
    baseline_tree,
    describe,
)
from tamedpuma.app.bench_fabrics import ROOT, machine_info, update_markdown
from tamedpuma.app.bench_parts import time_parts
from tamedpuma.app.bench_report import SECTION, TARGET_MS
from tamedpuma.app.bench_timing import time_controller
from tamedpuma.app.bench_workers import time_episodes, time_side_by_side
from tamedpuma.paths import CHECKOUT_ROOT

COUNTS = (2, 10, 100, 1000)
METHODS = ("puma", "fabrics", "fabrics+numpy", "fpm", "fpm+numpy", "cpm", "modulation_ik")
PARTS = ("fabrics", "fabrics+numpy", "puma", "fpm", "fpm+numpy", "cpm", "modulation_ik")


def load_averages() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (None where the OS has none)."""
    return [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else None


def one_line(exc: BaseException) -> str:
    """An exception as one line (Hydra's search path listing cut off)."""
    return " ".join(str(exc).split("Config search path")[0].split()) or type(exc).__name__


def report_from_stdout(text: str) -> dict:
    """The JSON report a ``--no-write`` bench run prints (the last top-level object)."""
    start = text.rfind("\n{\n") + 1  # 0 when the report is all there is
    return json.loads(text[start:text.rindex("}") + 1])


def render(root: Path, write: bool = True) -> int:
    """Rewrite the sections from the saved reports (``--render``); with ``write`` False
    (``--no-write``) print them instead."""
    try:
        report = json.loads((root / "benchmarks" / "bench.json").read_text())
        fabrics = json.loads((root / "benchmarks" / "fabrics.json").read_text())
    except (OSError, ValueError) as exc:
        print(f"error: --render needs the saved reports: {one_line(exc)}", file=sys.stderr)
        return 2
    sections = [(bench_report.markdown_section(report), SECTION)]
    steps = root / "benchmarks" / "steps.json"
    if steps.is_file():
        sections.append((bench_steps.markdown_section(json.loads(steps.read_text())),
                         bench_steps.SECTION))
    if not write:
        print("\n\n".join([text for text, _ in sections]
                           + [bench_fabrics.markdown_section(fabrics)]))
        return 0
    for text, section in sections:
        update_markdown(root / "BENCHMARKS.md", text, section)
    bench_fabrics.write(fabrics, root)
    print(f"rewrote {root / 'BENCHMARKS.md'} from benchmarks/*.json", file=sys.stderr)
    return 0


def run_steps(args, command: str) -> dict | None:
    """The in-episode section (None when it has no scenarios)."""
    if not args.steps_table1 and not args.steps_seeds:
        return None
    methods = [m for m in args.methods if "+" not in m]
    report = bench_steps.run(methods, args.steps_table1, args.steps_seeds,
                             args.reference_python, args.overrides,
                             log=lambda line: print(line, file=sys.stderr))
    report["command"] = command
    return report


def steps_only(args, command: str) -> int:
    """``--steps``: the in-episode section alone."""
    try:
        report = run_steps(args, command)
    except Exception as exc:  # as in run(): one line, not a traceback
        print(f"error: {one_line(exc)}", file=sys.stderr)
        return 2
    if report is None:
        print("error: --steps needs --steps-table1 ≥ 1 or --steps-seeds", file=sys.stderr)
        return 2
    print("\n".join(bench_steps.lines(report)))
    if not args.no_write:
        print(f"wrote {bench_steps.write(report, args.root)}", file=sys.stderr)
    return 0


def new_report(args, command: str) -> dict:
    """The report's frame: date, machine (with numba's version where installed), command."""
    from tamedpuma.fabrics import compiled

    machine = machine_info()
    if compiled.AVAILABLE:  # the optional fast extra (the compiled fabric and kinematics)
        from importlib.metadata import version

        machine["numba"] = version("numba")
    machine["load_averages_start"] = load_averages()
    return {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "controller": [],
            "errors": [], "machine": machine, "overrides": args.overrides, "command": command}


def controller_cells(args, report: dict, before_tree: Path | None) -> None:
    """Section 1's cells of every method, side by side with the baseline where given."""
    for method in args.methods:
        rows, before = [], []
        try:
            if before_tree is not None:
                sides = time_side_by_side(method, args.counts, args.calls, args.budget,
                                          {"now": CHECKOUT_ROOT, "before": before_tree},
                                          args.overrides)
                rows, before = sides["now"], sides["before"]
            else:
                rows = time_controller(method, args.counts, args.calls, args.budget,
                                       args.overrides)
        except Exception as exc:  # a missing model; Hydra's errors; a failing worker
            report["errors"].append({"method": method, "error": one_line(exc)})
        attach_baseline(rows, before)
        report["controller"] += rows
        print(f"bench: {method} done", file=sys.stderr)


def step_parts(args, report: dict) -> None:
    """Section 1's parts: each method at 2 obstacles and at the counts of its targets."""
    report["parts"] = []
    for method, n in [(m, n) for m in args.parts for n in args.parts_counts
                      if n == 2 or (m, n) in TARGET_MS]:
        try:
            report["parts"] += time_parts(method, n, overrides=args.overrides)
        except Exception as exc:  # as above
            report["errors"].append({"method": f"{method} (parts)", "error": one_line(exc)})


def episodes(args, report: dict, before_tree: Path | None) -> None:
    """Section 3: episode speed per recorder setting."""
    if args.episodes <= 0:
        return
    trees = {"now": CHECKOUT_ROOT, **({"before": before_tree} if before_tree else {})}
    try:
        report["episodes"] = time_episodes("fpm", args.episodes, args.overrides, trees)
    except Exception as exc:  # a missing model, a composition error: reported
        report["errors"].append({"method": "episode", "error": one_line(exc)})


def optional_sections(args, report: dict) -> dict | None:
    """Sections 4 and 5 where asked for; the fabrics report (None with --skip-fabrics)."""
    fabrics = None
    if not args.skip_fabrics:  # our fabric and the reference planner
        fabrics = bench_fabrics.run(calls=args.calls, reference_python=args.reference_python)
        fabrics["command"] = report["command"]
        report["fabrics"] = {k: fabrics[k] for k in ("results", "reference_live",
                                                      "reference_note")}
    if args.training:
        report["training"] = bench_runs.time_training(seeds=args.training_seeds)
        report["training_measured_by"] = f"`{report['command']}` ({report['date']})"
    time_sweeps(args, report)
    return fabrics


def time_sweeps(args, report: dict) -> None:
    """The sweeps asked for (``--table1 N``, ``--suite N``), each timed N times."""
    for key, repeats in (("table1", args.table1), ("suite", args.suite)):
        if repeats:
            report[key] = bench_sweeps.time_sweep(key, report["machine"]["cores"] or 1, repeats)
            print(f"bench: {key} done", file=sys.stderr)


def sweeps_only(args, command: str) -> int:
    """``--sweeps``: the sweeps alone, merged into the saved ``benchmarks/bench.json`` (its
    other sections kept), then the sections rendered."""
    if not args.table1 and not args.suite:
        print("error: --sweeps needs --table1 N or --suite N", file=sys.stderr)
        return 2
    saved = args.root / "benchmarks" / "bench.json"
    try:
        report = json.loads(saved.read_text())
    except (OSError, ValueError) as exc:
        print(f"error: --sweeps merges into the saved report: {one_line(exc)}", file=sys.stderr)
        return 2
    fresh = new_report(args, command)
    time_sweeps(args, fresh)
    finish(fresh, args)
    m = fresh["machine"]
    for key in ("table1", "suite"):
        if key in fresh:
            fresh[key]["measured_by"] = (
                f"`{command}` ({fresh['date']}; {m.get('cpu_model')}, load average "
                f"{m.get('load_averages_start')} at the start, {m.get('load_averages_end')} "
                "at the end)")
            report[key] = fresh[key]
    print(json.dumps({k: report.get(k) for k in ("table1", "suite")}, indent=2))
    if args.no_write:
        return 0
    saved.write_text(json.dumps(report, indent=2) + "\n")
    return render(args.root)


def finish(report: dict, args) -> None:
    """Models and the closing load averages."""
    models = [r["model"] for r in report["controller"] if r.get("model")]
    if models:
        report["models"] = ", ".join(dict.fromkeys(models))
    machine = report["machine"]
    machine["load_averages_end"] = load_averages()
    machine["load_average_1min_end"] = (machine["load_averages_end"] or [None])[0]


def write(report: dict, steps: dict | None, fabrics: dict | None, root: Path) -> None:
    """benchmarks/*.json and their BENCHMARKS.md sections."""
    out = root / "benchmarks" / "bench.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    update_markdown(root / "BENCHMARKS.md", bench_report.markdown_section(report), SECTION)
    if steps is not None:
        bench_steps.write(steps, root)
    if fabrics is not None:
        bench_fabrics.write(fabrics, root)
    print(f"wrote {out} and {root / 'BENCHMARKS.md'}", file=sys.stderr)


def run(args, command: str) -> int:
    """Every section asked for, then the files (unless ``--no-write``)."""
    try:
        before = baseline_tree(args.baseline) if args.baseline else None
    except BaselineError as exc:
        print(f"error: --baseline {exc}", file=sys.stderr)
        return 2
    report = new_report(args, command)
    if before is not None:
        report["baseline"] = report["episode_baseline"] = describe(before)
    controller_cells(args, report, before)
    step_parts(args, report)
    try:
        steps = run_steps(args, command)
    except Exception as exc:  # a composition error of the overrides, a missing model
        report["errors"].append({"method": "in episodes", "error": one_line(exc)})
        steps = None
    if steps is not None:
        report["steps"] = {"methods": steps["methods"], "reference": steps["reference"],
                           "cases": steps["cases"]}
    episodes(args, report, before)
    fabrics = optional_sections(args, report)
    finish(report, args)
    print(json.dumps(report, indent=2))
    if not args.no_write:
        write(report, steps, fabrics, args.root)
    return 0


def _measure_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--methods", nargs="+", default=list(METHODS))
    parser.add_argument("--counts", type=int, nargs="+", default=list(COUNTS))
    parser.add_argument("--calls", type=int, default=2000, help="timed calls per cell at most")
    parser.add_argument("--budget", type=float, default=10.0, help="seconds per cell at most")
    parser.add_argument("--episodes", type=int, default=3,
                        help="repeats per recorder setting (0: skip episode speed)")
    parser.add_argument("--training", action="store_true", help="also time PUMA training")
    parser.add_argument("--training-seeds", type=int, nargs="+", default=[0], metavar="SEED",
                        help="seeds of each task trained with --training")
    parser.add_argument("--table1", type=int, nargs="?", const=1, default=0, metavar="N",
                        help="also time +experiment=table1, N times (default 1)")
    parser.add_argument("--suite", type=int, nargs="?", const=1, default=0, metavar="N",
                        help="also time the randomized suite of the paper's five methods "
                        "(4,000 runs, ~30 min), N times (default 1)")
    parser.add_argument("--sweeps", action="store_true",
                        help="only the sweeps asked for (--table1, --suite), merged into the "
                        "saved benchmarks/bench.json")
    parser.add_argument("--parts", nargs="*", default=list(PARTS), metavar="METHOD",
                        help="methods whose step is broken into parts (none: skip)")
    parser.add_argument("--parts-counts", type=int, nargs="+", default=[2, 1000],
                        metavar="N", help="obstacle counts of the parts (each method: those "
                        "of its targets, and 2)")
    parser.add_argument("--steps", action="store_true",
                        help="only the step inside whole episodes (Table-1 scenarios and the "
                        "randomized suite), written to benchmarks/steps.json")
    parser.add_argument("--steps-table1", type=int, default=1, metavar="N",
                        help="the first N Table-1 scenarios of each task in the in-episode "
                        "section (0-15)")
    parser.add_argument("--steps-seeds", type=int, nargs="*", default=[2000], metavar="SEED",
                        help="randomized-suite seeds of the in-episode section (both tasks, "
                        "both starts; none with --steps-table1 0: skip the section)")


def _other_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--baseline", metavar="DIR",
                        help="also time the controller cells and the episodes in the checkout "
                        "DIR (e.g. `git worktree add DIR REV`), side by side")
    parser.add_argument("--skip-fabrics", action="store_true",
                        help="leave BENCHMARKS.md's \"Fabrics\" section (the vanilla fabric "
                        "against the reference planner) as it is")
    parser.add_argument("--reference-python", default=os.environ.get(bench_fabrics.REFERENCE_ENV)
                        or None, metavar="PATH", help="a Python with the reference `fabrics` "
                        "package: measured live (default: "
                        f"${bench_fabrics.REFERENCE_ENV}, else its dated figures are cited)")
    parser.add_argument("--render", action="store_true",
                        help="measure nothing: rewrite BENCHMARKS.md's sections from "
                        "benchmarks/*.json")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--root", type=Path, default=None,
                        help="folder to write benchmarks/ and BENCHMARKS.md into (default: "
                        f"{ROOT}: the checkout, or the current folder for an installed package)")
    parser.add_argument("overrides", nargs="*", help="config overrides for every build")


def parser() -> argparse.ArgumentParser:
    out = argparse.ArgumentParser(prog="python -m tamedpuma.bench",
                                  description=__doc__.split("\n\n")[0])
    _measure_options(out)
    _other_options(out)
    return out


def bad_arguments(args) -> str | None:
    """The one-line complaint about ``args``, None when they are usable."""
    if any(n < 0 for n in args.counts) or args.calls < 1 or args.budget <= 0:
        return "counts must be ≥ 0, calls ≥ 1 and budget > 0"
    if not 0 <= args.steps_table1 <= 15:
        return "--steps-table1 must be between 0 and 15"
    if args.table1 < 0 or args.suite < 0:
        return "--table1 and --suite take a number of repeats ≥ 0"
    return None


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser().parse_args(argv)
    args.root = args.root or ROOT
    command = "python -m tamedpuma.bench " + " ".join(argv)
    if args.render:
        return render(args.root, write=not args.no_write)
    problem = bad_arguments(args)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    if args.sweeps:
        return sweeps_only(args, command)
    return steps_only(args, command) if args.steps else run(args, command)
