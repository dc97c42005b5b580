"""Config -> :class:`Scenario`: parse, validate and, within a tolerance, clamp the start.

A scenario config (``conf/scenario/*.yaml``, goal usually interpolated from ``conf/task``) holds::

    name: default
    q0: [the robot's joint angles, rad]   # null: the robot config's home
    goal: {position: [x, y, z], quaternion: [x, y, z, w], velocity: [vx, vy, vz]}
    obstacles: [{center: [x, y, z], radius: r, velocity: [vx, vy, vz]}, ...]
    dt: control period [s]
    max_steps: episode length limit
    goal_tolerance: success radius [m]

Defaults and ranges live in the config schema (``tamedpuma/app/schema.py``); these functions
receive its typed objects, complete and checked: the run config
(:class:`tamedpuma.app.schema.RunConfig`) or its groups, read by attribute (any object with the
same attributes will do, e.g. :class:`ObstacleConfig`). They never change what they are given.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace

import numpy as np

from tamedpuma.errors import ScenarioError
from tamedpuma.robot.kinematics import RobotSpec
from tamedpuma.types import Goal, Obstacles, Scenario

log = logging.getLogger(__name__)


def clamp_start(q0: np.ndarray, spec: RobotSpec, tolerance: float, margin: float) -> np.ndarray:
    """Return q0 inside the joint limits.

    A joint outside ``[q_min, q_max]`` by at most ``tolerance`` [rad] (or inside by less than
    ``margin``) is moved ``margin`` [rad] inside its limit, with a warning; a joint further out
    than ``tolerance`` raises :class:`ScenarioError`. Four of the paper's pouring starts put
    joint 2 at −2.0944, 5e-6 rad past its limit: they are clamped.
    """
    q0 = np.asarray(q0, dtype=float)
    if q0.shape != (spec.dof,):
        raise ScenarioError(f"q0 must have {spec.dof} joint angles, got {q0.shape[0]}")
    below = spec.q_min - q0
    above = q0 - spec.q_max
    worst = np.maximum(below, above)
    bad = np.flatnonzero(worst > tolerance)
    if bad.size:
        j = int(bad[0])
        raise ScenarioError(
            f"start q0[{j}] = {q0[j]:.6g} rad is outside joint {j + 1}'s limits "
            f"[{spec.q_min[j]:.6g}, {spec.q_max[j]:.6g}] by {worst[j]:.3g} rad "
            f"(more than the tolerance {tolerance:g})")
    lo, hi = spec.q_min + margin, spec.q_max - margin
    clamped = np.clip(q0, lo, hi)
    moved = np.flatnonzero(clamped != q0)
    for j in moved:
        where = ("outside" if worst[j] > 0 else "within")
        log.warning("start q0[%d] = %.7g rad is %s joint %d's limit [%.7g, %.7g] by %.2g rad; "
                    "clamped %.3g rad inside, to %.7g", j, q0[j], where, j + 1, spec.q_min[j],
                    spec.q_max[j], abs(worst[j]), margin, clamped[j])
    return clamped


def _vec(value, n: int, what: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"{what} must be {n} numbers, got {value!r}") from exc
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ScenarioError(f"{what} must be {n} finite numbers, got {value!r}")
    return arr


@dataclass(frozen=True)
class ObstacleConfig:
    """One entry of ``scenario.obstacles`` made here (a generated obstacle): the attributes of
    the schema's ``ObstacleSchema``. center (3,) [m], radius [m], velocity (3,) [m/s]."""

    center: tuple[float, ...]
    radius: float
    velocity: tuple[float, ...] = (0.0, 0.0, 0.0)


def obstacles_from_config(items) -> Obstacles:
    """A sequence of obstacle configs (``center``, ``radius``, ``velocity``) ->
    :class:`Obstacles`."""
    items = list(items or [])
    if not items:
        return Obstacles.empty()
    centers = [_vec(o.center, 3, f"obstacles[{i}].center") for i, o in enumerate(items)]
    radii = [float(o.radius) for o in items]
    if any(not r > 0 for r in radii):
        raise ScenarioError("every obstacle radius must be positive")
    vels = [_vec(o.velocity, 3, f"obstacles[{i}].velocity")
            for i, o in enumerate(items)]
    return Obstacles(np.array(centers), np.array(radii), np.array(vels))


