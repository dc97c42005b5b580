"""Scenarios for any task, made from its demonstrations (``scenario=from_demos``).

Seeded by ``seed`` (the same seed gives the same scenario):

- start: one demonstration, drawn at random, gives the start pose: its first position plus a
  uniform offset of at most ``start_noise`` [m] and its first orientation; q0 is the pose IK
  solution from the robot's ``home`` (then seeded restarts) that converges with every body sphere
  above the ground. The goal is the task's goal.
- obstacles: the demonstration's path carried onto the goal (``p_k − p_end + p_goal``: PUMA
  learns each demonstration relative to its own final pose, so this is where the learned path from
  that start runs), a point at an arc-length fraction drawn from ``path_fraction``, moved sideways
  (perpendicular to the path) by at most ``path_offset`` [m]: obstacles on or near the path. A
  point is kept only if the obstacle's surface stays ``min_clearance`` [m] from the start's body
  spheres and end effector and from the goal, and clear of the other obstacles, and if the arm
  can still hold the goal pose with every body sphere ``goal_pose_clearance`` [m] clear of the
  obstacles (:mod:`tamedpuma.worlds.goal_pose`: 9 of the first 30 scenarios of the authors'
  other pouring folder had an obstacle by the forearm at the goal pose, where every controller
  rests 7-9 cm short).

numpy only (kinematics and IK from :mod:`tamedpuma.robot`). The configs are the schema's typed
objects (``tamedpuma/app/schema.py``), read by attribute and never changed: :func:`apply` returns
``dataclasses.replace`` copies.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING

import numpy as np

from tamedpuma.errors import ScenarioError
from tamedpuma.robot.ik import solve_pose_ik
from tamedpuma.worlds.goal_pose import goal_pose_spheres, pose_clear
from tamedpuma.worlds.scenarios import ObstacleConfig

if TYPE_CHECKING:  # annotations only: the config schema imports this module without torch
    from tamedpuma.puma.data import RawDemo


@dataclass(frozen=True)
class DemoScenarioConfig:
    """See the module docstring; lengths [m]. These defaults are the config defaults of
    ``scenario.generator`` (the schema, ``tamedpuma/app/schema.py``, takes its fields from here)."""

    seed: int = 0
    start_noise: float = 0.03
    n_obstacles: int = 1
    obstacle_radius: float = 0.05
    path_fraction: tuple[float, float] = (0.3, 0.7)
    path_offset: float = 0.03
    min_clearance: float = 0.1
    goal_pose_clearance: float = 0.02  # [m] the arm at the goal pose clear of the obstacles
    max_tries: int = 200


@dataclass(frozen=True)
class WorkspaceBox:
    """A ``task.workspace`` derived from the demonstrations (the attributes of the schema's
    ``WorkspaceSchema``): position box relative to the goal [m], max angle to it [rad]."""

    position_low: tuple[float, ...]
    position_high: tuple[float, ...]
    max_angle: float


def _arc_point(path: np.ndarray, u: float) -> tuple[np.ndarray, np.ndarray]:
    """Point at arc-length fraction u of a polyline, and the unit tangent there."""
    seg = np.diff(path, axis=0)
    length = np.linalg.norm(seg, axis=1)
    cum = np.concatenate(([0.0], np.cumsum(length)))
    if cum[-1] <= 0:
        return path[-1], np.array([1.0, 0.0, 0.0])
    s = u * cum[-1]
    k = int(np.clip(np.searchsorted(cum, s) - 1, 0, len(seg) - 1))
    frac = (s - cum[k]) / max(length[k], 1e-12)
    tangent = seg[k] / max(length[k], 1e-12)
    return path[k] + frac * seg[k], tangent


def start_configuration(kin, position, quaternion, home, rng) -> np.ndarray | None:
    """Pose IK from ``home`` then seeded restarts; None unless it converges with every body
    sphere above the ground (z > radius)."""
    for attempt in range(4):
        q_init = home if attempt == 0 else rng.uniform(kin.spec.q_min, kin.spec.q_max)
        res = solve_pose_ik(kin, position, quaternion, q_init, seed=int(rng.integers(1 << 30)))
        if not res.converged:
            continue
        centers = kin.sphere_centers(res.q)
        if len(centers) == 0 or np.all(centers[:, 2] > kin.spec.sphere_radii):
            return res.q
    return None


def generate(raws: list[RawDemo], goal_position, kin, home, cfg: DemoScenarioConfig,
             goal_quaternion=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(q0 (dof,), obstacle centres (n, 3), radii (n,), index of the demonstration used). With
    ``goal_quaternion``, the obstacles also leave the arm a way to hold the goal pose
    ``goal_pose_clearance`` clear of them (:mod:`tamedpuma.worlds.goal_pose`)."""
    rng = np.random.default_rng([int(cfg.seed), 2718])
    goal = np.asarray(goal_position, float)
    at_goal = (None if goal_quaternion is None
               else goal_pose_spheres(kin, goal, goal_quaternion, int(cfg.seed)))
    home = np.asarray(home if home is not None else (kin.spec.q_min + kin.spec.q_max) / 2, float)
    for _ in range(cfg.max_tries):
        i = int(rng.integers(len(raws)))
        demo = raws[i]
        offset = rng.normal(size=3)
        offset *= cfg.start_noise * rng.uniform() ** (1 / 3) / max(np.linalg.norm(offset), 1e-12)
        quat = demo.quat[0] if demo.quat is not None else kin.ee_pose(home)[1]
        q0 = start_configuration(kin, demo.pos[0] + offset, quat, home, rng)
        if q0 is None:
            continue
        keep_out = np.concatenate([kin.sphere_centers(q0), kin.ee_pose(q0)[0][None],
                                   goal[None]])
        keep_r = np.concatenate([kin.spec.sphere_radii, [0.0, 0.0]])
        path = demo.pos - demo.pos[-1] + goal
        centers: list[np.ndarray] = []
        for _ in range(cfg.max_tries):
            if len(centers) == cfg.n_obstacles:
                break
            point, tangent = _arc_point(path, rng.uniform(*cfg.path_fraction))
            side = np.cross(tangent, rng.normal(size=3))
            side /= max(np.linalg.norm(side), 1e-12)
            c = point + side * rng.uniform(0, cfg.path_offset)
            gap = np.linalg.norm(keep_out - c, axis=1) - keep_r - cfg.obstacle_radius
            if gap.min() < cfg.min_clearance or c[2] < cfg.obstacle_radius:
                continue
            if centers and (np.linalg.norm(np.array(centers) - c, axis=1).min()
                            < 2 * cfg.obstacle_radius):
                continue
            if at_goal is not None and not pose_clear(
                    at_goal, kin.spec.sphere_radii, np.array([*centers, c]),
                    np.full(len(centers) + 1, cfg.obstacle_radius), cfg.goal_pose_clearance):
                continue
            centers.append(c)
        if len(centers) == cfg.n_obstacles:
            return q0, np.array(centers).reshape(-1, 3), np.full(len(centers),
                                                                 cfg.obstacle_radius), i
    raise ScenarioError(f"could not make a scenario from the demonstrations in {cfg.max_tries} "
                        "tries (start unreachable by IK, or no obstacle place on the path "
                        f"{cfg.min_clearance} m clear of the start and the goal, the arm at the "
                        f"goal pose {cfg.goal_pose_clearance} m clear)")


