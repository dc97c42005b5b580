"""Per-run scalars from one run's trajectory (pure numpy; the same code serves the live episode
loop and the analysis of logs).

Definitions (``../shared/docs/experiments.md``, "Metrics"):

- success: the end-effector position comes within ``tolerance`` [m] of the (possibly moving) goal
  within the episode, and no collision happened up to then. Collision = any body sphere penetrating
  an obstacle sphere (clearance < 0) or a PyBullet robot–obstacle contact.
- time to success [s]: the first time the success condition holds.
- orientation error [rad]: the rotation angle between end-effector and goal orientation,
  ``2 arccos |⟨ζ, ζ_g⟩|``.
- computation time [ms]: wall time of the whole controller step.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


def orientation_error(quat: np.ndarray, goal_quat: np.ndarray) -> np.ndarray:
    """Angle [rad] of the rotation between unit quaternions (…, 4) and (…, 4), in [0, π]."""
    dot = np.abs(np.sum(np.asarray(quat) * np.asarray(goal_quat), axis=-1))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


@dataclass(frozen=True)
class RunMetrics:
    """Scalars of one run; times in seconds except ``compute_ms_*`` (milliseconds)."""

    steps: int
    duration_s: float
    success: bool
    success_with_orientation: bool
    time_to_success_s: float
    final_position_error_m: float
    final_orientation_error_rad: float
    min_clearance_m: float
    collided: bool
    obstacle_contact: bool
    ground_contact: bool
    joint_limit_violation_steps: int
    compute_ms_mean: float
    compute_ms_std: float
    compute_ms_median: float
    compute_ms_p99: float

    def as_dict(self) -> dict:
        return asdict(self)


def run_metrics(
    t: np.ndarray,
    position_error: np.ndarray,
    orientation_error: np.ndarray,
    clearance: np.ndarray,
    obstacle_contact: np.ndarray,
    ground_contact: np.ndarray,
    q: np.ndarray,
    q_min: np.ndarray,
    q_max: np.ndarray,
    compute_ms: np.ndarray,
    tolerance: float = 0.05,
    orientation_tolerance: float = 0.2,
    limit_tolerance: float = 1e-6,
) -> RunMetrics:
    """Metrics of one run from per-step arrays (T steps): t (T,) [s], end-effector position
    error to the goal (T,) [m], orientation error (T,) [rad], clearance (T,) [m], contact flags
    (T,), q (T, 7) [rad], compute_ms (T,). Works on live arrays and on arrays read from a log."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    if n == 0:
        raise ValueError("a run with no steps has no metrics")
    pos_err = np.asarray(position_error, dtype=float)
    rot_err = np.asarray(orientation_error, dtype=float)
    clearance = np.asarray(clearance, dtype=float)
    contact = np.asarray(obstacle_contact, dtype=bool)
    collision = (clearance < 0) | contact
    first_collision = int(np.argmax(collision)) if collision.any() else n
    reached = np.flatnonzero(pos_err[:first_collision] <= tolerance)
    success = reached.size > 0
    reached_o = np.flatnonzero((pos_err[:first_collision] <= tolerance)
                               & (rot_err[:first_collision] <= orientation_tolerance))
    q = np.asarray(q, dtype=float)
    violations = (q < q_min - limit_tolerance) | (q > q_max + limit_tolerance)
    ms = np.asarray(compute_ms, dtype=float)
    return RunMetrics(
        steps=n,
        duration_s=float(t[-1] - t[0]),
        success=bool(success),
        success_with_orientation=bool(reached_o.size > 0),
        time_to_success_s=float(t[reached[0]]) if success else float("nan"),
        final_position_error_m=float(pos_err[-1]),
        final_orientation_error_rad=float(rot_err[-1]),
        min_clearance_m=float(clearance.min()),
        collided=bool(collision.any()),
        obstacle_contact=bool(contact.any()),
        ground_contact=bool(np.any(ground_contact)),
        joint_limit_violation_steps=int(violations.any(axis=1).sum()),
        compute_ms_mean=float(ms.mean()),
        compute_ms_std=float(ms.std()),
        compute_ms_median=float(np.median(ms)),
        compute_ms_p99=float(np.percentile(ms, 99)),
    )