def scenario_from_config(cfg, spec: RobotSpec, *, task: str, seed: int,
                         limit_tolerance: float, limit_margin: float) -> Scenario:
    """Build a validated :class:`Scenario` from a typed scenario config (the schema's
    ``ScenarioSchema``); seed: the run's; limit_tolerance, limit_margin [rad]: the robot's start
    clamp (:func:`clamp_start`, ``robot.limit_tolerance`` and ``robot.limit_margin``)."""
    try:
        goal_cfg = cfg.goal
        goal = Goal(
            position=_vec(goal_cfg.position, 3, "goal.position"),
            quaternion=_vec(goal_cfg.quaternion, 4, "goal.quaternion"),
            velocity=_vec(goal_cfg.velocity, 3, "goal.velocity"),
        )
        q0_cfg = cfg.q0 if cfg.q0 is not None else spec.home  # null: the robot's home
        if q0_cfg is None:
            raise ScenarioError("scenario q0 is null and the robot config has no home")
        q0 = clamp_start(_vec(q0_cfg, spec.dof, "q0"), spec, limit_tolerance, limit_margin)
        return Scenario(
            name=str(cfg.name),
            task=task,
            q0=q0,
            goal=goal,
            obstacles=obstacles_from_config(cfg.obstacles),
            dt=float(cfg.dt),
            max_steps=int(cfg.max_steps),
            goal_tolerance=float(cfg.goal_tolerance),
            seed=int(seed),
        )
    except AttributeError as exc:
        raise ScenarioError(f"scenario config is missing a key: {exc}") from exc
    except ValueError as exc:
        raise ScenarioError(f"invalid scenario: {exc}") from exc


def with_clutter(scenario: Scenario, count: int, radius: float, low, high, keep_out: np.ndarray,
                 min_distance: float, rng: np.random.Generator,
                 max_tries: int = 200_000) -> Scenario:
    """Add ``count`` static sphere obstacles of ``radius`` [m], uniform in the box
    [low, high] [m], each at least ``min_distance`` [m] (surface to point) from every point of
    ``keep_out`` (e.g. the start's body spheres, the end effector's start and the goal) and not
    overlapping the scenario's own obstacles or each other. Seeded by ``rng``: same seed, same
    clutter. Gives up with :class:`ScenarioError` after ``max_tries`` candidate centres."""
    if count <= 0:
        return scenario
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    own = scenario.obstacles
    keep_out = np.asarray(keep_out, dtype=float).reshape(-1, 3)
    chosen: list[np.ndarray] = []
    tries = 0
    while len(chosen) < count:
        batch = rng.uniform(low, high, size=(max(64, 2 * (count - len(chosen))), 3))
        tries += len(batch)
        d_keep = np.linalg.norm(batch[:, None] - keep_out[None], axis=-1).min(axis=1)
        ok = d_keep - radius >= min_distance
        if len(own):
            gap = (np.linalg.norm(batch[:, None] - own.centers[None], axis=-1)
                   - radius - own.radii[None])
            ok &= gap.min(axis=1) > 0
        for center in batch[ok]:  # no two clutter spheres overlap
            if len(chosen) == count:
                break
            if not chosen or np.linalg.norm(np.asarray(chosen) - center, axis=1).min() > 2 * radius:
                chosen.append(center)
        if tries > max_tries and len(chosen) < count:
            raise ScenarioError(f"cannot place {count} clutter obstacles of radius {radius} m in "
                                f"the box {low.tolist()}..{high.tolist()}: only {len(chosen)} fit")
    centers = np.concatenate([own.centers, np.array(chosen)])
    radii = np.concatenate([own.radii, np.full(count, radius)])
    vels = np.concatenate([own.velocities, np.zeros((count, 3))])
    return replace(scenario, obstacles=Obstacles(centers, radii, vels))


def without_obstacles(scenario: Scenario) -> Scenario:
    """The same scenario with no obstacle (for path differences to PUMA)."""
    return replace(scenario, obstacles=Obstacles.empty())


def arm_points(kinematics, q: np.ndarray, per_segment: int = 8) -> np.ndarray:
    """Points along the arm at q [m]: its body-sphere centres and ``per_segment`` points on every
    segment between consecutive link origins (the links' axes, which the five spheres leave
    uncovered), end effector included. Clutter kept ``min_distance`` from them clears the meshes
    (link radius < 0.1 m) and not only the spheres."""
    origins = kinematics.link_poses(q)[0]
    s = np.linspace(0.0, 1.0, per_segment)[:, None, None]
    along = (origins[:-1][None] + s * (origins[1:] - origins[:-1])[None]).reshape(-1, 3)
    return np.concatenate([kinematics.sphere_centers(q), along, kinematics.ee_pose(q)[0][None]])