def task_raws(task) -> list[RawDemo]:
    """The task's raw demonstrations without torch, exactly those its model is trained on
    (:func:`tamedpuma.puma.pipeline.load_raws`): synthetic (``demos: null``) or a folder/file
    (relative paths: :func:`tamedpuma.paths.resolve`). ``task``: the typed task config."""
    from tamedpuma.paths import resolve
    from tamedpuma.puma import demo_formats, demos_synthetic

    src = task.demos
    if src is None:
        syn = task.synthetic
        return demos_synthetic.generate(str(syn.kind or task.name), task.goal_position,
                                        task.goal_quaternion, int(syn.n_demos),
                                        int(syn.seed), time_law=str(syn.time_law))
    return demo_formats.load_any(resolve(str(src)))


def _demo_starts(raws: list[RawDemo], kinematics, home) -> list[list[float]]:
    """The IK solutions of the demonstrations' start poses (those found), seeded."""
    rng = np.random.default_rng(0)
    home = np.asarray(home if home else (kinematics.spec.q_min + kinematics.spec.q_max) / 2,
                      float)
    starts = [start_configuration(kinematics, r.pos[0], r.quat[0] if r.quat is not None
                                  else kinematics.ee_pose(home)[1], home, rng) for r in raws]
    return [q.tolist() for q in starts if q is not None]


