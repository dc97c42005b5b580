"""Config -> :class:`Scenario`: parse, validate and, within a tolerance, clamp the start.

A scenario config (``conf/scenario/*.yaml``, goal usually interpolated from ``conf/task``) holds::

    name: default
    q0: [7 joint angles, rad]
    goal: {position: [x, y, z], quaternion: [x, y, z, w], velocity: [vx, vy, vz]}
    obstacles: [{center: [x, y, z], radius: r, velocity: [vx, vy, vz]}, ...]
    dt: 0.02           # control period [s]
    max_steps: 2000    # episode length limit (40 s)
    goal_tolerance: 0.05  # success radius [m]
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

import numpy as np

from tamedpuma.errors import ScenarioError
from tamedpuma.kinematics import RobotSpec
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


def obstacles_from_config(items) -> Obstacles:
    """A list of ``{center, radius, velocity?}`` mappings -> :class:`Obstacles`."""
    items = list(items or [])
    if not items:
        return Obstacles.empty()
    centers = [_vec(o["center"], 3, f"obstacles[{i}].center") for i, o in enumerate(items)]
    radii = [float(o["radius"]) for o in items]
    if any(not r > 0 for r in radii):
        raise ScenarioError("every obstacle radius must be positive")
    vels = [_vec(o.get("velocity") or [0, 0, 0], 3, f"obstacles[{i}].velocity")
            for i, o in enumerate(items)]
    return Obstacles(np.array(centers), np.array(radii), np.array(vels))


def scenario_from_config(cfg: Mapping, spec: RobotSpec, *, task: str, seed: int = 0,
                         limit_tolerance: float = 1e-4, limit_margin: float = 1e-3) -> Scenario:
    """Build a validated :class:`Scenario` from a (resolved) scenario config mapping."""
    try:
        goal_cfg = cfg["goal"]
        goal = Goal(
            position=_vec(goal_cfg["position"], 3, "goal.position"),
            quaternion=_vec(goal_cfg["quaternion"], 4, "goal.quaternion"),
            velocity=_vec(goal_cfg.get("velocity") or [0, 0, 0], 3, "goal.velocity"),
        )
        q0 = clamp_start(_vec(cfg["q0"], spec.dof, "q0"), spec, limit_tolerance, limit_margin)
        return Scenario(
            name=str(cfg["name"]),
            task=task,
            q0=q0,
            goal=goal,
            obstacles=obstacles_from_config(cfg.get("obstacles")),
            dt=float(cfg.get("dt", 0.02)),
            max_steps=int(cfg.get("max_steps", 2000)),
            goal_tolerance=float(cfg.get("goal_tolerance", 0.05)),
            seed=int(seed),
        )
    except KeyError as exc:
        raise ScenarioError(f"scenario config is missing the key {exc}") from exc
    except ValueError as exc:
        raise ScenarioError(f"invalid scenario: {exc}") from exc
