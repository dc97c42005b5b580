"""Run methods on a suite of random scenarios and classify every outcome (the failure classes
and the safety signals that tell a flailing, stalled or unsafe run apart).

    python -m analysis.random_suite --tasks tomato pouring --kinds near_table1 anywhere \\
        --seeds 1000-1049 --methods puma fpm cpm --models /work/models --jobs 2 \\
        --out runs/random_suite/eval.csv [--set method.some_key=value ...]
    python -m analysis.safety_suite --kinds table1 --seeds 0-14 ...   # the 30 Table-1 scenarios

Each run is the sweep's ``scenario=random scenario.random_seed=S scenario.start_kind=K
method=M method.checkpoint=<models>/<task>/puma.pt recorder=none`` (plus ``--set`` overrides),
composed by Hydra and run in-process (no files per run); one CSV row per run:

- ``success_paper``: within the goal tolerance within the episode, no body sphere penetrating an
  obstacle sphere before (the authors' check); ``success_whole_body``: also no PyBullet
  robot-obstacle contact, no ground contact and no joint-limit violation before success;
- ``failure``: for a run failing the paper criterion, the first that applies of ``contact`` (a body
  sphere penetrated an obstacle), ``ground`` (robot-ground contact or a link's collision mesh
  below the ground; not a body sphere below it, which the spheres' inflation would make
  stricter than the contact: the hand's 7 cm sphere dips below while the flange is clear),
  ``joint_limit``, ``stall`` (at rest, ‖q̇‖ < 0.05 rad/s over the last second, short of
  the goal), ``time`` (still moving at the end); for a paper success failing the whole-body
  criterion: ``mesh`` / ``ground`` / ``joint_limit``;
- ``alpha_max``: max |α| logged by the method [1/s]; ``speed_ratio_max``: max over steps and joints
  of |q̇|/q̇_max; ``clamp_frac``: fraction of steps where the commanded ``q̇ + q̈Δt`` exceeded a
  velocity limit (the simulator's clamp acted); ``min_clearance``, ``min_ground_clearance`` (the
  body spheres'), ``min_mesh_ground_clearance`` (the links' lowest hull points) [m];
  ``max_error`` [m]: the hand's largest distance to the goal; ``path_length`` [m]: the length of
  the hand's path (a flailing arm shows in both);
- ``success_orientation_paper`` / ``_whole_body``: the criterion's success with the goal
  orientation also held (within the scenario's orientation tolerance) ``--settle`` seconds after
  the first reach, the position still within the goal tolerance (:mod:`tamedpuma.metrics`, the
  sweep's rule with ``settle_time``); ``settled_orientation_error`` [rad] there.

Prints a summary per (task, kind, method). Hydra is used here (an entry point), not in the library.
"""

from __future__ import annotations

import argparse
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np
import pandas as pd

from tamedpuma.robot.ground import hull_heights_from_poses


class _Tracker:
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


