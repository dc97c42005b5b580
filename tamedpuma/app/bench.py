"""``python -m tamedpuma.bench``: the project's benchmarks in one command, written to files.

Sections (each regenerated, never typed in):

1. **Controller step** of every method at 2, 10, 100 and 1000 obstacles: the wall time of one
   whole ``controller.step(obs)`` (kinematics, network, fabric, regulator, pullback, solve) on
   fixed states near the default tomato start, obstacles seeded and kept clear of the arm
   (``bench_fabrics.random_obstacles``). Each method is built exactly as ``tamedpuma.sweep``
   builds it (same config, same model lookup). Median, p10, p90 [ms]; the first call at each
   count is reported apart (it allocates that count's buffers), warm-up calls are not timed.
   With ``--baseline REV`` the same cells are also timed on revision REV of this repository
   (``git archive`` into a temporary folder): one timing worker per tree, the same code, blocks
   of 100 calls alternating between them, so "before" and "after" share the machine's load;
   the table gives both medians and their ratio.
2. **Episode speed**: one FPM episode of the default scenario run through the sweep's own
   ``run_one`` with each recorder setting (none, MCAP, Rerun, both): simulated seconds per wall
   second, and each recorder's overhead against ``recorder=none``.
3. **Fabrics**: the vanilla fabric at 2-1000 obstacles against the reference ``fabrics``
   planner, measured live at 2 and 10 obstacles where a Python with it is given
   (``--reference-python`` or ``$TAMEDPUMA_REFERENCE_PYTHON``), its dated figures cited otherwise
   (:mod:`tamedpuma.app.bench_fabrics`; ``--skip-fabrics`` leaves the section as it is).
4. **PUMA training** and the **Table-1 sweep**: measured only on request (``--training``,
   ``--training-seeds``, ``--table1``: minutes each; :mod:`tamedpuma.app.bench_runs`), each judged
   against the speed targets, with the profile of the sweep's time from its runs' summaries;
   otherwise the last dated training figures found in ``benchmarks/`` are cited as such.

    python -m tamedpuma.bench                       # sections 1-3, writes the files below
    python -m tamedpuma.bench --methods fpm cpm --counts 2 1000 --skip-fabrics --no-write
    python -m tamedpuma.bench --baseline 93ed4a1      # also time revision 93ed4a1, side by side
    python -m tamedpuma.bench --training --training-seeds 0 1 2 --table1   # everything

Writes ``benchmarks/bench.json`` (every figure, machine, load averages at start and end) and
``benchmarks/fabrics.json``, the "## Controller step" and "## Fabrics" sections of
``BENCHMARKS.md`` (other sections are kept) and the one-line summary between README.md's
``<!-- bench-summary -->`` markers.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tamedpuma.app import bench_fabrics, bench_runs
from tamedpuma.app.bench_fabrics import ROOT, machine_info, random_obstacles, update_markdown

COUNTS = (2, 10, 100, 1000)
METHODS = ("puma", "fabrics", "fabrics+numba", "fpm", "fpm+numba", "cpm", "modulation_ik")
#: "<method>+<variant>": the method with extra overrides (the "before" side of a side-by-side
#: run is timed without them: the variant's previous default)
VARIANTS = {"numba": ["method.fabric.kernel=numba"]}
SECTION = "Controller step"
#: The speed targets: median [ms] per (method, obstacle count).
TARGET_MS = {("fpm", 2): 0.2, ("cpm", 2): 0.3, ("fpm", 1000): 0.6, ("cpm", 1000): 0.8,
             ("fabrics", 2): 0.05, ("fabrics", 1000): 0.2, ("modulation_ik", 2): 1.0,
             ("fabrics+numba", 2): 0.05, ("fabrics+numba", 1000): 0.2,
             ("fpm+numba", 2): 0.2, ("fpm+numba", 1000): 0.6}
#: The paper's laptop figures [ms] (i7-12700H): Table 1 (2 obstacles) and the 1000-obstacle claim.
PAPER_MS = {("puma", 2): 4.41, ("modulation_ik", 2): 7.08, ("fabrics", 2): 0.39,
            ("fpm", 2): 5.22, ("cpm", 2): 6.55, ("fpm", 1000): 5.9, ("cpm", 1000): 7.0,
            ("modulation_ik", 1000): 3.5e3}


def method_overrides(label: str) -> tuple[str, list[str]]:
    """``"fabrics+numba"`` -> ``("fabrics", ["method.fabric.kernel=numba"])``; a plain method
    name -> (it, []). ValueError for an unknown variant, or numba asked for but not installed."""
    method, _, variant = label.partition("+")
    if not variant:
        return method, []
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r} (known: {sorted(VARIANTS)})")
    if variant == "numba":
        from tamedpuma.fabrics import compiled

        if not compiled.AVAILABLE:
            raise ValueError("numba is not installed (pip install 'tamedpuma[fast]')")
    return method, list(VARIANTS[variant])


def compose(overrides: list[str]):
    """The sweep's config with ``overrides`` (Hydra's compose API; entry points only)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from tamedpuma.app.config import CONF_DIR

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return hydra_compose("sweep", overrides=overrides, return_hydra_config=False)


def _observation(scenario, q, qd, obstacles, t=0.0, step=0):
    from tamedpuma.types import Observation

    goal = scenario.goal
    return Observation(t=t, step=step, q=q, qd=qd, obstacle_centers=obstacles.centers,
                       obstacle_radii=obstacles.radii,
                       obstacle_velocities=obstacles.velocities,
                       goal_position=goal.position, goal_quaternion=goal.quaternion,
                       goal_velocity=goal.velocity)


def time_controller(method: str, counts, calls: int, budget_s: float, overrides=(),
                    seed: int = 0) -> list[dict]:
    """Per obstacle count: timing of ``controller.step`` of ``method`` built as the sweep does.

    A cell stops after ``calls`` timed calls or ``budget_s`` seconds, whichever comes first
    (Modulation-IK at 1000 obstacles takes seconds per call). States: the scenario's start
    plus small seeded perturbations (16 states, cycled), zero goal velocity.
    """
    from tamedpuma.app.sweep import build
    from tamedpuma.types import Obstacles

    label, (method, extra) = method, method_overrides(method)
    built = build(compose([f"method={method}", "recorder=none", *extra, *overrides]))
    kin_spec, scenario, controller = built.spec, built.scenario, built.controller
    model = None
    if built.model is not None:
        meta = built.model.metadata()
        model = (f"{meta['model_origin']} `{Path(meta['model_path']).parent.name}` "
                 f"(sha256 {meta['model_sha256'][:12]})")
    rng = np.random.default_rng(seed)
    q0 = np.asarray(scenario.q0, dtype=float)
    states = [(np.clip(q0 + rng.normal(scale=0.05, size=q0.size), kin_spec.q_min,
                       kin_spec.q_max), rng.normal(scale=0.2, size=q0.size)) for _ in range(16)]
    from tamedpuma.robot.kinematics import Kinematics

    centers0 = Kinematics(kin_spec).evaluate(q0, np.zeros(q0.size)).sphere_centers
    rows = []
    for n in counts:
        centers, radii, vel = random_obstacles(rng, n, centers0, kin_spec.sphere_radii, 0.15)
        obstacles = Obstacles(centers=centers, radii=radii, velocities=vel)
        controller.reset(dataclasses.replace(scenario, obstacles=obstacles))
        observations = [_observation(scenario, q, qd, obstacles) for q, qd in states]
        t0 = time.perf_counter()
        controller.step(observations[0])
        first_ms = (time.perf_counter() - t0) * 1e3
        warm_end = time.perf_counter() + min(1.0, budget_s / 10)
        for i in range(min(50, calls)):
            if time.perf_counter() > warm_end:
                break
            controller.step(observations[i % len(observations)])
        out, stop = [], time.perf_counter() + budget_s
        for i in range(calls):
            obs = observations[i % len(observations)]
            t0 = time.perf_counter()
            controller.step(obs)
            out.append(time.perf_counter() - t0)
            if time.perf_counter() > stop and len(out) >= 5:
                break
        ms = np.array(out) * 1e3
        rows.append({"method": label, "n_obstacles": n,
                     "median_ms": round(float(np.median(ms)), 5),
                     "p10_ms": round(float(np.percentile(ms, 10)), 5),
                     "p90_ms": round(float(np.percentile(ms, 90)), 5),
                     "mean_ms": round(float(ms.mean()), 5), "n_calls": int(ms.size),
                     "first_call_ms": round(first_ms, 5), "model": model})
    return rows


