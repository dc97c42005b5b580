"""``python -m tamedpuma.app.goal_reach RUNS``: which scenarios of a sweep have a goal pose the
arm can hold clear of the obstacles, and each method's convergence on those and on the others.

Every run folder under RUNS with a ``summary.json`` and Hydra's ``.hydra/config.yaml`` gives its
scenario again (built from that config as the run built it, without the controller); each
distinct scenario (task, name, number of obstacles) is judged once by
:func:`~tamedpuma.analysis.goal_reach.goal_pose_gap`. Writes ``goal_reach.csv`` into RUNS (one
row per scenario: task, scenario, number of obstacles, gap [m], verdict) and prints per method
the runs converged under the paper's criterion on the scenarios whose goal pose is clear,
blocked, or without an IK solution found (:data:`~tamedpuma.analysis.goal_reach.VERDICTS`).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

from tamedpuma.analysis.goal_reach import (
    SOLUTIONS,
    VERDICTS,
    goal_pose_gap,
    reach_table,
    scenario_key,
    verdict,
)
from tamedpuma.errors import TamedPumaError


def _runs(root: Path) -> list[tuple[Path, dict]]:
    """(run folder, summary) of every complete run under root with its Hydra config."""
    found = []
    for path in sorted(root.rglob("summary.json")):
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if summary.get("status") == "complete" and (path.parent / ".hydra/config.yaml").is_file():
            found.append((path.parent, summary))
    return found


def scenario_gaps(runs: list[tuple[Path, dict]], count: int = SOLUTIONS) -> dict:
    """:func:`~tamedpuma.analysis.goal_reach.scenario_key` -> the goal-pose gap [m] (None: no IK
    solution) of each distinct scenario of ``runs``."""
    from omegaconf import OmegaConf

    from tamedpuma.app.sweep import world_of

    gaps: dict = {}
    for folder, summary in runs:
        key = scenario_key(summary)
        if key in gaps:
            continue
        _, kinematics, scenario = world_of(OmegaConf.load(folder / ".hydra" / "config.yaml"))
        gaps[key] = goal_pose_gap(kinematics, scenario.goal.position, scenario.goal.quaternion,
                                  scenario.obstacles.centers, scenario.obstacles.radii,
                                  count=count, q0=scenario.q0)
    return gaps


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tamedpuma.app.goal_reach",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", type=Path, help="a sweep's output folder")
    parser.add_argument("--solutions", type=int, default=SOLUTIONS,
                        help=f"seeded pose IK solutions tried per goal ({SOLUTIONS})")
    args = parser.parse_args(argv)
    if not args.runs.is_dir():
        print(f"error: {args.runs} is not a folder", file=sys.stderr)
        return 2
    runs = _runs(args.runs)
    if not runs:
        print(f"error: no complete run with its .hydra/config.yaml under {args.runs}",
              file=sys.stderr)
        return 2
    try:
        gaps = scenario_gaps(runs, args.solutions)
    except TamedPumaError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = args.runs / "goal_reach.csv"
    with out.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["task", "scenario", "n_obstacles", "gap_m", "verdict"])
        for (task, scenario, n), gap in sorted(gaps.items()):
            writer.writerow([task, scenario, n, "" if gap is None else f"{gap:.4f}",
                             verdict(gap)])
    counts = {v: sum(1 for g in gaps.values() if verdict(g) == v) for v in VERDICTS}
    print(f"{len(gaps)} scenarios: goal pose clear {counts['clear']}, blocked (every IK "
          f"solution found inside an obstacle) {counts['blocked']}, no IK solution above the "
          f"ground found {counts['unsolved']} ({out})")
    print("| method | converged: goal pose clear | blocked | no solution found |")
    print("|---|---|---|---|")
    for row in reach_table([s for _, s in runs], gaps):
        cells = [f"{row[f'{v}_converged']} / {row[f'{v}_runs']}" for v in VERDICTS]
        print(f"| {row['method']} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