def run_one(spec: dict) -> dict:
    from omegaconf import OmegaConf

    from tamedpuma.app.sweep import build
    from tamedpuma.app.train import compose
    from tamedpuma.episode import run_episode
    from tamedpuma.robot.ground import link_hulls
    from tamedpuma.robot.kinematics import Kinematics
    from tamedpuma.worlds.bullet import Simulator

    task, kind, seed, method = spec["task"], spec["kind"], spec["seed"], spec["method"]
    if kind == "table1":  # seed = the Table-1 scenario number
        overrides = [f"task={task}", f"scenario={task}/{seed:02d}", f"method={method}",
                     "recorder=none", *spec["set"]]
    else:
        overrides = [f"task={task}", "scenario=random", f"scenario.random_seed={seed}",
                     f"scenario.start_kind={kind}", f"method={method}", "recorder=none",
                     *spec["set"]]
    overrides.append(f"without_obstacles={spec.get('free', False)}")
    cfg = OmegaConf.create(compose("sweep", overrides))
    if spec["models"] and "checkpoint" in cfg.method:  # Fabrics has no model
        cfg.method.checkpoint = model_path(spec["models"], task, str(cfg.method.name))
    built = build(cfg)
    sc, robot = built.scenario, built.spec
    tracker = _Tracker(sc.dt, robot.qd_max, robot.sphere_radii,
                       link_hulls(Kinematics(robot)), robot.link_names)
    start = time.perf_counter()
    with Simulator(robot, built.sim_config) as sim:
        result = run_episode(sc, built.controller, sim, [tracker], None, stop_on_success=True,
                             settle_time=spec.get("settle", 0.0))
    wall = time.perf_counter() - start
    if spec.get("paths"):
        out = Path(spec["paths"])
        out.mkdir(parents=True, exist_ok=True)
        np.save(out / f"{task}_{kind}_{seed}_{spec['label']}_{int(spec.get('free', False))}.npy",
                result.ee_position)
    a = np.array(tracker.rows)
    t, err, clear, contact, ground = a[:, 0], a[:, 1], a[:, 2], a[:, 3] > 0, a[:, 4] > 0
    q = result.q
    limit = np.any((q < robot.q_min - 1e-6) | (q > robot.q_max + 1e-6), axis=1)
    below = a[:, 11] < 0  # a link's mesh below the ground plane
    pen = clear < 0
    first_pen = int(np.argmax(pen)) if pen.any() else len(t)
    reached = np.flatnonzero(err[:first_pen] <= sc.goal_tolerance)
    paper = reached.size > 0
    end = int(reached[0]) + 1 if paper else len(t)
    wb_mesh, wb_ground, wb_limit = contact[:end].any(), (ground | below)[:end].any(), \
        limit[:end].any()
    whole = paper and not (wb_mesh or wb_ground or wb_limit)
    last = a[-int(1.0 / sc.dt):, 8]
    if paper:
        failure = "" if whole else ("mesh" if wb_mesh else "ground" if wb_ground else
                                    "joint_limit")
    elif pen.any():
        failure = "contact"
    elif (ground | below).any():
        failure = "ground"
    elif limit.any():
        failure = "joint_limit"
    elif np.max(last) < 0.05:
        failure = "stall"
    else:
        failure = "time"
    return {"task": task, "kind": kind, "seed": seed, "method": method,
            "label": spec["label"], "success_paper": bool(paper), "success_whole_body": bool(whole),
            "failure": failure, "time_to_success": float(t[reached[0]]) if paper else np.nan,
            "final_error": float(err[-1]), "min_error": float(err.min()),
            "max_error": float(err.max()),
            "path_length": float(np.sum(np.linalg.norm(np.diff(result.ee_position, axis=0),
                                                       axis=1))),
            "min_clearance": float(clear.min()), "min_ground_clearance": float(a[:, 9].min()),
            "min_mesh_ground_clearance": float(a[:, 11].min()),
            "mesh_contact": bool(contact.any()), "ground_contact": bool(ground.any()),
            "limit_steps": int(limit.sum()), "alpha_max": float(a[:, 5].max()),
            "speed_ratio_max": float(a[:, 6].max()), "clamp_frac": float(np.mean(a[:, 7] > 1.0)),
            "steps": len(t), "wall_s": wall,
            "end_at_limit": int(np.sum(np.minimum(q[-1] - robot.q_min, robot.q_max - q[-1])
                                       < 0.05)),
            "end_orientation_error": float(a[-1, 10]),
            "settled_orientation_error": result.metrics.settled_orientation_error_rad,
            "success_orientation_paper": bool(result.metrics.orientation_success_paper),
            "success_orientation_whole_body": bool(
                whole and result.metrics.orientation_success_whole_body),
            "ms_mean": float(result.metrics.compute_ms_mean)}


def model_path(models: str, task: str, method: str) -> str:
    """The checkpoint in the ``--models`` folder a method uses: ``<task>_position/puma.pt``
    (the first-order model) for Modulation-IK, ``<task>/puma.pt`` for the others."""
    folder = f"{task}_position" if method == "modulation_ik" else task
    return f"{models}/{folder}/puma.pt"