def _timed_calls(fn, calls: int) -> np.ndarray:
    """``calls`` individually timed calls of ``fn`` [s]."""
    out = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out


def _tamed_parts(ctrl, state, obs, av, accel, null) -> dict:
    """The parts of an FPM/CPM step after the network (``forcing.mode: metric``): the
    circulation's specs (with the fabric's clearance, as the step calls them), the directional
    metric, the pullback through the metric and the control-rate filters; {} otherwise."""
    from tamedpuma.methods._policy import pull_through_metric, pull_to_joints
    from tamedpuma.methods._tamed import approached_metric

    forcing, puma = getattr(ctrl, "forcing", None), ctrl.puma
    if forcing is None or forcing.mode != "metric":
        return {}
    parts = {}
    free = pull_to_joints(accel, puma.damping, null)
    circulation = getattr(ctrl, "circulation", None)
    if circulation is not None:
        parts["circulation specs"] = lambda: circulation.specs(
            state, obs.qd, free, obs.obstacle_centers, obs.obstacle_radii, None,
            av.min_clearance)
    W = approached_metric(av, free) if forcing.directional else av.M
    if forcing.directional:
        parts["directional metric"] = lambda: approached_metric(av, free)
    weights = forcing.weight
    priority = forcing.priority_rows(len(accel.xdd))  # as the step solves it
    secondary = forcing.secondary_damping()  # the orientation rows' damping, as the step
    parts["pullback through the metric"] = lambda: pull_through_metric(
        accel, W, weights, forcing.null_metric, null, None, priority, secondary)
    qd_next = obs.qd + ctrl.dt * (av.acceleration() + free)
    parts["control-rate filters"] = lambda: ctrl.rate.next_velocity(
        qd_next, av, ctrl.dt, ctrl.qd_max, ctrl.ground_rows(state, obs.qd), obs.qd)
    return parts