def reach_problem(scenario: Scenario, kinematics) -> str | None:
    """Why the goal cannot be reached from any configuration, or None: it lies farther from
    the first link's origin than the arm spans (the sum of the distances between consecutive
    link origins and the end effector at ``q0`` [m], an upper bound of the reach)."""
    origins = kinematics.link_poses(scenario.q0)[0]
    chain = np.vstack([origins, kinematics.ee_pose(scenario.q0)[0][None]])
    span = float(np.linalg.norm(np.diff(chain, axis=0), axis=1).sum())
    distance = float(np.linalg.norm(scenario.goal.position - origins[0]))
    if distance <= span:
        return None
    where = ", ".join(f"{v:.2f}" for v in scenario.goal.position)
    return (f"the goal ({where}) m is {distance:.2f} m from the robot's base, beyond the "
            f"arm's reach ({span:.2f} m): the run cannot succeed")


def clutter_count(clutter, own: int) -> int:
    """How many clutter obstacles to add: ``clutter.total`` − the scenario's own ``own`` when a
    total is set (the obstacle-count sweep: 2, 10, 100, 1000 in all), else ``clutter.count``."""
    total = clutter.total
    if total is not None:
        if int(total) < own:
            raise ScenarioError(f"clutter.total={total} is below the scenario's own {own} "
                                f"obstacles")
        return int(total) - own
    return int(clutter.count)


#: a task's Table-1 start configurations q0 (n, dof) [rad] by task name (empty for a task
#: without them); the app layer reads them from the configs (``tamedpuma.app.config``)
StartsOf = Callable[[str], Sequence[Sequence[float]]]


def random_scenario(cfg, kinematics, table1_starts: StartsOf | None = None) -> Scenario:
    """The ``scenario=random`` scenario of a whole typed run config: drawn by
    :func:`tamedpuma.worlds.random_scenarios.generate` from ``scenario.random_seed``,
    ``scenario.start_kind`` and ``scenario.random`` (the task's goal and workspace);
    ``near_table1`` starts near ``table1_starts(task)`` (for a task without Table-1 starts the
    sweep hands down its demonstrations' starts: :func:`tamedpuma.worlds.demo_scenarios.apply`)."""
    from tamedpuma.worlds.random_scenarios import RandomParams, TaskRegion

    sc_cfg, task_cfg = cfg.scenario, cfg.task
    try:
        seed = int(sc_cfg.random_seed)
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"scenario.random_seed must be an integer, "
                            f"got {sc_cfg.random_seed!r}") from exc
    if task_cfg.workspace is None:
        raise ScenarioError(f"task {task_cfg.name!r} has no workspace: "
                            "scenario=random needs one")
    # scenario.random: the schema's typed block (null when the YAML has none: RandomParams' own)
    params = RandomParams() if sc_cfg.random is None else RandomParams(
        **{f.name: getattr(sc_cfg.random, f.name) for f in fields(RandomParams)})
    kind = str(sc_cfg.start_kind)
    region = TaskRegion.from_task_config(task_cfg)
    region = replace(region, goal_position=np.asarray(sc_cfg.goal.position, dtype=float),
                     goal_quaternion=np.asarray(sc_cfg.goal.quaternion, dtype=float))
    known = table1_starts(region.name) if table1_starts is not None else []
    starts = (known or []) if kind == "near_table1" else []
    generated = _generated(region, kinematics, seed, params, starts, start_kind=kind,
                           dt=float(sc_cfg.dt), max_steps=int(sc_cfg.max_steps),
                           goal_tolerance=float(sc_cfg.goal_tolerance))
    log.info("random scenario %s after %d draws (rejected: %s)", generated.scenario.name,
             generated.tries, generated.rejected)
    return generated.scenario


#: the last few generated scenarios of this process, by everything their draw depends on
_GENERATED: dict[bytes, object] = {}
_GENERATED_KEPT = 4


