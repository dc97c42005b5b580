"""Run methods on a suite of scenarios and classify every outcome (the failure classes and the
safety signals that tell a flailing, stalled or unsafe run apart).

    python -m tamedpuma.safety_suite --tasks tomato pouring --kinds near_table1 anywhere \\
        --seeds 1000-1049 --methods puma fpm cpm --jobs 2 \\
        --out runs/random_suite/eval.csv [--models DIR] [--set method.some_key=value ...]
    python -m tamedpuma.safety_suite --kinds table1 --seeds 0-14 ...   # the 30 Table-1 scenarios

Each run is the sweep's ``scenario=random scenario.random_seed=S scenario.start_kind=K
method=M recorder=none`` (``scenario=<task>/<S>`` for ``--kinds table1``; plus ``--set``
overrides, and with ``--models DIR`` ``method.checkpoint=DIR/<task>/puma.pt``), composed by Hydra
and run in-process (no files per run); one CSV row per run (columns:
:mod:`tamedpuma.analysis.safety`):

- ``success_paper``, ``success_whole_body``, ``failure``: the criteria and the failure class;
- ``alpha_max`` [1/s], ``speed_ratio_max``, ``clamp_frac``, ``min_clearance``,
  ``min_ground_clearance``, ``min_mesh_ground_clearance`` [m], ``max_error`` [m],
  ``path_length`` [m]: the signals of a flailing or unsafe arm;
- ``success_orientation_paper`` / ``_whole_body``: the criterion's success with the goal
  orientation also held ``--settle`` seconds after the first reach (:mod:`tamedpuma.metrics`,
  the sweep's rule with ``settle_time``); ``settled_orientation_error`` [rad] there.

Prints a summary per (task, kind, method).
"""

from __future__ import annotations

import argparse
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np
import pandas as pd

from tamedpuma.analysis.safety import Trace, classify, signals, split_by_puma_limits, summarise
from tamedpuma.robot.ground import hull_heights_from_poses

#: the per-step signals the tracker keeps, in the order of :class:`Trace`'s fields
FIELDS = ("t", "error", "clearance", "contact", "ground", "alpha", "speed_ratio",
          "command_ratio", "speed", "sphere_ground", "orientation_error", "mesh_ground")


class Tracker:
    """A recorder that keeps what the classification needs, per step."""

    def __init__(self, dt, qd_max, radii, hulls=None, link_names=()):
        self.dt, self.qd_max, self.radii = dt, np.asarray(qd_max), np.asarray(radii)
        self.hulls, self.link_names = hulls, link_names
        self.rows = []

    def open(self, info):
        self.rows = []

    def write(self, rec):
        s = rec.scalars
        cmd = np.abs(rec.qd + rec.qdd_cmd * self.dt) / self.qd_max
        self.rows.append((rec.t, s["position_error_m"], s["clearance_m"], s["obstacle_contact"],
                          s["ground_contact"], abs(s.get("alpha", 0.0)),
                          float(np.max(np.abs(rec.qd) / self.qd_max)), float(cmd.max()),
                          float(np.linalg.norm(rec.qd)),
                          float(np.min(rec.body_sphere_centers[:, 2] - self.radii)),
                          s["orientation_error_rad"], self._lowest_mesh_point(rec)))

    def _lowest_mesh_point(self, rec) -> float:
        if self.hulls is None:
            return np.inf
        return float(np.min(hull_heights_from_poses(self.hulls, self.link_names,
                                                    rec.link_positions, rec.link_quaternions)))

    def close(self, complete, summary):
        pass

    def trace(self, q: np.ndarray) -> Trace:
        """The kept signals as a :class:`Trace` (``q``: the episode's joint positions)."""
        a = np.array(self.rows, dtype=float)
        columns = {name: a[:, i] for i, name in enumerate(FIELDS)}
        columns["contact"], columns["ground"] = columns["contact"] > 0, columns["ground"] > 0
        return Trace(**columns, q=np.asarray(q))


