"""Whose is a slow step: the controller's, or the machine's? ``python -m tamedpuma.recheck DIR``.

A step over the bound (10 ms, :data:`~tamedpuma.analysis.summaries.BOUND_MS`) in a sweep's
``summary.json`` is either work the controller did at that state (a search, a fallback, a
compile) or time the machine took from it: another process on the core (the wall time grows,
the thread's CPU time does not), and on a virtual machine the hypervisor holding the virtual CPU,
which the guest counts as the running thread's CPU time as well. Both times alone cannot tell the
two apart; running the step again can. A run is deterministic for its config and seed (the same
states, step for step), so each run holding a step over the bound is run again ``repeats`` times
from its own overrides (``.hydra/overrides.yaml``, without recorders) and every such step is
judged on the least of its times over the sweep and the re-runs [ms]:

- *reproduced* (the controller's): the step is over the bound in every run of it;
- *not reproduced* (the machine's): at least one run of the same step at the same state keeps
  the bound.

A re-run that is not the same run (another step count, or another final state: the hand's final
position and orientation errors and the least clearance, to the bit: code or a model changed
since; a model retrained to the same weights gives the same run) is reported as not comparable.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import yaml

from tamedpuma.analysis.runs import set_aside
from tamedpuma.analysis.summaries import BOUND_MS
from tamedpuma.app.bench_steps import run_summary
from tamedpuma.app.cli import fail
from tamedpuma.errors import LogError, TamedPumaError
from tamedpuma.runlog import upgrade_summary

#: the methods whose steps the bound is asked of (Modulation-IK's optimisation is reported only)
BOUNDED = ("puma", "fabrics", "fpm", "cpm")
#: the summary's fields a re-run must repeat to the bit to be the same run (with the step count)
SAME_RUN = ("final_position_error_m", "final_orientation_error_rad", "min_clearance_m")


@dataclass(frozen=True)
class SlowRun:
    """A run with steps over the bound: its folder, method, step count, final state
    (:data:`SAME_RUN`) and, per slow step, its index and wall and CPU time [ms]."""

    run_dir: str
    method: str
    steps: int
    final: tuple
    slow: tuple[tuple[int, float, float], ...]


@dataclass(frozen=True)
class Verdict:
    """One slow step judged: its run, index, the sweep's wall and CPU time [ms], the least over
    the sweep and the re-runs (wall, CPU [ms]) and whether it reproduced (None: not comparable,
    with the reason)."""

    run_dir: str
    method: str
    step: int
    wall_ms: float
    cpu_ms: float
    least_wall_ms: float | None
    least_cpu_ms: float | None
    reproduced: bool | None
    why: str = ""


def slow_runs(root: Path, bound: float = BOUND_MS, methods=BOUNDED) -> list[SlowRun]:
    """The complete runs below ``root`` of ``methods`` (all: None) with a step over ``bound``."""
    found = []
    for path in sorted(root.rglob("summary.json")):
        if set_aside(path):
            continue
        try:
            s = upgrade_summary(json.loads(path.read_text()))
        except (OSError, ValueError, LogError):
            continue  # an unreadable summary is the analysis's to report
        if s.get("status") != "complete" or (methods and s.get("method") not in methods):
            continue
        wall, cpu = s.get("step_compute_ms") or [], s.get("step_compute_cpu_ms") or []
        slow = tuple((k, float(w), float(cpu[k]) if k < len(cpu) else float("nan"))
                     for k, w in enumerate(wall) if w > bound)
        if slow:
            found.append(SlowRun(str(path.parent), s.get("method", "?"), len(wall),
                                 tuple(s.get(k) for k in SAME_RUN), slow))
    return found


def rerun_overrides(run_dir: Path) -> list[str]:
    """The run's own overrides (``.hydra/overrides.yaml``) less where it wrote and Hydra's."""
    path = run_dir / ".hydra" / "overrides.yaml"
    try:
        lines = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise TamedPumaError(f"cannot re-run {run_dir}: {path} unreadable ({exc})") from exc
    return [str(o) for o in lines or ()
            if not str(o).startswith(("output_root=", "hydra.", "recorder="))]


def judge(run: SlowRun, reruns: list[dict], bound: float) -> list[Verdict]:
    """Each slow step of ``run`` on the least of its times over the sweep and ``reruns``."""
    for again in reruns:
        why = ""
        if len(again.get("step_compute_ms", ())) != run.steps:
            why = (f"the re-run took {len(again.get('step_compute_ms', ()))} steps, the "
                   f"sweep's {run.steps}")
        elif tuple(again.get(k) for k in SAME_RUN) != run.final:
            why = "the re-run ends in another state (code or model changed since?)"
        if why:
            return [Verdict(run.run_dir, run.method, k, w, c, None, None, None, why)
                    for k, w, c in run.slow]
    out = []
    for k, w, c in run.slow:
        walls = [w, *(float(a["step_compute_ms"][k]) for a in reruns)]
        cpus = [c, *(float(a["step_compute_cpu_ms"][k]) for a in reruns)]
        out.append(Verdict(run.run_dir, run.method, k, w, c, min(walls), min(cpus),
                           min(walls) > bound))
    return out


def line(v: Verdict, root: Path) -> str:
    """One verdict as a line of the report."""
    where = f"{Path(v.run_dir).relative_to(root)} step {v.step}"
    seen = f"{v.wall_ms:.2f} ms (CPU {v.cpu_ms:.2f})"
    if v.reproduced is None:
        return f"{where}: {seen}; not comparable: {v.why}"
    whose = "the controller's (reproduced)" if v.reproduced else "the machine's (not reproduced)"
    return (f"{where}: {seen} in the sweep, at least {v.least_wall_ms:.2f} ms "
            f"(CPU {v.least_cpu_ms:.2f}) over it and the re-runs: {whose}")


def recheck(root: Path, bound: float, repeats: int, methods) -> list[Verdict]:
    """Every slow step below ``root`` judged after ``repeats`` re-runs of its run."""
    verdicts = []
    for run in slow_runs(root, bound, methods):
        overrides = rerun_overrides(Path(run.run_dir))
        reruns = [run_summary(overrides) for _ in range(repeats)]
        verdicts += judge(run, reruns, bound)
    return verdicts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tamedpuma.recheck",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="a sweep folder (its runs' summary.json)")
    parser.add_argument("--bound", type=float, default=BOUND_MS, help="[ms] (default 10)")
    parser.add_argument("--repeats", type=int, default=2, help="re-runs of each run (default 2)")
    parser.add_argument("--methods", nargs="*", default=list(BOUNDED),
                        help="the methods to check (default: puma fabrics fpm cpm; none: all)")
    parser.add_argument("--json", type=Path, default=None, help="also write the verdicts here")
    args = parser.parse_args(argv)
    if not args.root.is_dir():
        fail(f"{args.root} is not a folder")
    if args.repeats < 1 or not args.bound > 0:
        fail("--repeats must be >= 1 and --bound > 0")
    try:
        verdicts = recheck(args.root, args.bound, args.repeats, tuple(args.methods))
    except TamedPumaError as exc:
        fail(str(exc))
    for v in verdicts:
        print(line(v, args.root))
    mine = sum(v.reproduced is True for v in verdicts)
    print(f"{len(verdicts)} step(s) over {args.bound:g} ms; {mine} reproduced (the controller's), "
          f"{sum(v.reproduced is False for v in verdicts)} not (the machine's), "
          f"{sum(v.reproduced is None for v in verdicts)} not comparable")
    if args.json is not None:
        args.json.write_text(json.dumps([asdict(v) for v in verdicts], indent=1))
    return 1 if mine else 0
