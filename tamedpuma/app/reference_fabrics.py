"""Time the reference planner (the GPL ``fabrics`` package by Spahn et al.) on our workload.

A standalone script for the *reference* venv (``fabrics``, ``forwardkinematics``, ``mpscenes``,
casadi, numpy; no tamedpuma): nothing in our package imports it. It only *calls* the package's
public API (``ParameterizedFabricPlanner.set_components`` / ``concretize`` / ``compute_action``);
none of its code is copied here. Run by ``python -m tamedpuma.bench_fabrics --reference-python``::

    REF_PYTHON tamedpuma/app/reference_fabrics.py --input workload.json

The input JSON (written by :func:`tamedpuma.app.bench_fabrics.reference_payload`)::

    {"urdf_path": str (or "urdf": the URDF text), "root_link": str, "ee_link": str,
     "q_min": [rad]*dof, "q_max": [rad]*dof,
     "spheres": [{"link": str, "radius": m}, ...],    # the body spheres (at the link origins)
     "goal_position": [m]*3, "goal_weight": float,
     "states": [{"q": [rad]*dof, "qd": [rad/s]*dof}, ...],
     "counts": [{"n_obstacles": int, "centers": [[m]*3]*n, "radii": [m]*n, "n_calls": int}, ...],
     "warmup": int, "motion": {"steps": int, "dt": s},
     "episode": {"steps": int, "dt": s, "substep": s, "max_joint_force": N·m,
                 "joint_names": [str]*dof, "qd_max": [rad/s]*dof}}   # optional

Per count the planner is built (goal attractor on the end-effector position, every body sphere
against every obstacle sphere, joint limits; the planner's default parameters), its build timed,
``compute_action`` timed per call over the states (cycled, after ``warmup`` calls), and a short
rollout from the first state at rest integrates the action (semi-implicit Euler) to check the
planner drives the end effector toward the goal. With ``episode`` (and PyBullet installed beside
the package), the planner also drives the robot in PyBullet as our simulator does
(:mod:`tamedpuma.worlds.bullet`: the velocity target ``clip(q̇ + q̈ Δt, ±q̇_max)`` held by
velocity motors over Δt / substep physics steps, the ground and the obstacle spheres in the world)
for ``steps`` control periods from the first state at rest, each ``compute_action`` timed where
the controller's step is timed in our episodes: between the physics steps, whose work evicts
the step's code and data from the CPU's caches.

One JSON line per count goes to stdout::

    {"n_obstacles": n, "build_s": s, "median_ms": ms, "p10_ms": ms, "p90_ms": ms, "n_calls": int,
     "finite": bool, "motion": {"steps": int, "dt": s, "ee_distance_start_m": m,
                                "ee_distance_end_m": m, "min_clearance_m": m, "finite": bool},
     "episode": {"steps": int, "median_ms": ms, "p99_ms": ms, "max_ms": ms,
                 "ee_distance_start_m": m, "ee_distance_end_m": m, "finite": bool}
                or {"skipped": why},                    # with "episode" in the input
     "fabrics_version": str}

Everything else the package prints goes to stderr. Exit code 2 with a one-line message on a bad
input or a missing package.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
import time
import warnings
from pathlib import Path

import numpy as np

MARKER = "n_obstacles"  # every result line carries this key; other stdout lines are not results


def load_input(path: Path) -> dict:
    """The workload dict, with the URDF text under ``"urdf"`` (read from ``urdf_path`` if
    need be)."""
    spec = json.loads(Path(path).read_text())
    if "urdf" not in spec:
        spec["urdf"] = Path(spec["urdf_path"]).read_text()
    return spec


def build_planner(spec: dict, n_obstacles: int):
    """(planner, forward kinematics, build time [s]) of the reference planner at
    ``n_obstacles`` obstacle spheres."""
    from fabrics.planner.parameterized_planner import ParameterizedFabricPlanner
    from forwardkinematics.urdfFks.generic_urdf_fk import GenericURDFFk
    from mpscenes.goals.goal_composition import GoalComposition

    start = time.perf_counter()
    with contextlib.redirect_stdout(sys.stderr):  # the packages print progress to stdout
        fk = GenericURDFFk(spec["urdf"], root_link=spec["root_link"],
                           end_links=[spec["ee_link"]])
        goal = GoalComposition(name="goal", content_dict={"subgoal0": {
            "weight": float(spec["goal_weight"]), "is_primary_goal": True,
            "indices": [0, 1, 2], "parent_link": spec["root_link"],
            "child_link": spec["ee_link"], "desired_position": list(spec["goal_position"]),
            "epsilon": 0.05, "type": "staticSubGoal"}})
        planner = ParameterizedFabricPlanner(len(spec["q_min"]), fk)
        limits = np.column_stack((spec["q_min"], spec["q_max"])).tolist()
        planner.set_components(collision_links=[s["link"] for s in spec["spheres"]], goal=goal,
                               limits=limits, number_obstacles=n_obstacles)
        planner.concretize()
    return planner, fk, time.perf_counter() - start


def action_arguments(spec: dict, count: dict) -> dict:
    """The keyword arguments of ``compute_action`` except q and qdot: goal, obstacles [m],
    body-sphere radii [m]."""
    args = {"x_goal_0": np.asarray(spec["goal_position"], float),
            "weight_goal_0": float(spec["goal_weight"])}
    for sphere in spec["spheres"]:
        args[f"radius_body_{sphere['link']}"] = float(sphere["radius"])
    for j, (center, radius) in enumerate(zip(count["centers"], count["radii"])):
        args[f"x_obst_{j}"] = np.asarray(center, float)
        args[f"radius_obst_{j}"] = float(radius)
    return args


def time_actions(planner, states: list, fixed: dict, n_calls: int, warmup: int):
    """Per-call wall times [ms] of ``compute_action`` cycling over ``states``; all finite?"""
    calls = [{"q": np.asarray(s["q"], float), "qdot": np.asarray(s["qd"], float), **fixed}
             for s in states]
    finite = True
    for i in range(warmup):
        finite &= bool(np.all(np.isfinite(planner.compute_action(**calls[i % len(calls)]))))
    out = np.empty(n_calls)
    for i in range(n_calls):
        kwargs = calls[i % len(calls)]
        t0 = time.perf_counter()
        planner.compute_action(**kwargs)
        out[i] = time.perf_counter() - t0
    return out * 1e3, finite


def rollout(planner, fk, spec: dict, count: dict, fixed: dict, q0, steps: int,
            dt: float) -> dict:
    """Integrate the planner's action ``steps`` × ``dt`` [s] from ``q0`` at rest (semi-implicit
    Euler): the end effector's distance to the goal [m] at the start and the end, the smallest
    body-sphere to obstacle-sphere clearance on the way [m] (null without obstacles), and whether
    every action was finite."""
    goal = np.asarray(spec["goal_position"], float)
    centers = np.asarray(count["centers"], float).reshape(-1, 3)
    radii = np.asarray(count["radii"], float)
    links = [(s["link"], float(s["radius"])) for s in spec["spheres"]]
    q, qd = np.asarray(q0, float).copy(), np.zeros(len(q0))

    def position(q, link):
        return np.asarray(fk.numpy(q, link, position_only=True), float).ravel()

    def clearance(q):
        if not len(radii):
            return np.inf
        return min(float((np.linalg.norm(centers - position(q, link), axis=1) - radii).min()) - r
                   for link, r in links)

    start, lowest, finite = np.linalg.norm(position(q, spec["ee_link"]) - goal), clearance(q), True
    for _ in range(steps):
        qdd = planner.compute_action(q=q, qdot=qd, **fixed)
        finite &= bool(np.all(np.isfinite(qdd)))
        qd = qd + dt * qdd
        q = q + dt * qd
        lowest = min(lowest, clearance(q))
    return {"steps": steps, "dt": dt, "ee_distance_start_m": round(float(start), 5),
            "ee_distance_end_m": round(float(np.linalg.norm(position(q, spec["ee_link"]) - goal)),
                                       5),
            "min_clearance_m": round(lowest, 5) if np.isfinite(lowest) else None,
            "finite": finite}


def episode(planner, spec: dict, count: dict, fixed: dict) -> dict:
    """The planner driving the robot in PyBullet from the first state at rest (the module
    docstring): each ``compute_action`` timed [ms] between the control periods' physics steps,
    and the end effector's distance to the goal [m] at the start and the end; ``{"skipped":
    why}`` where PyBullet is not installed."""
    try:
        import pybullet as pb
        import pybullet_data
    except ImportError as exc:
        return {"skipped": f"pybullet not installed beside the reference ({exc})"}
    if not spec.get("urdf_path"):
        return {"skipped": "the episode loads the robot from urdf_path (its meshes beside it)"}
    ep = spec["episode"]
    n_sub = max(1, round(float(ep["dt"]) / float(ep["substep"])))
    qd_max = np.asarray(ep["qd_max"], float)
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0, 0, -9.81, physicsClientId=client)
        pb.setPhysicsEngineParameter(fixedTimeStep=float(ep["substep"]), numSubSteps=0,
                                     physicsClientId=client)
        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
        pb.loadURDF("plane.urdf", physicsClientId=client)
        robot = pb.loadURDF(spec["urdf_path"], [0, 0, 0], useFixedBase=True,
                            physicsClientId=client)
        names = [pb.getJointInfo(robot, i, physicsClientId=client)[1].decode()
                 for i in range(pb.getNumJoints(robot, physicsClientId=client))]
        joints = [names.index(n) for n in ep["joint_names"]]
        for center, radius in zip(count["centers"], count["radii"]):
            shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=float(radius),
                                            physicsClientId=client)
            pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=shape,
                               basePosition=list(map(float, center)),
                               useMaximalCoordinates=True, physicsClientId=client)
        for j, q in zip(joints, spec["states"][0]["q"]):
            pb.resetJointState(robot, j, float(q), 0.0, physicsClientId=client)
        forces = [float(ep["max_joint_force"])] * len(joints)
        pb.setJointMotorControlArray(robot, joints, pb.VELOCITY_CONTROL,
                                     targetVelocities=[0.0] * len(joints), forces=forces,
                                     physicsClientId=client)
        return _drive(planner, spec, fixed, pb, client, robot, joints, forces, n_sub, qd_max)
    finally:
        pb.disconnect(client)


def _drive(planner, spec, fixed, pb, client, robot, joints, forces, n_sub, qd_max) -> dict:
    """:func:`episode`'s control loop (its world built)."""
    ep, dt = spec["episode"], float(spec["episode"]["dt"])
    ee = [pb.getJointInfo(robot, i, physicsClientId=client)[12].decode()
          for i in range(pb.getNumJoints(robot, physicsClientId=client))].index(spec["ee_link"])
    goal = np.asarray(spec["goal_position"], float)

    def distance() -> float:
        p = pb.getLinkState(robot, ee, computeForwardKinematics=True, physicsClientId=client)[4]
        return float(np.linalg.norm(np.asarray(p) - goal))

    start, finite = distance(), True
    ms = np.empty(int(ep["steps"]))
    for k in range(len(ms)):
        states = pb.getJointStates(robot, joints, physicsClientId=client)
        q = np.array([s[0] for s in states])
        qd = np.array([s[1] for s in states])
        t0 = time.perf_counter()
        qdd = planner.compute_action(q=q, qdot=qd, **fixed)
        ms[k] = (time.perf_counter() - t0) * 1e3
        qdd = np.asarray(qdd, float).ravel()
        finite &= bool(np.all(np.isfinite(qdd)))
        target = np.clip(qd + dt * np.nan_to_num(qdd), -qd_max, qd_max)
        pb.setJointMotorControlArray(robot, joints, pb.VELOCITY_CONTROL,
                                     targetVelocities=target.tolist(), forces=forces,
                                     physicsClientId=client)
        for _ in range(n_sub):
            pb.stepSimulation(physicsClientId=client)
    return {"steps": len(ms), "median_ms": round(float(np.median(ms)), 5),
            "p99_ms": round(float(np.percentile(ms, 99)), 5), "max_ms": round(float(ms.max()), 5),
            "ee_distance_start_m": round(start, 5), "ee_distance_end_m": round(distance(), 5),
            "finite": finite}