def _seeds(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi) + 1) if hi else [int(lo)])
    return out


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    g = df.groupby(["task", "kind", "label"])
    out = g.agg(n=("seed", "size"), paper=("success_paper", "mean"),
                whole_body=("success_whole_body", "mean"),
                oriented=("success_orientation_paper", "mean"), alpha_max=("alpha_max", "max"),
                speed_ratio_max=("speed_ratio_max", "max"), clamp_frac=("clamp_frac", "mean"))
    fails = df[df.failure != ""].groupby(["task", "kind", "label"])["failure"].agg(
        lambda s: " ".join(f"{k}:{v}" for k, v in s.value_counts().items()))
    return out.join(fails).fillna("")


def split_by_puma_limits(df: pd.DataFrame, puma_free: pd.DataFrame) -> pd.DataFrame:
    """Success per (task, kind, label), split by whether PUMA alone, on the same scenario
    without obstacles, drove a joint past its limit (``puma_free``: this script's CSV of
    ``--methods puma --free``; its ``limit_steps`` > 0). Where PUMA's own motion needs a joint
    past its limit, a method that keeps the limits can only reach the goal by another route:
    the split says how much of a method's failure rate is that."""
    puma = puma_free[puma_free.method == "puma"]
    past = puma.assign(puma_past_limit=puma.limit_steps > 0)[
        ["task", "kind", "seed", "puma_past_limit"]]
    both = df.merge(past, on=["task", "kind", "seed"], how="inner")
    if both.empty:
        raise ValueError("no scenario of the runs is in the PUMA obstacle-free CSV")
    out = both.groupby(["task", "kind", "label", "puma_past_limit"]).agg(
        n=("seed", "size"), paper=("success_paper", "mean"),
        whole_body=("success_whole_body", "mean"))
    return out.unstack("puma_past_limit")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=["tomato", "pouring"])
    ap.add_argument("--kinds", nargs="+", default=["near_table1", "anywhere"])
    ap.add_argument("--seeds", default="1000-1049")
    ap.add_argument("--methods", nargs="+", default=["puma", "fpm", "cpm"])
    ap.add_argument("--models", default="/work/models", help="folder of <task>/puma.pt and, "
                    "for Modulation-IK, <task>_position/puma.pt ('' = the method config's "
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
    ap.add_argument("--puma-free", default="", help="a CSV of this script with --methods puma "
                    "--free on the same scenarios: also print success split by whether PUMA's "
                    "own obstacle-free run drove a joint past its limit")
    args = ap.parse_args(argv)
    puma_free = None
    if args.puma_free:  # read before the runs: a bad file is a one-line error, not lost work
        try:
            puma_free = pd.read_csv(args.puma_free)
        except (OSError, ValueError) as exc:
            ap.error(f"--puma-free {args.puma_free}: {' '.join(str(exc).split())}")
        missing = {"task", "kind", "seed", "method", "limit_steps"} - set(puma_free.columns)
        if missing:
            ap.error(f"--puma-free {args.puma_free}: not a safety_suite CSV (no column "
                     f"{', '.join(sorted(missing))})")
    specs = [{"task": t, "kind": k, "seed": s, "method": m, "models": args.models,
              "set": args.set, "label": args.label or m, "free": args.free, "paths": args.paths,
              "settle": args.settle}
             for t in args.tasks for k in args.kinds for m in args.methods
             for s in _seeds(args.seeds)]
    if args.label:
        for s in specs:
            s["label"] = f"{s['method']}:{args.label}"
    rows = []
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_suffix(".partial.csv")  # every finished run, as it finishes
    with Pool(args.jobs) as pool:
        for i, row in enumerate(pool.imap_unordered(run_one, specs), 1):
            rows.append(row)
            pd.DataFrame([row]).to_csv(partial, mode="a", header=i == 1, index=False)
            if i % 20 == 0:
                print(f"{i}/{len(specs)} runs", flush=True)
    df = pd.DataFrame(rows).sort_values(["task", "kind", "label", "seed"])
    df.to_csv(out, index=False)
    partial.unlink(missing_ok=True)
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(summarise(df))
        if puma_free is not None:
            print("success where PUMA's own obstacle-free run keeps every joint inside its "
                  "limits (False) or drives one past it (True):")
            try:
                print(split_by_puma_limits(df, puma_free))
            except ValueError as exc:
                print(f"--puma-free: {exc}")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
