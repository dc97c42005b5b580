"""Random scenarios drawn the way the Table-1 ones look, deterministic for a seed.

One call, :func:`generate`, turns ``(task, seed, start kind)`` into a validated
:class:`~tamedpuma.types.Scenario`; the same arguments always give the same scenario. Drawing:

- **start** q0: ``near_table1``: one of the task's Table-1 starts (uniformly), plus
  ``N(0, start_sigma²)`` per joint [rad]; ``anywhere``: uniform in the joint range shrunk by
  ``limit_margin``. Either way q0 must lie inside the joint limits (by ``limit_margin``), the end
  effector inside the task's workspace (position relative to the goal in the box
  ``[position_low, position_high]`` and orientation within ``max_angle`` of the goal's, the region
  PUMA is trained on: ``conf/task/*.yaml``), and every body sphere ``ground_clearance`` above the
  ground;
- **goal**: the task goal moved by a uniform vector in the ball of radius ``goal_shift_max`` [m];
  with probability ``goal_moving_prob`` it moves at a constant horizontal velocity of speed
  ``U(0, goal_speed_max)`` [m/s] (Table 1: −0.01 and −0.001 m/s along x);
- **obstacles**: 1 or 2 spheres (equally likely) of radius ``U(radius_range)`` [m], each centred
  at ``p_ee(q0) + u (p_g − p_ee(q0)) + w`` with ``u ~ U(segment_range)`` and ``w`` uniform in the
  ball of radius ``lateral_max`` (near the straight start-goal segment, where they block the
  motion); each moves with probability ``obstacle_moving_prob`` at a horizontal velocity of speed
  ``U(obstacle_speed_range)`` [m/s] (Table 1: 0.01-0.05 m/s along x).

A draw is rejected, and the reason counted, when: q0 is outside the joint limits
(``joint_limits``), the end effector outside the workspace (``workspace``), a body sphere is
below ``ground_clearance`` (``ground``), a body sphere is within ``start_clearance`` of an
obstacle at t = 0 (``start_collision``), an obstacle reaches below the ground (``obstacle_ground``),
an obstacle comes within ``goal_clearance`` [m] (surface to point) of the goal at any time of the
episode (``goal_blocked``: the goal would be unreachable without contact), an obstacle comes
within ``base_clearance`` of the fixed base column (links 0-2, the z axis up to ``base_height``;
no body sphere covers it, so nothing could avoid it: ``base``), or the goal pose has no inverse
kinematics solution inside the joint limits (by ``limit_margin``) at t = 0 or, for a moving goal,
at a quarter, half, three quarters or the end of the episode (``goal_unreachable``: a goal that
moves out of the arm's reach, at up to 0.4 m over 40 s, ends a scenario no controller can
finish). The check draws nothing from the generator's random stream, so a draw it accepts is
the one the generator accepted without it.

numpy and the kinematics only (no simulator). The Hydra side is ``conf/scenario/random.yaml``
(``scenario=random scenario.random_seed=N scenario.start_kind=near_table1|anywhere``), built by
:func:`tamedpuma.worlds.scenarios.build_scenario`.
"""

from __future__ import annotations

import zlib
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from tamedpuma.errors import ScenarioError
from tamedpuma.robot.ik import solve_pose_ik
from tamedpuma.robot.rotations import orientation_error
from tamedpuma.types import Goal, Obstacles, Scenario

START_KINDS = ("near_table1", "anywhere")
REJECT_REASONS = ("joint_limits", "workspace", "ground", "start_collision", "obstacle_ground",
                  "goal_blocked", "base", "goal_unreachable")
#: the goal pose's IK (:func:`~tamedpuma.robot.ik.solve_pose_ik`): tolerance [m, rad] and the
#: seeded random starts besides the previous solution
REACH_TOLERANCE = 1e-4
REACH_RESTARTS = 16


@dataclass(frozen=True)
class TaskRegion:
    """What the generator needs of a task: name, goal pose (position [m], quaternion xyzw) and the
    workspace relative to the goal (position box [m], max orientation angle [rad])."""

    name: str
    goal_position: np.ndarray
    goal_quaternion: np.ndarray
    position_low: np.ndarray
    position_high: np.ndarray
    max_angle: float

    @staticmethod
    def from_task_config(task) -> TaskRegion:
        """From a typed ``task`` config (the schema's ``TaskSchema``, ``conf/task/*.yaml``)."""
        ws = task.workspace
        return TaskRegion(str(task.name), np.asarray(task.goal_position, dtype=float),
                          np.asarray(task.goal_quaternion, dtype=float),
                          np.asarray(ws.position_low, dtype=float),
                          np.asarray(ws.position_high, dtype=float), float(ws.max_angle))


