"""Damped least-squares inverse kinematics for an end-effector pose (position and orientation).

Iterates ``q ← clip(q + Jᵀ(J Jᵀ + λ² I)⁻¹ e, q_min + m, q_max − m)`` with the 6-D pose error
``e = [p_g − p; log(R_g Rᵀ)]`` [m, rad] in the world frame until ‖e‖ is below the tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tamedpuma.robot.kinematics import Kinematics
from tamedpuma.robot.rotations import quat_to_matrix, rotation_error


@dataclass(frozen=True)
class PoseIKSolution:
    """q: solution [rad]; position_error [m]; orientation_error [rad]; iterations; converged."""

    q: np.ndarray
    position_error: float
    orientation_error: float
    iterations: int
    converged: bool


def pose_dls(kin: Kinematics, position, goal_rot, q, lo, hi, damping, tolerance,
             max_iterations,
             patience: int = 0, rotation_weight: float = 1.0):
    """Damped least squares on the pose error from q, clipped to [lo, hi] (the module's
    iteration), until ‖e‖ < tolerance, ``max_iterations``, or, with ``patience`` > 0, once that
    many iterations have not reduced ‖e‖ by 1 % (stuck on the limits): (q, e, iterations); e is
    the error at the last q evaluated. ``rotation_weight`` scales the orientation rows of e and J
    (0: the position alone, the orientation free; e's orientation part is then 0)."""
    return run_to_end(pose_dls_steps(kin, position, goal_rot, q, lo, hi, damping, tolerance,
                                     max_iterations, patience, rotation_weight))


def run_to_end(steps):
    """The return value of a generator run to its end (its yields discarded)."""
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def pose_dls_steps(kin: Kinematics, position, goal_rot, q, lo, hi, damping, tolerance,
                   max_iterations, patience: int = 0, rotation_weight: float = 1.0):
    """:func:`pose_dls` one iteration at a time: a generator that yields before each kinematic
    pass and returns (q, e, iterations), so that a caller can spread the solve over control
    steps (an anytime computation with a bounded cost per step)."""
    rows = np.array([1.0, 1.0, 1.0] + [rotation_weight] * 3)
    damped = damping**2 * np.eye(6)  # λ²I
    err = np.full(6, np.inf)
    best, since = np.inf, 0
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007 (count returned)
        yield  # before the pass: its state is used before the next yield
        ee_position, ee_rotation, ee_jacobian = kin.ee_pose_jacobian(q)  # = evaluate's
        err = rows * np.concatenate([position - ee_position,
                                     rotation_error(ee_rotation, goal_rot)])
        norm = math.sqrt(err.dot(err))  # = np.linalg.norm(err), without its wrapper
        if norm < tolerance:
            break
        if patience > 0:
            if norm < 0.99 * best:
                best, since = norm, 0
            else:
                since += 1
                if since >= patience:
                    break
        jac = rows[:, None] * ee_jacobian
        step = jac.T @ np.linalg.solve(jac @ jac.T + damped, err)
        q = np.minimum(np.maximum(q + step, lo), hi)  # = np.clip(q + step, lo, hi)
    return q, err, it


def solve_pose_ik(kin: Kinematics, position: np.ndarray, quaternion: np.ndarray,
                  q_init: np.ndarray, damping: float = 1e-2, tolerance: float = 1e-5,
                  max_iterations: int = 300, margin: float = 0.05, restarts: int = 16,
                  seed: int = 0) -> PoseIKSolution:
    """Joint configuration reaching the pose (position [m], quaternion (x, y, z, w)).

    Starts from ``q_init``; if that does not converge (a local minimum at the joint limits), from
    up to ``restarts`` seeded random configurations, keeping the first that converges (or the
    smallest error). Deterministic for a given seed.
    """
    spec = kin.spec
    position = np.asarray(position, dtype=float)
    goal_rot = quat_to_matrix(quaternion)
    lo, hi = spec.q_min + margin, spec.q_max - margin
    rng = np.random.default_rng(seed)
    starts = [np.clip(np.asarray(q_init, dtype=float), lo, hi)]
    starts += [rng.uniform(lo, hi) for _ in range(restarts)]
    best = None
    total = 0
    for start in starts:
        q, err, it = pose_dls(kin, position, goal_rot, start, lo, hi, damping, tolerance,
                          max_iterations)
        total += it
        if best is None or np.linalg.norm(err) < np.linalg.norm(best[1]):
            best = (q, err)
        if np.linalg.norm(err) < tolerance:
            break
    q, err = best
    return PoseIKSolution(q=q, position_error=float(np.linalg.norm(err[:3])),
                    orientation_error=float(np.linalg.norm(err[3:])), iterations=total,
                    converged=bool(np.linalg.norm(err) < tolerance))