def _version(package: str) -> str:
    """The installed version of ``package``, or "unknown"."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:
        return "unknown"


def measure(spec: dict, count: dict) -> dict:
    """Build and time the planner at one obstacle count: the result line (see the module doc)."""
    planner, fk, build_s = build_planner(spec, int(count["n_obstacles"]))
    fixed = action_arguments(spec, count)
    ms, finite = time_actions(planner, spec["states"], fixed, int(count["n_calls"]),
                              int(spec["warmup"]))
    motion = rollout(planner, fk, spec, count, fixed, spec["states"][0]["q"],
                     int(spec["motion"]["steps"]), float(spec["motion"]["dt"]))
    out = {
        MARKER: int(count["n_obstacles"]),
        "build_s": round(build_s, 4),
        "median_ms": round(float(np.median(ms)), 5),
        "p10_ms": round(float(np.percentile(ms, 10)), 5),
        "p90_ms": round(float(np.percentile(ms, 90)), 5),
        "n_calls": len(ms),
        "finite": finite,
        "motion": motion,
        "fabrics_version": _version("fabrics"),
    }
    if spec.get("episode"):
        out["episode"] = episode(planner, spec, count, fixed)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--input", type=Path, required=True, help="the workload JSON")
    args = parser.parse_args(argv)
    logging.disable(logging.WARNING)  # the package warns on every near-zero action
    warnings.simplefilter("ignore", FutureWarning)  # casadi's numpy-interop notice
    try:
        import fabrics  # noqa: F401  (fail early, in one line, where it is missing)
        spec = load_input(args.input)
    except (ImportError, OSError, ValueError, KeyError) as exc:
        print(f"reference_fabrics: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    for count in spec["counts"]:
        print(json.dumps(measure(spec, count)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