def _generated(region, kinematics, seed: int, params, starts, **scenario):
    """:func:`tamedpuma.worlds.random_scenarios.generate`, remembered for the last
    :data:`_GENERATED_KEPT` draws of this process: a sweep runs each random scenario with and
    without its obstacles back to back in one worker (~30 ms a draw on average, up to ~0.1 s with
    many rejections), and a draw is a function of its arguments (the scenario is frozen)."""
    import pickle

    from tamedpuma.worlds.random_scenarios import generate

    key = pickle.dumps((region, kinematics.spec, seed, params,
                        [[float(v) for v in q] for q in starts], sorted(scenario.items())))
    if key not in _GENERATED:
        if len(_GENERATED) >= _GENERATED_KEPT:
            del _GENERATED[next(iter(_GENERATED))]
        _GENERATED[key] = generate(region, kinematics, seed, params, starts, **scenario)
    return _GENERATED[key]


def build_scenario(cfg, spec: RobotSpec, kinematics,
                   reference: np.ndarray | Callable[[], np.ndarray] | None = None,
                   table1_starts: StartsOf | None = None) -> Scenario:
    """The run's scenario from a whole typed run config (``RunConfig``): the ``scenario``
    group checked against the ``task`` group, then ``without_obstacles`` and ``clutter``, seeded
    by ``seed`` and kept clear of (``clutter.keep_clear``) the arm at the start
    (:func:`arm_points`) and the goal ('start_goal'), or of the swept volume of ``reference``, a
    collision-free joint path (T, dof) [rad] to the goal in the scenario's own world (or a
    function returning it, called only when clutter is added), by
    ``clutter.margin`` [m] ('path': :mod:`tamedpuma.worlds.clutter`; the scene stays feasible).
    ``table1_starts``: a random scenario's ``near_table1`` starts (:func:`random_scenario`)."""
    sc_cfg, task = cfg.scenario, cfg.task.name
    if sc_cfg.task not in (None, task):
        raise ScenarioError(f"scenario {sc_cfg.name!r} belongs to task {sc_cfg.task!r}, "
                            f"not {task!r}: add task={sc_cfg.task}")
    robot = cfg.robot
    if sc_cfg.random_seed is not None:  # null in fixed scenarios
        scenario = random_scenario(cfg, kinematics, table1_starts)
    else:
        scenario = scenario_from_config(sc_cfg, spec, task=task, seed=int(cfg.seed),
                                        limit_tolerance=float(robot.limit_tolerance),
                                        limit_margin=float(robot.limit_margin))
    if cfg.without_obstacles:
        scenario = without_obstacles(scenario)
    clutter = cfg.clutter
    count = clutter_count(clutter, len(scenario.obstacles))
    if count <= 0:
        return scenario
    rng = np.random.default_rng([int(cfg.seed), 7919])
    if clutter.keep_clear == "path":
        path = reference() if callable(reference) else reference
        return with_path_clutter(scenario, count, clutter, kinematics, path, rng)
    keep_out = np.concatenate([arm_points(kinematics, scenario.q0),
                               scenario.goal.position[None]])
    return with_clutter(scenario, count, float(clutter.radius), clutter.low,
                        clutter.high, keep_out, float(clutter.min_distance), rng)


def with_path_clutter(scenario: Scenario, count: int, clutter, kinematics,
                      reference: np.ndarray | None, rng: np.random.Generator) -> Scenario:
    """``scenario`` plus ``count`` static spheres (``clutter.radius``, in the box
    ``clutter.low..high``, ``clutter.region``) kept ``clutter.margin`` [m] clear of the swept
    volume of ``reference`` (T, dof) [rad] (:func:`tamedpuma.worlds.clutter.place_clutter`; the
    arm: balls of ``clutter.arm_radius`` [m] round its skeleton)."""
    from tamedpuma.worlds.clutter import place_clutter, swept_volume

    if reference is None:
        raise ScenarioError("clutter.keep_clear=path needs a reference motion "
                            "(tamedpuma/app/reference.py)")
    reference = np.asarray(reference, dtype=float)
    if not np.allclose(reference[0], scenario.q0, atol=1e-6):
        raise ScenarioError("clutter.keep_clear=path: the reference motion does not start at "
                            "the scenario's q0")
    radius = float(clutter.radius)
    volume = swept_volume(kinematics, reference, arm_radius=float(clutter.arm_radius))
    own = scenario.obstacles
    centers = place_clutter(count, radius, clutter.low, clutter.high, volume,
                            float(clutter.margin), own.centers, own.radii, rng,
                            region=str(clutter.region), shell=float(clutter.shell))
    obstacles = Obstacles(np.concatenate([own.centers, centers]),
                          np.concatenate([own.radii, np.full(count, radius)]),
                          np.concatenate([own.velocities, np.zeros((count, 3))]))
    return replace(scenario, obstacles=obstacles)