def model_path(models: str, task: str, method: str) -> str:
    """The checkpoint in the ``--models`` folder a method uses: ``<task>_position/puma.pt``
    (the first-order model) for Modulation-IK, ``<task>/puma.pt`` for the others."""
    folder = f"{task}_position" if method == "modulation_ik" else task
    return f"{models}/{folder}/puma.pt"


def overrides(spec: dict) -> list[str]:
    """The sweep overrides of one run of the suite."""
    task, kind, seed, method = spec["task"], spec["kind"], spec["seed"], spec["method"]
    if kind == "table1":  # seed = the Table-1 scenario number
        out = [f"task={task}", f"scenario={task}/{seed:02d}"]
    else:
        out = [f"task={task}", "scenario=random", f"scenario.random_seed={seed}",
               f"scenario.start_kind={kind}"]
    return [*out, f"method={method}", "recorder=none", *spec["set"],
            f"without_obstacles={spec.get('free', False)}"]


def build_run(spec: dict):
    """The sweep's build of one run (with ``--models``: the method's checkpoint there)."""
    from omegaconf import OmegaConf

    from tamedpuma.app.compose import compose_dict
    from tamedpuma.app.sweep import build

    cfg = OmegaConf.create(compose_dict("sweep", overrides(spec)))
    if spec["models"] and "checkpoint" in cfg.method:  # Fabrics has no model
        cfg.method.checkpoint = model_path(spec["models"], spec["task"], str(cfg.method.name))
    return build(cfg)


def save_path(spec: dict, ee_position: np.ndarray) -> None:
    """``--paths``: the run's end-effector path as .npy."""
    out = Path(spec["paths"])
    out.mkdir(parents=True, exist_ok=True)
    name = (f"{spec['task']}_{spec['kind']}_{spec['seed']}_{spec['label']}_"
            f"{int(spec.get('free', False))}.npy")
    np.save(out / name, ee_position)


def run_one(spec: dict) -> dict:
    """One run of the suite: its CSV row."""
    from tamedpuma.episode import run_episode
    from tamedpuma.robot.ground import link_hulls
    from tamedpuma.robot.kinematics import Kinematics
    from tamedpuma.worlds.bullet import Simulator

    built = build_run(spec)
    sc, robot = built.scenario, built.spec
    tracker = Tracker(sc.dt, robot.qd_max, robot.sphere_radii,
                      link_hulls(Kinematics(robot)), robot.link_names)
    start = time.perf_counter()
    with Simulator(robot, built.sim_config) as sim:
        result = run_episode(sc, built.controller, sim, [tracker], None, stop_on_success=True,
                             settle_time=spec.get("settle", 0.0))
    wall = time.perf_counter() - start
    if spec.get("paths"):
        save_path(spec, result.ee_position)
    trace = tracker.trace(result.q)
    outcome = classify(trace, sc.goal_tolerance, sc.dt, robot.q_min, robot.q_max)
    m = result.metrics
    return {"task": spec["task"], "kind": spec["kind"], "seed": spec["seed"],
            "method": spec["method"], "label": spec["label"],
            "success_paper": outcome.paper, "success_whole_body": outcome.whole_body,
            "failure": outcome.failure,
            **signals(trace, outcome, result.ee_position, robot.q_min, robot.q_max),
            "wall_s": wall, "settled_orientation_error": m.settled_orientation_error_rad,
            "success_orientation_paper": bool(m.orientation_success_paper),
            "success_orientation_whole_body": bool(outcome.whole_body
                                                   and m.orientation_success_whole_body),
            "ms_mean": float(m.compute_ms_mean)}