@dataclass(frozen=True)
class RandomParams:
    """Generator parameters (see the module docstring); lengths [m], angles [rad], speeds [m/s].

    These defaults are the config defaults of ``scenario.random`` (the schema,
    ``tamedpuma/app/schema.py``, takes its ``scenario.random`` fields from this class). The
    scenario's own ``start_kind``, ``dt``, ``max_steps`` and ``goal_tolerance`` are arguments of
    :func:`generate`."""

    start_sigma: float = 0.3
    limit_margin: float = 0.02
    ground_clearance: float = 0.02
    goal_shift_max: float = 0.08
    goal_moving_prob: float = 0.25
    goal_speed_max: float = 0.01
    radius_range: tuple[float, float] = (0.04, 0.07)
    segment_range: tuple[float, float] = (0.25, 0.8)
    lateral_max: float = 0.1
    obstacle_moving_prob: float = 0.3
    obstacle_speed_range: tuple[float, float] = (0.01, 0.05)
    start_clearance: float = 0.05
    goal_clearance: float = 0.1
    base_clearance: float = 0.12
    base_height: float = 0.4
    max_tries: int = 20000

    def __post_init__(self):
        for name in ("radius_range", "segment_range", "obstacle_speed_range"):
            value = getattr(self, name)
            try:
                lo, hi = (float(v) for v in value)
            except (TypeError, ValueError):
                lo = hi = float("nan")
            if not 0 <= lo <= hi:
                raise ValueError(f"scenario.random.{name} must be [low, high] with "
                                 f"0 <= low <= high, got {list(value)}")
            object.__setattr__(self, name, (lo, hi))


@dataclass(frozen=True)
class Generated:
    """A generated scenario and the rejected draws before it, counted by reason."""

    scenario: Scenario
    tries: int
    rejected: Mapping[str, int]


def _rng(task: str, seed: int, start_kind: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(task.encode()),
                                  START_KINDS.index(start_kind)])


def _ball(rng: np.random.Generator, radius: float) -> np.ndarray:
    """A uniform point of the 3-D ball of ``radius``."""
    v = rng.normal(size=3)
    return v / max(np.linalg.norm(v), 1e-12) * radius * rng.uniform() ** (1.0 / 3.0)


def _horizontal(rng: np.random.Generator, speed: float) -> np.ndarray:
    phi = rng.uniform(0.0, 2.0 * np.pi)
    return np.array([np.cos(phi), np.sin(phi), 0.0]) * speed


def _draw_start(rng, kind, starts, q_min, q_max, p: RandomParams) -> np.ndarray:
    if kind == "near_table1":
        base = starts[rng.integers(len(starts))]
        return base + rng.normal(scale=p.start_sigma, size=base.shape)
    return rng.uniform(q_min + p.limit_margin, q_max - p.limit_margin)


def _check_start(q0, kinematics, region: TaskRegion, goal_p, goal_quat, p: RandomParams):
    """(reason or None, ee position, sphere centres) of a start."""
    spec = kinematics.spec
    if np.any(q0 < spec.q_min + p.limit_margin) or np.any(q0 > spec.q_max - p.limit_margin):
        return "joint_limits", None, None
    ee_p, ee_quat = kinematics.ee_pose(q0)
    rel = ee_p - goal_p
    if (np.any(rel < region.position_low) or np.any(rel > region.position_high)
            or orientation_error(ee_quat, goal_quat) > region.max_angle):
        return "workspace", None, None
    centers = kinematics.sphere_centers(q0)
    if np.min(centers[:, 2] - spec.sphere_radii) < p.ground_clearance:
        return "ground", None, None
    return None, ee_p, centers


def _check_obstacles(obstacles: Obstacles, goal: Goal, centers, radii, p: RandomParams,
                     horizon: float):
    """Reason or None for the obstacles, over the episode's ``horizon`` [s]."""
    c0, r = obstacles.centers, obstacles.radii
    if np.min(c0[:, 2] - r) < 0.0:
        return "obstacle_ground"
    gaps = np.linalg.norm(centers[:, None] - c0[None], axis=-1) - radii[:, None] - r[None]
    if gaps.min() < p.start_clearance:
        return "start_collision"
    t = np.linspace(0.0, horizon, 201)[:, None, None]
    oc = c0[None] + t * obstacles.velocities[None]  # (T, m, 3)
    g = goal.position + t[:, :, 0] * goal.velocity  # (T, 3)
    if np.min(np.linalg.norm(oc - g[:, None], axis=-1) - r) < p.goal_clearance:
        return "goal_blocked"
    height = np.clip(oc[..., 2], 0.0, p.base_height)
    axis_gap = np.hypot(oc[..., 0], oc[..., 1]) ** 2 + (oc[..., 2] - height) ** 2
    if np.min(np.sqrt(axis_gap) - r) < p.base_clearance:
        return "base"
    return None