def _with_derived_goal(task, raws: list[RawDemo]):
    """``task`` with its goal (unless set by hand) and workspace (unless set) derived from the
    demonstrations (:mod:`tamedpuma.puma.task_from_demos`)."""
    from tamedpuma.puma.task_from_demos import derive_goal, workspace_numbers

    gp, gq, _ = derive_goal(raws, float(task.spread_limit))
    if task.goal_position is not None:  # a derive task with its goal set by hand
        gp = np.asarray(task.goal_position, float)
        gq = None if task.goal_quaternion is None else np.asarray(task.goal_quaternion, float)
    workspace = task.workspace
    if workspace is None:  # the derived one (scenario=random needs it)
        lo, hi, ang = workspace_numbers(raws, gp, gq, float(task.margin),
                                        float(task.angle_margin))
        workspace = WorkspaceBox(tuple(lo.tolist()), tuple(hi.tolist()), ang)
    return replace(task, goal_position=gp.tolist(),
                   goal_quaternion=None if gq is None else gq.tolist(), workspace=workspace)


def _generated(sc, gen, raws: list[RawDemo], kinematics, home):
    """``sc`` with the start and obstacles of its ``generator: {kind: demos, ...}`` block (the
    obstacles added to any listed ones)."""
    if gen.kind != "demos":
        raise ScenarioError("scenario.generator.kind must be 'demos'")
    values = {f.name: getattr(gen, f.name) for f in fields(DemoScenarioConfig)}
    try:
        cfg = DemoScenarioConfig(**{k: tuple(v) if isinstance(v, list) else v
                                    for k, v in values.items()})
    except TypeError as exc:
        raise ScenarioError(f"scenario.generator: {exc}") from None
    q0, centers, radii, _ = generate(raws, sc.goal.position, kinematics, home, cfg,
                                     sc.goal.quaternion)
    made = [ObstacleConfig(tuple(c.tolist()), float(r)) for c, r in zip(centers, radii)]
    return replace(sc, q0=q0.tolist(), obstacles=[*(sc.obstacles or []), *made],
                   name=f"{sc.name}_{cfg.seed}")


def apply(run, kinematics) -> tuple[object, list[list[float]]]:
    """A typed run config with the demonstrations' part filled in, and the demonstrations'
    start configurations [rad] (empty unless needed): a task with ``derive`` and no goal gets
    the derived goal (:func:`tamedpuma.puma.task_from_demos.derive_goal`), the scenario its goal
    if unset, and a scenario with a ``generator: {kind: demos, ...}`` block its generated start
    and obstacles (added to any listed ones). The starts are for ``scenario=random`` with
    ``near_table1`` on a task without Table-1 starts (the IK solutions of the demonstrations'
    start poses): the caller hands them to
    :func:`tamedpuma.worlds.scenarios.build_scenario` with the Table-1 starts."""
    task, sc = run.task, run.scenario
    gen = sc.generator
    random_near = (sc.random_seed is not None and sc.start_kind == "near_table1"
                   and (task.derive or task.demos not in (None, "lasa")))
    need_goal = bool(task.derive) and (task.goal_position is None or task.workspace is None)
    if not need_goal and not gen and not random_near:
        return run, []
    raws = task_raws(task) if task.demos != "lasa" else []
    starts = _demo_starts(raws, kinematics, run.robot.home) if random_near else []
    if need_goal:
        task = _with_derived_goal(task, raws)
    goal = sc.goal
    if goal.position is None:
        goal = replace(goal, position=task.goal_position)
    if goal.quaternion is None:
        goal = replace(goal, quaternion=task.goal_quaternion or [0.0, 0.0, 0.0, 1.0])
    sc = replace(sc, goal=goal)
    if gen:
        sc = _generated(sc, gen, raws, kinematics, run.robot.home)
    return replace(run, task=task, scenario=sc), starts