def time_parts(method: str, n_obstacles: int = 2, calls: int = 1000, overrides=(),
               seed: int = 0) -> list[dict]:
    """Where one controller step's time goes: the step's parts timed one by one at one state
    (kinematics, avoidance fabric, network, pullback, ...; the remainder is the method's own
    arithmetic and log scalars). For the parts that use a trained model, also with the network's
    reference path (``primitive.single = None``: the batched numpy copy). Methods without a part
    skip it. Rows: ``{method, part, us, reference_us}``."""
    from tamedpuma.app.sweep import build
    from tamedpuma.methods._policy import pull_to_joints
    from tamedpuma.robot.kinematics import Kinematics
    from tamedpuma.types import Obstacles

    label, (method, extra) = method, method_overrides(method)
    built = build(compose([f"method={method}", "recorder=none", *extra, *overrides]))
    spec, scenario, ctrl = built.spec, built.scenario, built.controller
    rng = np.random.default_rng(seed)
    q0 = np.asarray(scenario.q0, dtype=float)
    centers0 = Kinematics(spec).evaluate(q0, np.zeros(q0.size)).sphere_centers
    obstacles = Obstacles(*random_obstacles(rng, n_obstacles, centers0, spec.sphere_radii, 0.15))
    ctrl.reset(dataclasses.replace(scenario, obstacles=obstacles))
    q = np.clip(q0 + rng.normal(scale=0.05, size=q0.size), spec.q_min, spec.q_max)
    obs = _observation(scenario, q, rng.normal(scale=0.2, size=q0.size), obstacles)
    kin = getattr(ctrl, "kinematics", None)
    fabric = getattr(ctrl, "fabric", None)
    puma = getattr(ctrl, "puma", ctrl if hasattr(ctrl, "task") else None)
    parts = {"step": lambda: ctrl.step(obs)}
    state = kin.evaluate(obs.q, obs.qd) if kin is not None else None
    if kin is not None:
        parts["kinematics"] = lambda: kin.evaluate(obs.q, obs.qd)
    if fabric is not None and method == "fabrics":
        goal_r = ctrl._rotation(obs.goal_quaternion)
        parts["fabric (all leaves, solve, speed control)"] = lambda: fabric.evaluate(
            state, obs.q, obs.qd, obs.obstacle_centers, obs.obstacle_radii,
            obs.obstacle_velocities, obs.goal_position, goal_r)
    elif fabric is not None:
        av = fabric.avoidance(state, obs.q, obs.qd, obs.obstacle_centers, obs.obstacle_radii,
                              obs.obstacle_velocities)
        parts["avoidance fabric"] = lambda: fabric.avoidance(
            state, obs.q, obs.qd, obs.obstacle_centers, obs.obstacle_radii,
            obs.obstacle_velocities)
        parts["its solve and energization"] = lambda: av.alpha(obs.qd, av.acceleration())
    task = getattr(puma, "task", None)
    primitive = getattr(task, "primitive", None)
    if task is not None and state is not None:
        goal = (obs.goal_position, obs.goal_quaternion)
        parts["network: acceleration"] = lambda: task.acceleration(state, obs.qd, *goal)
        if method == "cpm":
            parts["network: acceleration + ψ and ∂ψ"] = lambda: (
                task.acceleration(state, obs.qd, *goal), task.potential(state, *goal))
        accel = task.acceleration(state, obs.qd, *goal)
        null = puma.null_space.acceleration(kin, obs.qd) if puma.null_space else None
        parts["pullback J⁺ and null space"] = lambda: pull_to_joints(
            accel, puma.damping, puma.null_space.acceleration(kin, obs.qd)
            if puma.null_space else None)
        if fabric is not None and method != "fabrics":
            parts.update(_tamed_parts(ctrl, state, obs, av, accel, null))
    if method == "modulation_ik":  # its IK solve, as the method logs it (ik_solve_ms)
        solve_ms = [ctrl.step(obs).scalars.get("ik_solve_ms", np.nan) for _ in range(20)]
        ik_us = float(np.nanmedian(solve_ms)) * 1e3
    # every (part, path) timed in rounds of calls/10, interleaved, so that a burst of load on
    # the shared machine spreads over all of them instead of hitting one row
    reference = primitive is not None and hasattr(primitive, "single")
    jobs = [(part, False) for part in parts] + [
        (part, True) for part in parts
        if reference and (part == "step" or part.startswith("network"))]
    times = {job: [] for job in jobs}
    rounds = 10
    for _ in range(rounds + 1):  # the first round warms up and is dropped
        for part, ref in jobs:
            one = primitive.single if ref else None
            if ref:
                primitive.single = None
            try:
                times[(part, ref)].append(_timed_calls(parts[part], max(1, calls // rounds)))
            finally:
                if ref:
                    primitive.single = one
    rows = []
    if method == "modulation_ik" and np.isfinite(ik_us):
        rows.append({"method": label, "n_obstacles": n_obstacles,
                     "part": "IK solve (Drake SNOPT; the step's ik_solve_ms)", "us": ik_us})
    for part in parts:
        row = {"method": label, "n_obstacles": n_obstacles, "part": part,
               "us": round(float(np.median(np.concatenate(times[(part, False)][1:]))) * 1e6, 2)}
        if (part, True) in times:
            row["reference_us"] = round(
                float(np.median(np.concatenate(times[(part, True)][1:]))) * 1e6, 2)
        rows.append(row)
    return rows


#: Recorder settings timed, as sweep overrides.
RECORDERS = {"none": ["recorder=none"], "mcap": ["recorder=mcap"],
             "rerun": ["recorder=none", "recorder.rerun=true"], "mcap+rerun": ["recorder=default"]}


def time_episodes(method: str = "fpm", repeats: int = 3, overrides=(),
                  trees: dict | None = None) -> list[dict]:
    """Episode speed: one default-scenario episode of ``method`` per recorder setting
    (:data:`RECORDERS`), ``repeats`` times, through the sweep's own ``run_one`` in a worker
    process per source tree (``trees`` = {side: path}, default {"now": this tree}; with a
    "before" side its figures are attached as ``before_*`` and ``speedup``). Every worker runs
    one untimed episode first (imports, model load); then rounds of one episode per (recorder,
    side), the order rotated every round, so load changes hit every cell alike.

    Per cell (medians): ``wall_s`` = the episode itself (``run_episode``: simulator, controller,
    recorders from open to close), ``run_wall_s`` = the whole ``run_one`` (plus building the
    config, model and world, and writing summary.json), ``realtime_factor`` = simulated s per
    episode wall s, ``overhead_vs_none`` = episode wall / the same side's ``recorder=none`` − 1.
    """
    trees = trees or {"now": ROOT}
    workers = {}
    try:
        for side, tree in trees.items():
            workers[side] = _Worker(Path(tree), {"method": method, "overrides": list(overrides),
                                                 "recorders": RECORDERS}, _EPISODE_WORKER)
        for w in workers.values():  # warm-up: imports, model file, first-call allocations
            w.ask({"cmd": "run", "recorder": "none"})
        got = {(side, rec): [] for side in trees for rec in RECORDERS}
        recorders, sides = list(RECORDERS), list(trees)
        for r in range(repeats):
            for rec in recorders[r % len(recorders):] + recorders[:r % len(recorders)]:
                for side in (sides if r % 2 == 0 else sides[::-1]):
                    run = workers[side].ask({"cmd": "run", "recorder": rec,
                                             "physics": rec == "none"})
                    if rec == "none":
                        run.update(workers[side].read())
                    got[(side, rec)].append(run)
    finally:
        for w in workers.values():
            w.close()
    rows = {side: [] for side in trees}
    for side in trees:
        for rec in RECORDERS:
            runs = got[(side, rec)]
            wall = np.array([x["loop_s"] for x in runs])
            sim_s = float(runs[-1]["sim_s"])
            rows[side].append({
                "method": method, "recorder": rec, "steps": runs[-1]["steps"],
                "sim_s": round(sim_s, 3), "wall_s": round(float(np.median(wall)), 4),
                "wall_p10_s": round(float(np.percentile(wall, 10)), 4),
                "wall_p90_s": round(float(np.percentile(wall, 90)), 4),
                "run_wall_s": round(float(np.median([x["wall_s"] for x in runs])), 4),
                "realtime_factor": round(sim_s / float(np.median(wall)), 1),
                "controller_s": round(float(np.median([x["controller_s"] for x in runs])), 4),
                "repeats": len(runs)})
            parts = sorted({k for x in runs for k in x.get("own", {})})
            if parts:  # the recorders' own time (medians [s]) and its share of the rest
                own = {k: float(np.median([x["own"].get(k, 0.0) for x in runs])) for k in parts}
                total = float(np.median([sum(x["own"].values()) for x in runs]))
                rows[side][-1]["recorder_own_s"] = {k: round(v, 4) for k, v in own.items()}
                rows[side][-1]["recorder_own_share"] = round(
                    total / max(float(np.median(wall)) - total, 1e-9), 4)
            if rec == "none":
                rows[side][-1]["physics_s"] = round(
                    float(np.median([x["physics_s"] for x in runs])), 4)
        base = next(r["wall_s"] for r in rows[side] if r["recorder"] == "none")
        for r in rows[side]:
            r["overhead_vs_none"] = round(r["wall_s"] / base - 1.0, 4)
    main_side = next(iter(trees))
    out = rows[main_side]
    if "before" in rows and main_side != "before":
        for row, old in zip(out, rows["before"]):
            for key in ("steps", "sim_s", "wall_s", "realtime_factor", "overhead_vs_none"):
                row[f"before_{key}"] = old[key]
            row["speedup"] = round(old["wall_s"] / old["sim_s"] * row["sim_s"] / row["wall_s"],
                                   3)  # ratio of the speeds (simulated s per wall s)
    return out


#: The start of every worker script: the reply channel is the original stdout, anything the
#: project prints goes to stderr; ``send`` writes one JSON line.
_WORKER_PROTOCOL = r"""
import json, os, sys, time
reply = os.fdopen(os.dup(1), "w")
os.dup2(2, 1)  # anything the project prints goes to stderr, not into the protocol

def send(obj):
    reply.write(json.dumps(obj) + "\n")
    reply.flush()
"""


#: An episode worker (see :func:`time_episodes`), run by ``python -c`` inside a source tree. It
#: reads JSON lines: {"method", "overrides", "recorders"} (set-up), then {"cmd": "run",
#: "recorder"} (one episode through ``run_one``; answers its wall times [s], steps and simulated
#: time) and {"cmd": "quit"}. It uses only APIs both trees have.
_EPISODE_WORKER = _WORKER_PROTOCOL + r"""
import shutil, tempfile
from pathlib import Path
import tamedpuma.episode as episode
from tamedpuma.app import sweep
from tamedpuma.app.bench import compose

loops = []
_run_episode = episode.run_episode

def timed_run_episode(*args, **kwargs):
    t0 = time.perf_counter()
    try:
        return _run_episode(*args, **kwargs)
    finally:
        loops.append(time.perf_counter() - t0)

episode.run_episode = timed_run_episode  # run_one imports it at call time
if hasattr(sweep, "run_episode"):
    sweep.run_episode = timed_run_episode
own = {}  # the recorders' own time per run [s]: their open/write/close and the step records


def timed(owner, name, key):
    f = getattr(owner, name)

    def g(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return f(*args, **kwargs)
        finally:
            own[key] = own.get(key, 0.0) + time.perf_counter() - t0
    setattr(owner, name, g)


from tamedpuma.recording.mcap_writer import McapRecorder
from tamedpuma.recording.rerun_writer import RerunRecorder

for cls, label in ((McapRecorder, "mcap"), (RerunRecorder, "rerun")):
    timed(cls, "write", f"{label}_write")
    timed(cls, "open", f"{label}_open_close")
    timed(cls, "close", f"{label}_open_close")
if hasattr(episode, "_step_record"):
    timed(episode, "_step_record", "step_records")
setup = json.loads(sys.stdin.readline())
configs = {name: compose([f"method={setup['method']}", *extra, *setup["overrides"]])
           for name, extra in setup["recorders"].items()}
tmp = Path(tempfile.mkdtemp(prefix="bench_episode_"))
send({"ok": True})
try:
    for i, line in enumerate(sys.stdin):
        cmd = json.loads(line)
        if cmd["cmd"] == "quit":
            break
        run_dir = tmp / f"run{i}"
        run_dir.mkdir()
        own.clear()
        t0 = time.perf_counter()
        summary = sweep.run_one(configs[cmd["recorder"]], run_dir)
        wall = time.perf_counter() - t0
        send({"wall_s": wall, "loop_s": loops[-1], "steps": summary["steps"], "own": dict(own),
              "sim_s": summary["duration_s"],
              "controller_s": sum(summary.get("step_compute_ms") or [float("nan")]) / 1e3})
        shutil.rmtree(run_dir, ignore_errors=True)
        if cmd.get("physics"):  # the simulator alone: as many steps, zero command, no reads
            import numpy as np
            from tamedpuma.worlds.bullet import Simulator

            built = sweep.build(configs["none"])
            with Simulator(built.spec, built.sim_config, built.disturbance) as sim:
                sim.reset(built.scenario)
                zero = np.zeros(built.spec.dof)
                t0 = time.perf_counter()
                for _ in range(summary["steps"]):
                    sim.step(zero)
                physics = time.perf_counter() - t0
            send({"physics_s": physics})
finally:
    shutil.rmtree(tmp, ignore_errors=True)
"""


#: A timing worker, run by ``python -c`` inside a source tree (this one or a baseline's), so that
#: both sides are measured by the same code, one block of calls at a time, alternately. It reads
#: JSON lines: {"method", "overrides", "counts", "seed"} (build), then {"cmd": "reset", "n"}
#: (obstacles of that count; answers the first call's time), {"cmd": "time", "calls", "warm"}
#: (answers the timed calls [s]) and {"cmd": "quit"}. It uses only APIs both trees have.
_WORKER = _WORKER_PROTOCOL + r"""
import dataclasses
import numpy as np
from tamedpuma.app.bench import _observation, compose
from tamedpuma.app.bench_fabrics import random_obstacles
from tamedpuma.app.sweep import build
from tamedpuma.robot.kinematics import Kinematics
from tamedpuma.types import Obstacles

setup = json.loads(sys.stdin.readline())
built = build(compose([f"method={setup['method']}", "recorder=none", *setup["overrides"]]))
spec, scenario, ctrl = built.spec, built.scenario, built.controller
rng = np.random.default_rng(setup["seed"])
q0 = np.asarray(scenario.q0, dtype=float)
states = [(np.clip(q0 + rng.normal(scale=0.05, size=q0.size), spec.q_min, spec.q_max),
           rng.normal(scale=0.2, size=q0.size)) for _ in range(16)]
centers0 = Kinematics(spec).evaluate(q0, np.zeros(q0.size)).sphere_centers
model = None
if getattr(built, "model", None) is not None:
    meta = built.model.metadata()
    folder = os.path.basename(os.path.dirname(meta["model_path"]))
    model = f"{meta['model_origin']} `{folder}` (sha256 {meta['model_sha256'][:12]})"
send({"ok": True, "model": model})
observations, i = [], 0
for line in sys.stdin:
    cmd = json.loads(line)
    if cmd["cmd"] == "quit":
        break
    if cmd["cmd"] == "reset":
        c, r, v = random_obstacles(rng, cmd["n"], centers0, spec.sphere_radii, 0.15)
        obstacles = Obstacles(centers=c, radii=r, velocities=v)
        ctrl.reset(dataclasses.replace(scenario, obstacles=obstacles))
        observations = [_observation(scenario, q, qd, obstacles) for q, qd in states]
        t0 = time.perf_counter()
        ctrl.step(observations[0])
        send({"first_s": time.perf_counter() - t0})
        i = 1
        continue
    for _ in range(cmd["warm"]):
        ctrl.step(observations[i % 16])
        i += 1
    out = []
    for _ in range(cmd["calls"]):
        obs = observations[i % 16]
        i += 1
        t0 = time.perf_counter()
        ctrl.step(obs)
        out.append(time.perf_counter() - t0)
    send({"s": out})
"""


class _Worker:
    """One timing worker process in a source tree (see ``_WORKER``)."""

    def __init__(self, tree: Path, setup: dict, script: str | None = None):
        self.log = tempfile.TemporaryFile(mode="w+")
        env = {**os.environ, "PYTHONPATH": str(tree)}
        self.proc = subprocess.Popen([sys.executable, "-c", script or _WORKER], cwd=tree,
                                     env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self.log, text=True)
        self.model = self.ask(setup).get("model")

    def ask(self, cmd: dict) -> dict:
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        return self.read()

    def read(self) -> dict:
        """The worker's next answer."""
        line = self.proc.stdout.readline()
        if not line:
            self.proc.wait()
            self.log.seek(0)
            lines = [x for x in self.log.read().splitlines() if x.strip()]
            raise RuntimeError(lines[-1] if lines else f"worker exit {self.proc.returncode}")
        return json.loads(line)

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write('{"cmd": "quit"}\n')
                self.proc.stdin.close()
            except OSError:
                pass
            self.proc.wait(timeout=30)
        self.log.close()


def _cell(method: str, n: int, ms: np.ndarray, first_ms: float, model) -> dict:
    return {"method": method, "n_obstacles": n, "median_ms": round(float(np.median(ms)), 5),
            "p10_ms": round(float(np.percentile(ms, 10)), 5),
            "p90_ms": round(float(np.percentile(ms, 90)), 5),
            "mean_ms": round(float(ms.mean()), 5), "n_calls": int(ms.size),
            "first_call_ms": round(first_ms, 5), "model": model}


def time_side_by_side(method: str, counts, calls: int, budget_s: float, trees: dict,
                      overrides=(), block: int = 100) -> dict[str, list[dict]]:
    """The controller cells of ``method`` in each source tree of ``trees`` ({side: path}),
    measured as :func:`time_controller` does but interleaved: per obstacle count, blocks of at
    most ``block`` calls alternate between the sides (the order swapped every round), so a
    change of the machine's load hits every side alike. A side stops at ``calls`` calls or
    ``budget_s`` seconds of its own. Returns {side: rows}."""
    label, (method, extra) = method, method_overrides(method)
    workers = {}
    try:
        for side, tree in trees.items():
            variant = [] if side == "before" else extra  # before: the variant's old default
            workers[side] = _Worker(Path(tree), {"method": method, "seed": 0,
                                                 "overrides": [*variant, *overrides]})
        rows = {side: [] for side in trees}
        for n in counts:
            first = {side: w.ask({"cmd": "reset", "n": n})["first_s"] * 1e3
                     for side, w in workers.items()}
            warm = {side: max(1, min(50, int(min(1.0, budget_s / 10) * 1e3 / max(ms, 1e-3))))
                    for side, ms in first.items()}
            for side, w in workers.items():
                w.ask({"cmd": "time", "calls": 0, "warm": warm[side]})
            got = {side: [] for side in trees}
            spent = dict.fromkeys(trees, 0.0)
            order = list(trees)
            while any(len(got[s]) < calls and spent[s] < budget_s for s in order):
                for side in order:
                    if len(got[side]) >= calls or spent[side] >= budget_s:
                        continue
                    per = (spent[side] / len(got[side])) if got[side] else first[side] / 1e3
                    k = int(max(1, min(block, calls - len(got[side]),
                                       (budget_s - spent[side]) / max(per, 1e-6))))
                    t0 = time.perf_counter()
                    got[side] += workers[side].ask({"cmd": "time", "calls": k, "warm": 0})["s"]
                    spent[side] += time.perf_counter() - t0
                order.reverse()
            for side in trees:
                rows[side].append(_cell(label, n, np.array(got[side]) * 1e3, first[side],
                                        workers[side].model))
        return rows
    finally:
        for w in workers.values():
            w.close()


def load_averages() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (None where the OS has none)."""
    return [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else None


def export_revision(root: Path, rev: str, dest: Path) -> str:
    """Write the tree of ``rev`` into ``dest`` (``git archive``, no git metadata touched);
    returns the full commit id. Raises RuntimeError with git's message on failure."""
    def git(*args, **kw):
        proc = subprocess.run(["git", "-C", str(root), *args], capture_output=True, **kw)
        if proc.returncode != 0:
            raise RuntimeError(f"git {args[0]} {rev}: {proc.stderr.decode().strip()}")
        return proc.stdout

    commit = git("rev-parse", "--verify", f"{rev}^{{commit}}").decode().strip()
    archive = git("archive", "--format=tar", commit)
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return commit


def _report_from_stdout(text: str) -> dict:
    """The JSON report a ``--no-write`` bench run prints (the last top-level object)."""
    start = text.rfind("\n{\n") + 1  # 0 when the report is all there is
    return json.loads(text[start:text.rindex("}") + 1])


def attach_baseline(rows: list[dict], before: list[dict]) -> None:
    """Add ``before_*`` figures and ``speedup`` (before median / median) to matching rows."""
    by = {(r["method"], r["n_obstacles"]): r for r in before}
    for row in rows:
        old = by.get((row["method"], row["n_obstacles"]))
        if old:
            for key in ("median_ms", "p10_ms", "p90_ms", "n_calls"):
                row[f"before_{key}"] = old[key]
            row["speedup"] = round(old["median_ms"] / row["median_ms"], 3)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split("Config search path")[0].split()) or type(exc).__name__


def cited(root: Path) -> dict:
    """Dated figures already in ``benchmarks/`` (training reports), cited, not re-measured."""
    out = {}
    for task in ("tomato", "pouring"):
        path = root / "benchmarks" / f"puma_{task}.json"
        if path.is_file():
            data = json.loads(path.read_text())
            out[f"training_{task}"] = {
                "source": str(path.relative_to(root)),
                "wall_s": data.get("pipeline_seconds"),
                "date": time.strftime("%Y-%m-%d", time.gmtime(path.stat().st_mtime)),
            }
    return out


def _fmt(x: float) -> str:
    return f"{x:.3f}" if x < 10 else f"{x:.0f}"


def _ratio(x: float) -> str:
    return f"{x:.1f}×" if x < 10 else f"{x:.0f}×"


def _loads(m: dict, key: str) -> str:
    loads = m.get(key)
    return " / ".join(f"{x:.2f}" for x in loads) if loads else "?"


def _profile(report: dict, method: str, n: int, top: int = 4) -> str:
    """The largest parts of ``method``'s step at ``n`` obstacles (the parts table), in words."""
    rows = [r for r in report.get("parts", []) if r["method"] == method
            and r["n_obstacles"] == n]
    step = next((r["us"] for r in rows if r["part"] == "step"), None)
    rows = sorted((r for r in rows if r["part"] != "step"), key=lambda r: -r["us"])[:top]
    if not rows:
        return ""
    where = ", ".join(f"{r['part']} {r['us']:.0f} µs" for r in rows)
    whole = f"the step timed alone {step:.0f} µs; " if step else ""
    return f" Profile at {n} obstacles ({whole}largest parts): {where}."


#: Why a target is out of reach where the profile alone does not say it.
_WHY = {
    "fabrics": "All of it is kinematics plus the fused fabric: about 20 pinocchio and 60 numpy "
               "calls of ~0.5 µs each at 2 obstacles; at 1000 obstacles one pass of ~10 calls "
               "over the 5000 pairs' distances, then rows, kernel and products of the pairs "
               "within the activation distance x_a only (~2% of them on the bench's states: "
               "`fused.LayoutBuffers._gathered_pair_rows`; the others have metric 0). "
               "`fabrics+numba` compiles that pass, the kernel and the products.",
    "fpm": "Kinematics, fabric and network are the vanilla costs above; the rest is FPM's "
           "forcing (PUMA's obstacle-free pull, the directional metric, the "
           "weighted pullback with the position priority: three LAPACK "
           "solves instead of one, the control-rate barrier step over the barrier rows "
           "within the activation distance, the far pairs bounded by `discrete.FarRows`), "
           "each a few small-array numpy calls; at 1000 obstacles the fabric's pass over the "
           "5000 pairs' distances. "
           "What is left at 2 obstacles is per-call overhead spread over ~290 function calls "
           "(cProfile; no part above the network's ~35 µs and the fabric's ~30 µs); the "
           "`+numba` variant compiles the fabric; a compiled network is the next candidate "
           "(not tried: its products would differ from BLAS's in the last bits).",
    "cpm": "As FPM, plus ψ and ∂ψ (the rest row of the network's pass and a hand-written "
           "backward pass) and the regulator.",
    "modulation_ik": "The IK solve (SNOPT through Drake, a fresh program each step) is the "
                     "step: SNOPT's own ~20 evaluations of Drake's kinematics and "
                     "signed-distance query are ~0.7-1 ms of it on this machine, which no "
                     "change that keeps its answers can remove; building the program "
                     "~0.15 ms (reusing one measured 0.03-0.04 ms less: RemoveCost is slow); "
                     "the modulation, the network, the problem's validation and the "
                     "distance check of the answer are the rest (~0.3 ms).",
}


def target_lines(report: dict) -> list[str]:
    """The speed targets, each: met, or its figure and the profile that explains it."""
    by = {(r["method"], r["n_obstacles"]): r for r in report.get("controller", [])}
    out = []
    for (method, n), target in TARGET_MS.items():
        row = by.get((method, n))
        if row is None:
            continue
        med, p10 = row["median_ms"], row["p10_ms"]
        ratio = f", {_ratio(row['speedup'])} faster than before" if "speedup" in row else ""
        if med <= target:
            out.append(f"- {method}, {n} obstacles, median ≤ {target} ms: **met** "
                       f"({_fmt(med)} ms{ratio}).")
            continue
        verdict = ("met at p10, not at the median (the shared machine's load)"
                   if p10 <= target else "not met")
        base = method.partition("+")[0]
        out.append(f"- {method}, {n} obstacles, median ≤ {target} ms: **{verdict}**: "
                   f"{_fmt(med)} ms (p10 {_fmt(p10)}){ratio}."
                   + _profile(report, method, n) + (f" {_WHY[base]}" if base in _WHY else ""))
    eps = {r["recorder"]: r for r in report.get("episodes", [])}
    none = eps.get("none")
    if none:
        for rec, r in eps.items():
            if rec == "none":
                continue
            over, share = r["overhead_vs_none"], r.get("recorder_own_share")
            if share is None:
                out.append(f"- recorder {rec} adds ≤ 10% to the episode: "
                           f"**{'met' if over <= 0.10 else 'not met'}** ({100 * over:+.1f}%).")
                continue
            parts = ", ".join(f"{k.replace('_', ' ')} {1e6 * v / r['steps']:.0f} µs"
                              for k, v in r["recorder_own_s"].items())
            verdict = "met" if share <= 0.10 and over <= 0.10 else (
                "not met" if share > 0.10 else "met by its own time, not by the wall time")
            out.append(f"- recorder {rec} adds ≤ 10% to the episode: **{verdict}**: its own "
                       f"time is {100 * share:+.1f}% of the rest of the episode (per step: "
                       f"{parts}); the wall time vs recorder=none {100 * over:+.1f}% (the "
                       f"difference of two medians of a loaded machine: noisier).")
        rtf = none["realtime_factor"]
        line = (f"- FPM episodes ≥ 50× real time: **{'met' if rtf >= 50 else 'not met'}** "
                f"({rtf:.1f}× with recorder=none).")
        if rtf < 50 and "physics_s" in none:
            phys, ctrl, sim_s = none["physics_s"], none["controller_s"], none["sim_s"]
            line += (f" Bound: PyBullet's physics alone (1 ms substeps, unchanged: they decide "
                     f"every result) takes {phys:.3f} s, {sim_s / phys:.0f}× real time at "
                     f"most; with the controller's {ctrl:.3f} s inside the episode "
                     f"({1e3 * ctrl / none['steps']:.3f} ms per step, slower than the hot-loop "
                     f"step above: the physics evicts its caches) "
                     f"{sim_s / (phys + ctrl):.0f}× at most, before any state read or record.")
        out.append(line)
    training = bench_runs.training_target_line(report.get("training") or [])
    out += [training] if training else []
    out += bench_runs.table1_lines(report.get("table1"))[1:2]  # its verdict with the profile
    if not out:
        return []
    return ["", "Speed targets (medians of this run; the machine is shared, so the p10 "
            "is given too):", "", *out]


def markdown_section(report: dict) -> str:
    """The "## Controller step" section of BENCHMARKS.md, from ``report`` alone."""
    m = report["machine"]
    base = report.get("baseline")
    lines = [f"## {SECTION}", "",
             f"Regenerated by `{report.get('command', 'python -m tamedpuma.bench')}` (figures: "
             f"`benchmarks/bench.json`, {report['date']}). One whole `controller.step` "
             "(kinematics, network, fabric, regulator, pullback, solve) on fixed states near the "
             "default tomato start, each method built as the sweep builds it (models: "
             f"{report.get('models', 'the sweep defaults')}); obstacles seeded, clear of the arm.",
             ""]
    if base:
        lines += [f"\"before\": the same cells on commit `{base['commit'][:7]}` "
                  f"(`--baseline {base['rev']}`), in the same run: one timing worker per source "
                  "tree running the same timing code, blocks of at most 100 calls alternating "
                  "between them (order swapped every round), so both sides see the same load; "
                  "with both numbers and their ratio = before median / median.", ""]
    head = "| method | obstacles | median [ms] | p10 [ms] | p90 [ms] | calls | first call [ms] "
    rule = "|---|---:|---:|---:|---:|---:|---:|"
    if base:
        head += "| before: median [ms] | p10 [ms] | p90 [ms] | ratio "
        rule += "---:|---:|---:|---:|"
    lines += [head + "| target [ms] | paper [ms] |", rule + "---:|---:|"]
    for row in report["controller"]:
        key = (row["method"], row["n_obstacles"])
        target, paper = TARGET_MS.get(key), PAPER_MS.get(key)
        cells = (f"| {row['method']} | {row['n_obstacles']} | {_fmt(row['median_ms'])} | "
                 f"{_fmt(row['p10_ms'])} | {_fmt(row['p90_ms'])} | {row['n_calls']} | "
                 f"{_fmt(row['first_call_ms'])} |")
        if base:
            cells += (f" {_fmt(row['before_median_ms'])} | {_fmt(row['before_p10_ms'])} | "
                      f"{_fmt(row['before_p90_ms'])} | {_ratio(row['speedup'])} |"
                      if "speedup" in row else " — | — | — | — |")
        met = "—"
        if target is not None:  # under load the median is inflated; p10 ≈ the unloaded cost
            met = (f"≤ {target}: median {'✓' if row['median_ms'] <= target else '✗'}, "
                   f"p10 {'✓' if row['p10_ms'] <= target else '✗'}")
        cells += f" {met} | {paper if paper else '—'} |"
        lines.append(cells)
    for row in report.get("errors", []):
        lines.append(f"| {row['method']} | — | not measured: {row['error']} |")
    if report.get("parts"):
        lines += ["", "Where the time goes (one state per obstacle count, each part timed "
                  "alone: the median of 1000 calls in 10 rounds interleaved with the other "
                  "parts [µs]; \"reference network\": the same "
                  "with the network's reference path, the batched numpy copy "
                  "`puma/fastnet.py`, selected by `primitive.single = None`; FPM/CPM: "
                  "\"pullback J⁺ and null space\" is PUMA's obstacle-free pull q̈_P, which "
                  "the circulation and the directional metric need; the step's remainder is "
                  "the method's own arithmetic and log scalars, and a step run whole is "
                  "slower than its parts run alone, each in a hot loop):", "",
                  "| method | obstacles | part | [µs] | reference network [µs] |",
                  "|---|---:|---|---:|---:|"]
        for row in report["parts"]:
            ref = row.get("reference_us")
            lines.append(f"| {row['method']} | {row['n_obstacles']} | {row['part']} | "
                         f"{row['us']:.1f} | {f'{ref:.1f}' if ref is not None else ''} |")
        lines += ["", "At a few obstacles every part is per-call overhead, not arithmetic: the "
                  "kinematics are about 20 pinocchio calls (one per frame quantity of the end "
                  "effector and each body sphere), the fabric about 60 numpy calls on "
                  "preallocated buffers (`fabrics/fused.py`), the network about 25 "
                  "(`puma/single.py`: constants folded into the weights; with ψ, CPM reuses "
                  "the rest-state row of the same pass and adds a hand-written backward pass). "
                  "The kinematics are computed once per step and shared by the network's task "
                  "map, the null-space term and the fabric."]
    if report.get("episodes"):
        eps = report["episodes"]
        ebase = report.get("episode_baseline")
        lines += ["", "Episode speed (default tomato scenario, "
                  f"{eps[0]['method']}, through the sweep's `run_one` in a worker process, "
                  f"median of {eps[0]['repeats']} episodes per row after one warm-up, rows "
                  "interleaved round by round; \"episode\": `run_episode` from the recorders' "
                  "open to their close (simulator, controller, recorders), \"run\": the whole "
                  "`run_one` (also building config, model and world, writing summary.json); "
                  "target: recorders ≤ 10% overhead, FPM ≥ 50× real time"
                  + (f"; \"before\": the same on commit `{ebase['commit'][:7]}` "
                     f"(`{ebase['rev']}`), interleaved with these, ratio = speed / speed "
                     "before" if ebase else "") + "):", ""]
        head = ("| recorder | steps | simulated [s] | episode wall [s] (p10–p90) | × real time "
                "| overhead vs none | run wall [s] ")
        rule = "|---|---:|---:|---:|---:|---:|---:|"
        if ebase:
            head += "| before: steps | episode wall [s] | × real time | overhead | ratio "
            rule += "---:|---:|---:|---:|---:|"
        lines += [head + "|", rule]
        for r in eps:
            cells = (f"| {r['recorder']} | {r['steps']} | {r['sim_s']:.2f} | "
                     f"{r['wall_s']:.3f} ({r.get('wall_p10_s', r['wall_s']):.3f}–"
                     f"{r.get('wall_p90_s', r['wall_s']):.3f}) | "
                     f"{r['realtime_factor']:.1f} | {100 * r['overhead_vs_none']:+.1f}% | "
                     f"{r.get('run_wall_s', float('nan')):.3f} |")
            if ebase:
                cells += (f" {r['before_steps']} | {r['before_wall_s']:.3f} | "
                          f"{r['before_realtime_factor']:.1f} | "
                          f"{100 * r['before_overhead_vs_none']:+.1f}% | "
                          f"{_ratio(r['speedup'])} |" if "speedup" in r
                          else " — | — | — | — | — |")
            lines.append(cells)
        none = next((r for r in eps if r["recorder"] == "none" and "physics_s" in r), None)
        if none:
            rest = none["wall_s"] - none["physics_s"] - none["controller_s"]
            lines += ["", "Where the episode's time goes (recorder=none, medians): the simulator "
                      f"alone {none['physics_s']:.3f} s (the same {none['steps']} steps with a "
                      "zero command and no state reads: "
                      f"{none['sim_s'] / none['physics_s']:.0f}× real time at most, PyBullet's "
                      "1 ms substeps), the controller "
                      f"{none['controller_s']:.3f} s "
                      f"({1e3 * none['controller_s'] / none['steps']:.3f} ms per step), the "
                      f"rest {rest:.3f} s (the simulator's state reads, "
                      "contacts, the step records, metrics)."]
    lines += target_lines(report)
    lines += bench_runs.training_lines(report.get("training") or [],
                                       report.get("training_measured_by"))
    lines += bench_runs.table1_lines(report.get("table1"))[2:]  # its per-method table
    for key, item in report.get("cited", {}).items():
        lines += ["", f"{key} (cited from `{item['source']}`, not re-measured in this run): "
                  f"{item['wall_s']:.0f} s wall (file dated {item['date']})."]
    lines += ["", f"Machine: {m['cpu_model']}, {m['cores']} cores, Python {m['python']}, "
              f"numpy {m['numpy']}"
              + (f", numba {m['numba']} (the `fast` extra)" if m.get("numba") else
                 ", numba not installed")
              + "; load average (1 / 5 / 15 min) "
              f"{_loads(m, 'load_averages_start')} at the start, "
              f"{_loads(m, 'load_averages_end')} at the end (a shared machine inflates every "
              "figure; compare ratios measured in one run).", ""]
    return "\n".join(lines)


README_MARKERS = ("<!-- bench-summary -->", "<!-- /bench-summary -->")


def readme_summary(report: dict) -> str:
    """One sentence for README.md: the 2- and 1000-obstacle medians of every method timed."""
    by = {(r["method"], r["n_obstacles"]): r for r in report["controller"]}
    parts = []
    for method in dict.fromkeys(r["method"] for r in report["controller"]):
        cells = [f"{_fmt(by[(method, n)]['median_ms'])} ms ({n})" for n in (2, 1000)
                 if (method, n) in by]
        if cells:
            parts.append(f"{method} " + " / ".join(cells))
    if not parts:
        return ""
    loads = report["machine"].get("load_averages_start") or ["?"]
    return (f"Median controller step (obstacles), {report['date']}, load average {loads[0]}: "
            + "; ".join(parts) + ".")


def update_readme(path: Path, summary: str) -> bool:
    """Replace the text between README's bench-summary markers (False if there are none)."""
    if not summary or not path.is_file():
        return False
    text = path.read_text()
    start, end = README_MARKERS
    i, j = text.find(start), text.find(end)
    if i < 0 or j < i:
        return False
    path.write_text(text[:i + len(start)] + summary + text[j:])
    return True


def render(root: Path) -> int:
    """Rewrite the sections and the README line from the saved reports (``--render``)."""
    try:
        report = json.loads((root / "benchmarks" / "bench.json").read_text())
        fabrics = json.loads((root / "benchmarks" / "fabrics.json").read_text())
    except (OSError, ValueError) as exc:
        print(f"error: --render needs the saved reports: {_one_line(exc)}", file=sys.stderr)
        return 2
    update_markdown(root / "BENCHMARKS.md", markdown_section(report), SECTION)
    update_readme(root / "README.md", readme_summary(report))
    bench_fabrics.write(fabrics, root)
    print(f"rewrote {root / 'BENCHMARKS.md'} and the README summary from benchmarks/*.json",
          file=sys.stderr)
    return 0


def _steps(args) -> int:
    """``--steps``: the in-episode section alone (:mod:`tamedpuma.app.bench_steps`)."""
    from tamedpuma.app import bench_steps

    if not 0 <= args.steps_table1 <= 15:
        print("error: --steps-table1 must be between 0 and 15", file=sys.stderr)
        return 2
    methods = [m for m in args.methods if "+" not in m]
    report = bench_steps.run(methods, args.steps_table1, args.steps_seeds,
                             args.reference_python, args.overrides,
                             log=lambda line: print(line, file=sys.stderr))
    report["command"] = "python -m tamedpuma.bench " + " ".join(sys.argv[1:])
    print("\n".join(bench_steps.lines(report)))
    if not args.no_write:
        print(f"wrote {bench_steps.write(report, args.root)}", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--methods", nargs="+", default=list(METHODS))
    parser.add_argument("--counts", type=int, nargs="+", default=list(COUNTS))
    parser.add_argument("--calls", type=int, default=2000, help="timed calls per cell at most")
    parser.add_argument("--budget", type=float, default=10.0, help="seconds per cell at most")
    parser.add_argument("--episodes", type=int, default=3,
                        help="repeats per recorder setting (0: skip episode speed)")
    parser.add_argument("--training", action="store_true", help="also time PUMA training")
    parser.add_argument("--training-seeds", type=int, nargs="+", default=[0], metavar="SEED",
                        help="seeds of each task trained with --training")
    parser.add_argument("--table1", action="store_true", help="also time +experiment=table1")
    parser.add_argument("--parts", nargs="*",
                        default=["fabrics", "fabrics+numba", "puma", "fpm", "fpm+numba", "cpm",
                                 "modulation_ik"],
                        metavar="METHOD", help="methods whose step is broken into parts "
                        "(none: skip)")
    parser.add_argument("--parts-counts", type=int, nargs="+", default=[2, 1000],
                        metavar="N", help="obstacle counts of the parts (each method: those "
                        "of its targets, and 2)")
    parser.add_argument("--baseline", metavar="REV",
                        help="also time the controller cells on git revision REV, side by side")
    parser.add_argument("--episode-baseline", metavar="REV",
                        help="also time the episodes on git revision REV, side by side "
                        "(default: --baseline)")
    parser.add_argument("--skip-fabrics", action="store_true",
                        help="leave BENCHMARKS.md's \"Fabrics\" section (the vanilla fabric "
                        "against the reference planner) as it is")
    parser.add_argument("--reference-python", default=os.environ.get(bench_fabrics.REFERENCE_ENV)
                        or None, metavar="PATH", help="a Python with the reference `fabrics` "
                        "package: measured live at 2 and 10 obstacles (default: "
                        f"${bench_fabrics.REFERENCE_ENV}, else its dated figures are cited)")
    parser.add_argument("--render", action="store_true",
                        help="measure nothing: rewrite BENCHMARKS.md's sections and the README "
                        "line from benchmarks/bench.json and benchmarks/fabrics.json")
    parser.add_argument("--steps", action="store_true",
                        help="only the step inside whole episodes (Table-1 scenarios and the "
                        "randomized suite), written to benchmarks/steps.json "
                        "(tamedpuma/app/bench_steps.py)")
    parser.add_argument("--steps-table1", type=int, default=3, metavar="N",
                        help="with --steps: the first N Table-1 scenarios of each task")
    parser.add_argument("--steps-seeds", type=int, nargs="*", default=[2000], metavar="SEED",
                        help="with --steps: randomized-suite seeds (both tasks, both starts)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--root", type=Path, default=ROOT, help="repository root to write into")
    parser.add_argument("overrides", nargs="*", help="config overrides for every build")
    args = parser.parse_args(argv)
    if args.render:
        return render(args.root)
    if args.steps:
        return _steps(args)
    if any(n < 0 for n in args.counts) or args.calls < 1 or args.budget <= 0:
        print("error: counts must be ≥ 0, calls ≥ 1 and budget > 0", file=sys.stderr)
        return 2
    machine = machine_info()
    from tamedpuma.fabrics import compiled

    if compiled.AVAILABLE:  # the optional fast extra (fabric.kernel=numba)
        from importlib.metadata import version

        machine["numba"] = version("numba")
    machine["load_averages_start"] = load_averages()
    report = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "controller": [],
              "errors": [], "machine": machine, "overrides": args.overrides,
              "command": "python -m tamedpuma.bench " + " ".join(argv if argv is not None
                                                                  else sys.argv[1:])}
    episode_rev = args.episode_baseline or args.baseline
    with tempfile.TemporaryDirectory() as baseline_tree, \
            tempfile.TemporaryDirectory() as episode_tree:
        for option, rev, tree, key in (("--baseline", args.baseline, baseline_tree, "baseline"),
                                       ("--episode-baseline", episode_rev, episode_tree,
                                        "episode_baseline")):
            if not rev or (args.episodes <= 0 and key == "episode_baseline"):
                continue
            try:
                report[key] = {"rev": rev, "commit": export_revision(args.root, rev, Path(tree))}
            except (RuntimeError, OSError, subprocess.CalledProcessError) as exc:
                print(f"error: {option} {rev}: {_one_line(exc)}", file=sys.stderr)
                return 2
        for method in args.methods:
            rows, before = [], []
            try:
                if args.baseline:  # both trees timed by the same worker, block by block
                    sides = time_side_by_side(method, args.counts, args.calls, args.budget,
                                              {"now": ROOT, "before": baseline_tree},
                                              args.overrides)
                    rows, before = sides["now"], sides["before"]
                else:
                    rows = time_controller(method, args.counts, args.calls, args.budget,
                                           args.overrides)
            except Exception as exc:  # a missing model; Hydra's errors; a failing worker
                report["errors"].append({"method": method, "error": _one_line(exc)})
            attach_baseline(rows, before)
            report["controller"] += rows
            print(f"bench: {method} done", file=sys.stderr)
        report["parts"] = []
        for method, n in [(m, n) for m in args.parts for n in args.parts_counts
                          if n == 2 or (m, n) in TARGET_MS]:
            try:
                report["parts"] += time_parts(method, n, overrides=args.overrides)
            except Exception as exc:  # as above
                report["errors"].append({"method": f"{method} (parts)",
                                         "error": _one_line(exc)})
        if args.episodes > 0:
            trees = {"now": ROOT, **({"before": episode_tree} if episode_rev else {})}
            try:
                report["episodes"] = time_episodes("fpm", args.episodes, args.overrides, trees)
            except Exception as exc:  # a missing model, a composition error: reported
                report["errors"].append({"method": "episode", "error": _one_line(exc)})
    fabrics = None
    if not args.skip_fabrics:  # the "Fabrics" section: our fabric and the reference planner
        fabrics = bench_fabrics.run(calls=args.calls, reference_python=args.reference_python)
        fabrics["command"] = report["command"]
        report["fabrics"] = {k: fabrics[k] for k in ("results", "reference_live",
                                                      "reference_note")}
    if args.training:
        report["training"] = bench_runs.time_training(seeds=args.training_seeds)
        report["training_measured_by"] = f"`{report['command']}` ({report['date']})"
    if args.table1:
        report["table1"] = bench_runs.time_table1(machine["cores"] or 1)
    models = [r["model"] for r in report["controller"] if r.get("model")]
    if models:
        report["models"] = ", ".join(dict.fromkeys(models))
    report["cited"] = {} if args.training else cited(args.root)  # measured here: not cited
    machine["load_averages_end"] = load_averages()
    machine["load_average_1min_end"] = (machine["load_averages_end"] or [None])[0]
    print(json.dumps(report, indent=2))
    if not args.no_write:
        out = args.root / "benchmarks" / "bench.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(report, indent=2) + "\n")
        update_markdown(args.root / "BENCHMARKS.md", markdown_section(report), SECTION)
        update_readme(args.root / "README.md", readme_summary(report))
        if fabrics is not None:
            bench_fabrics.write(fabrics, args.root)
        print(f"wrote {out}, {args.root / 'BENCHMARKS.md'} and the README summary",
              file=sys.stderr)
    return 0