def goal_reachable(goal: Goal, kinematics, q0: np.ndarray, p: RandomParams,
                   horizon: float) -> bool:
    """Whether the goal pose has an IK solution inside the joint limits by ``limit_margin`` at
    t = 0 and, for a moving goal, at each quarter of the ``horizon`` [s] (each solved from the
    one before, starting at q0, then from seeded starts: deterministic, and independent of the
    generator's random stream)."""
    times = np.linspace(0.0, horizon, 5) if np.any(goal.velocity != 0) else np.zeros(1)
    q = np.asarray(q0, dtype=float)
    for t in times:
        sol = solve_pose_ik(kinematics, goal.position + t * goal.velocity, goal.quaternion, q,
                            tolerance=REACH_TOLERANCE, margin=p.limit_margin,
                            restarts=REACH_RESTARTS)
        if not sol.converged:
            return False
        q = sol.q
    return True


def generate(region: TaskRegion, kinematics, seed: int, params: RandomParams,
             table1_starts: Sequence[Sequence[float]] = (), *, start_kind: str, dt: float,
             max_steps: int, goal_tolerance: float) -> Generated:
    """The scenario ``random_<task>_<start_kind>_<seed>`` (see the module docstring).

    region: the task's goal and workspace; kinematics: a
    :class:`~tamedpuma.robot.kinematics.Kinematics` (its spec gives the limits and body spheres);
    table1_starts: the task's Table-1 starts (n, dof) [rad] (needed for ``near_table1``);
    start_kind: one of :data:`START_KINDS`; dt [s], max_steps and goal_tolerance [m]: the
    scenario's (``scenario.*``; the obstacles are checked over the horizon max_steps·dt).
    Raises :class:`ScenarioError` if no valid draw is found in ``params.max_tries``.
    """
    kind = start_kind
    if kind not in START_KINDS:
        raise ScenarioError(f"scenario.start_kind must be one of {START_KINDS}, got {kind!r}")
    starts = np.asarray(table1_starts, dtype=float).reshape(-1, kinematics.spec.dof)
    if kind == "near_table1" and not len(starts):
        raise ScenarioError("start_kind near_table1 needs the task's Table-1 starts")
    spec = kinematics.spec
    radii = spec.sphere_radii
    rng = _rng(region.name, seed, kind)
    rejected: Counter[str] = Counter()
    goal_quat = region.goal_quaternion / np.linalg.norm(region.goal_quaternion)
    for tries in range(1, params.max_tries + 1):
        goal_p = region.goal_position + _ball(rng, params.goal_shift_max)
        goal_v = (_horizontal(rng, rng.uniform(0.0, params.goal_speed_max))
                  if rng.uniform() < params.goal_moving_prob else np.zeros(3))
        goal = Goal(goal_p, goal_quat, goal_v)
        q0 = _draw_start(rng, kind, starts, spec.q_min, spec.q_max, params)
        reason, ee_p, centers = _check_start(q0, kinematics, region, goal_p, goal_quat, params)
        if reason is None:
            n_obs = int(rng.integers(1, 3))
            c, r, v = [], [], []
            for _ in range(n_obs):
                u = rng.uniform(*params.segment_range)
                c.append(ee_p + u * (goal_p - ee_p) + _ball(rng, params.lateral_max))
                r.append(rng.uniform(*params.radius_range))
                v.append(_horizontal(rng, rng.uniform(*params.obstacle_speed_range))
                         if rng.uniform() < params.obstacle_moving_prob else np.zeros(3))
            obstacles = Obstacles(np.array(c), np.array(r), np.array(v))
            reason = _check_obstacles(obstacles, goal, centers, radii, params,
                                      max_steps * dt)
            if reason is None and not goal_reachable(goal, kinematics, q0, params,
                                                     max_steps * dt):
                reason = "goal_unreachable"
        if reason is None:
            scenario = Scenario(name=f"random_{region.name}_{kind}_{seed}", task=region.name,
                                q0=q0, goal=goal, obstacles=obstacles, dt=dt, max_steps=max_steps,
                                goal_tolerance=goal_tolerance, seed=int(seed))
            return Generated(scenario, tries, dict(rejected))
        rejected[reason] += 1
    raise ScenarioError(f"no valid random scenario for {region.name} seed {seed} "
                        f"({kind}) in {params.max_tries} draws: rejected {dict(rejected)}")


def scenario_config(scenario: Scenario) -> dict:
    """A generated scenario as a plain scenario config (``conf/scenario`` format), e.g. to save
    a failing draw as a fixed scenario file."""
    obs = scenario.obstacles
    return {"name": scenario.name, "task": scenario.task,
            "q0": [float(v) for v in scenario.q0],
            "goal": {"position": scenario.goal.position.tolist(),
                     "quaternion": scenario.goal.quaternion.tolist(),
                     "velocity": scenario.goal.velocity.tolist()},
            "obstacles": [{"center": c.tolist(), "radius": float(r), "velocity": v.tolist()}
                          for c, r, v in zip(obs.centers, obs.radii, obs.velocities)],
            "dt": scenario.dt, "max_steps": scenario.max_steps,
            "goal_tolerance": scenario.goal_tolerance}