def seeds(text: str) -> list[int]:
    """``"1000-1002,7"`` -> [1000, 1001, 1002, 7] (ValueError for anything else)."""
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi) + 1) if hi else [int(lo)])
    return out


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m tamedpuma.safety_suite",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=["tomato", "pouring"])
    ap.add_argument("--kinds", nargs="+", default=["near_table1", "anywhere"],
                    help="start kinds of the random scenarios, or table1")
    ap.add_argument("--seeds", default="1000-1049", help="e.g. 1000-1049 or 0-14,20")
    ap.add_argument("--methods", nargs="+", default=["puma", "fpm", "cpm"])
    ap.add_argument("--models", default="", help="folder of <task>/puma.pt and, for "
                    "Modulation-IK, <task>_position/puma.pt (default: each method config's "
                    "checkpoint; methods without a model, Fabrics, ignore it)")
    ap.add_argument("--set", nargs="*", default=[], help="extra Hydra overrides for every run")
    ap.add_argument("--label", default=None, help="label of this configuration in the table")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--free", action="store_true", help="without obstacles (path differences)")
    ap.add_argument("--paths", default="", help="save every run's end-effector path (.npy) here")
    ap.add_argument("--settle", type=float, default=0.0, help="[s] continue this long after the "
                    "first reach and judge the orientation then (the sweep's settle_time; 0: stop "
                    "at the reach and judge the orientation there)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--puma-free", default="", help="a CSV of this suite with --methods puma "
                    "--free on the same scenarios: also print success split by whether PUMA's "
                    "own obstacle-free run drove a joint past its limit")
    return ap


def read_puma_free(ap, path: str) -> pd.DataFrame | None:
    """``--puma-free``, read before the runs: a bad file is a one-line error, not lost work."""
    if not path:
        return None
    try:
        puma_free = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        ap.error(f"--puma-free {path}: {' '.join(str(exc).split())}")
    missing = {"task", "kind", "seed", "method", "limit_steps"} - set(puma_free.columns)
    if missing:
        ap.error(f"--puma-free {path}: not a safety_suite CSV (no column "
                 f"{', '.join(sorted(missing))})")
    return puma_free


def specs(args, seed_list: list[int]) -> list[dict]:
    """One spec per (task, kind, method, seed)."""
    label = (lambda m: f"{m}:{args.label}") if args.label else (lambda m: m)
    return [{"task": t, "kind": k, "seed": s, "method": m, "models": args.models,
             "set": args.set, "label": label(m), "free": args.free, "paths": args.paths,
             "settle": args.settle}
            for t in args.tasks for k in args.kinds for m in args.methods for s in seed_list]


def run_all(todo: list[dict], jobs: int, out: Path) -> pd.DataFrame:
    """Every run, ``jobs`` at a time; each finished row appended to ``<out>.partial.csv``."""
    rows = []
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_suffix(".partial.csv")
    with Pool(jobs) as pool:
        for i, row in enumerate(pool.imap_unordered(run_one, todo), 1):
            rows.append(row)
            pd.DataFrame([row]).to_csv(partial, mode="a", header=i == 1, index=False)
            if i % 20 == 0:
                print(f"{i}/{len(todo)} runs", flush=True)
    df = pd.DataFrame(rows).sort_values(["task", "kind", "label", "seed"])
    df.to_csv(out, index=False)
    partial.unlink(missing_ok=True)
    return df


def report(df: pd.DataFrame, puma_free: pd.DataFrame | None) -> None:
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(summarise(df))
        if puma_free is not None:
            print("success where PUMA's own obstacle-free run keeps every joint inside its "
                  "limits (False) or drives one past it (True):")
            try:
                print(split_by_puma_limits(df, puma_free))
            except ValueError as exc:
                print(f"--puma-free: {exc}")


def main(argv=None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    try:
        seed_list = seeds(args.seeds)
    except ValueError:
        ap.error(f"--seeds {args.seeds}: not a list of seeds and ranges (e.g. 1000-1049,7)")
    if args.jobs < 1:
        ap.error("--jobs must be ≥ 1")
    puma_free = read_puma_free(ap, args.puma_free)
    out = Path(args.out)
    report(run_all(specs(args, seed_list), args.jobs, out), puma_free)
    print(f"wrote {out}")
    return 0
