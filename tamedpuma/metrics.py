"""Per-run scalars from one run's trajectory (pure numpy; the same code serves the live episode
loop and the analysis of logs).

Definitions (``../shared/docs/experiments.md``, "Metrics"). Let k_r be the first step at which the
end-effector position is within ``tolerance`` [m] of the (possibly moving) goal, t_r its time;
with a discrete disturbance (``disturbance_time``: a goal change or a push) only steps at or after
its onset count, so the run must reach the goal after the disturbance.

- **paper** success (the authors' ``check_distance_collision``): k_r exists, t_r < the time limit
  (40 s), and no body sphere of the robot's collision model penetrates an obstacle sphere
  (clearance < 0) at any step 0..k_r.
- **whole-body** success: the paper criterion, and also at every step 0..k_r no PyBullet
  robot–obstacle contact, no robot–ground contact and no joint outside its limits
  (by more than ``limit_tolerance`` [rad]).
- success with orientation (for either criterion): the run continues for ``settle_time`` [s]
  after t_r; at the first step k_s with t ≥ t_r + settle_time the position is still within
  ``tolerance``, the orientation error is ≤ ``orientation_tolerance`` [rad], and the criterion's
  collision conditions hold over 0..k_s. A log that ends before t_r + settle_time fails it.
- failure class (``failure_paper``, ``failure_whole_body``; empty on success): the first cause
  that occurred up to k_r (or the whole run if never reached), in the order of the steps:
  ``sphere_penetration``, ``obstacle_contact``, ``ground_contact``, ``joint_limit``; otherwise
  ``late`` (reached after the time limit), ``stall`` (the end effector moved less than
  ``stall_distance`` [m] over the last ``stall_window`` [s]) or ``time`` (still moving).
- **converged** (for either criterion): the hand comes to rest inside the goal ball after the
  reach. A step k is at rest when, over the ``rest_window`` [s] before it, the position error
  vector e = x_ee − x_g (the hand relative to the possibly moving goal) moved less than
  ``rest_distance`` [m] from e_k; k_c is the first step k ≥ k_r at rest with ‖e_k‖ ≤
  ``tolerance``. Converged: k_c exists, t_c < the time limit and the criterion's collision
  conditions hold over 0..k_c. **Converged with orientation**: the same at k_o, the first step
  k ≥ k_r at which the whole pose rests inside the ball (also the rotation vector of the error
  rotation, r = log(ζ ⊗ ζ_g⁻¹), moved less than ``rest_angle`` [rad] over the window: a hand
  still turning towards the goal orientation is not at rest), with the orientation error at
  k_o ≤ ``orientation_tolerance``. A hand that passes through the ball, or hovers in it
  without resting, has reached but not converged.
- left after reach: the position error exceeded ``tolerance`` at some step after k_r (the hand
  entered the ball and went out again); ``max_error_after_reach_m`` is the farthest it went.
- time to success [s]: t_r (NaN if never reached); rest time [s]: t_c (NaN if none).
- recovery time [s]: t_r − ``disturbance_time`` when a disturbance began at that time, the goal
  was first reached after it and the run succeeded under the whole-body criterion (else NaN).
- orientation error [rad]: the rotation angle between end-effector and goal orientation,
  ``2 arccos |⟨ζ, ζ_g⟩|``.
- computation time [ms]: wall time of the whole controller step; mean, std, median, p99 and max
  over every step of the run, and the first step's time on its own (the warm-up step: it is
  included in the statistics, and shown apart so a reader can see its weight).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

#: the logged scalars of the error vector x_ee − x_g [m] (the rest test's input from a log)
ERROR_VECTOR_FIELDS = ("position_error_x_m", "position_error_y_m", "position_error_z_m")
#: the logged scalars of the error rotation's vector r = log(ζ ⊗ ζ_g⁻¹) [rad] (the pose rest test)
ROTATION_VECTOR_FIELDS = ("orientation_error_x_rad", "orientation_error_y_rad",
                          "orientation_error_z_rad")

#: Collision causes in the order they are reported when several occur at the same step.
CAUSES = ("sphere_penetration", "obstacle_contact", "ground_contact", "joint_limit")
PAPER_CAUSES = ("sphere_penetration",)


@dataclass(frozen=True)
class RunMetrics:
    """Scalars of one run; times in seconds except ``compute_ms_*`` (the controller step's wall
    time) and ``compute_cpu_ms_*`` (its thread's CPU time; NaN for a log without it), both in
    milliseconds. ``success`` is the whole-body criterion (the stricter one)."""

    steps: int
    duration_s: float
    success_paper: bool
    success_whole_body: bool
    orientation_success_paper: bool
    orientation_success_whole_body: bool
    failure_paper: str
    failure_whole_body: str
    time_to_success_s: float
    recovery_time_s: float
    settle_time_s: float
    converged_paper: bool
    converged_whole_body: bool
    orientation_converged_paper: bool
    orientation_converged_whole_body: bool
    rest_time_s: float
    left_after_reach: bool
    max_error_after_reach_m: float
    final_position_error_m: float
    final_orientation_error_rad: float
    settled_orientation_error_rad: float
    min_clearance_m: float
    collided: bool
    sphere_penetration: bool
    obstacle_contact: bool
    ground_contact: bool
    joint_limit_violation_steps: int
    compute_ms_mean: float
    compute_ms_std: float
    compute_ms_median: float
    compute_ms_p99: float
    compute_ms_max: float
    compute_ms_first: float
    compute_cpu_ms_median: float = math.nan
    compute_cpu_ms_p99: float = math.nan
    compute_cpu_ms_max: float = math.nan

    @property
    def success(self) -> bool:
        """The whole-body criterion."""
        return self.success_whole_body

    def as_dict(self) -> dict:
        return asdict(self)


def _first(mask: np.ndarray) -> int:
    """Index of the first True in ``mask``, or len(mask)."""
    return int(np.argmax(mask)) if mask.any() else len(mask)


def _judge(causes: dict[str, np.ndarray], names: tuple[str, ...], reach: int | None,
           settle: int | None, n: int) -> tuple[bool, bool, str | None]:
    """(position success ignoring time, orientation window clean, first cause up to the reach or
    the end). ``reach``/``settle``: step indices or None."""
    end = reach if reach is not None else n - 1
    firsts = {name: _first(causes[name][: end + 1]) for name in names}
    first_step = min(firsts.values())
    cause = None
    if first_step <= end:
        cause = next(name for name in names if firsts[name] == first_step)
    clean_settle = settle is not None and not any(causes[name][: settle + 1].any()
                                                  for name in names)
    return cause is None and reach is not None, clean_settle, cause


def _failure_causes(clearance, obstacle_contact, ground_contact, q, q_min, q_max,
                    limit_tolerance: float) -> dict[str, np.ndarray]:
    """Per-step flags (T,) of each failure cause: a body sphere inside an obstacle (clearance
    < 0), a contact with an obstacle or the ground, a joint beyond its limit by more than
    ``limit_tolerance`` [rad]."""
    q = np.asarray(q, dtype=float)
    return {
        "sphere_penetration": clearance < 0,
        "obstacle_contact": np.asarray(obstacle_contact, dtype=bool),
        "ground_contact": np.asarray(ground_contact, dtype=bool),
        "joint_limit": ((q < q_min - limit_tolerance) | (q > q_max + limit_tolerance)).any(axis=1),
    }


def _reach_and_settle(t: np.ndarray, inside: np.ndarray, settle_time: float,
                      disturbance_time: float | None) -> tuple[int | None, int | None]:
    """Step indices of the first step inside the goal tolerance (at or after the disturbance, if
    any) and of the first step ``settle_time`` [s] later; None where there is none."""
    n = len(t)
    after = t >= disturbance_time - 1e-9 if disturbance_time is not None else np.ones(n, bool)
    reach = _first(inside & after)
    if reach >= n:
        return None, None
    k_s = _first(t >= t[reach] + settle_time - 1e-9)
    return reach, (k_s if k_s < n else None)


def at_rest(t: np.ndarray, error_vector: np.ndarray, rest_window: float,
            rest_distance: float, rotation_vector: np.ndarray | None = None,
            rest_angle: float = math.inf) -> np.ndarray:
    """Per step (T,): the error vector e (T, 3) [m] stayed within ``rest_distance`` [m] of e_k
    over the ``rest_window`` [s] before step k (False until a whole window has passed), and,
    given ``rotation_vector`` r (T, 3) [rad], r within ``rest_angle`` [rad] of r_k too."""
    t, e, r, start, full = _rest_windows(t, error_vector, rotation_vector, rest_window)
    out = np.zeros(len(t), dtype=bool)
    for k in np.nonzero(full)[0]:
        out[k] = _rest_at(k, start, e, r, rest_distance, rest_angle)
    return out


def _rest_windows(t, error_vector, rotation_vector, rest_window: float) -> tuple:
    """(t, e, r as arrays, the first step inside each step's window (T,), whether a whole
    window has passed at each step (T,))."""
    t = np.asarray(t, dtype=float)
    e = np.asarray(error_vector, dtype=float)
    r = None if rotation_vector is None else np.asarray(rotation_vector, dtype=float)
    start = np.searchsorted(t, t - rest_window + 1e-9)  # first step inside each window
    return t, e, r, start, t - t[0] >= rest_window - 1e-9


def _rest_at(k: int, start: np.ndarray, e: np.ndarray, r: np.ndarray | None,
             rest_distance: float, rest_angle: float) -> bool:
    """Step k of :func:`at_rest` (its window complete)."""
    return (_within(e[start[k]:k + 1], rest_distance)
            and (r is None or _within(r[start[k]:k + 1], rest_angle)))


def _within(window: np.ndarray, radius: float) -> bool:
    """Every row of ``window`` (m, 3) within ``radius`` of its last row."""
    d = window - window[-1]
    return bool(np.einsum("ij,ij->i", d, d).max() <= radius ** 2)


class RestMonitor:
    """:func:`at_rest` one step at a time (the episode loop's stop test): ``update(t, e, r)``
    returns whether step k is at rest, with the same window, distance and angle."""

    def __init__(self, rest_window: float, rest_distance: float, rest_angle: float = math.inf):
        self.window, self.distance, self.angle = rest_window, rest_distance, rest_angle
        self.t0: float | None = None
        self.times: deque[float] = deque()
        self.errors: deque[np.ndarray] = deque()
        self.rotations: deque[np.ndarray] = deque()

    def update(self, t: float, error_vector: np.ndarray, rotation_vector=None,
               check: bool = True) -> bool:
        """Record step (t, e, r); whether it is at rest (False without ``check``: the window is
        kept, the test not computed; without r, or with an infinite angle, the position alone)."""
        if self.t0 is None:
            self.t0 = t
        self.times.append(t)
        self.errors.append(np.array(error_vector, dtype=float))
        use_r = rotation_vector is not None and math.isfinite(self.angle)
        self.rotations.append(np.array(rotation_vector, dtype=float) if use_r else None)
        while self.times[0] < t - self.window + 1e-9:
            self.times.popleft()
            self.errors.popleft()
            self.rotations.popleft()
        if not check or t - self.t0 < self.window - 1e-9:
            return False
        if not _within(np.asarray(self.errors), self.distance):
            return False
        if not use_r or any(r is None for r in self.rotations):
            return True
        return _within(np.asarray(self.rotations), self.angle)


def rest_step(t, error_vector, inside: np.ndarray, reach: int | None, rest_window: float,
              rest_distance: float, rotation_vector=None,
              rest_angle: float = math.inf) -> int | None:
    """k_c: the first step at or after ``reach`` at rest (:func:`at_rest`) inside the ball."""
    if reach is None or error_vector is None:
        return None
    t, e, r, start, full = _rest_windows(t, error_vector, rotation_vector, rest_window)
    candidates = full & np.asarray(inside, dtype=bool)
    candidates[:reach] = False
    for k in np.nonzero(candidates)[0]:  # at_rest's test, only up to the first step it holds
        if _rest_at(k, start, e, r, rest_distance, rest_angle):
            return int(k)
    return None


def _rest_outcome(t, error_vector, inside, reach, rot_err, causes, time_limit: float,
                  orientation_tolerance: float, rest_test: tuple, rotation_vector) -> dict:
    """``converged_*`` at the position's rest step, ``orientation_converged_*`` at the pose's
    (without a rotation vector: the position's) and ``rest_time_s`` (the position's);
    a static goal's error vector may be the hand's position (it moves as e does)."""
    window, distance, angle = rest_test
    rest = rest_step(t, error_vector, inside, reach, window, distance)
    pose = rest
    if rotation_vector is not None and math.isfinite(angle):
        pose = rest_step(t, error_vector, inside, reach, window, distance, rotation_vector,
                         angle)
    out = _converged(causes, rest, time_limit, t, "converged")
    oriented = pose is not None and rot_err[pose] <= orientation_tolerance
    out.update(_converged(causes, pose, time_limit, t, "orientation_converged", oriented))
    return {**out, "rest_time_s": float(t[rest]) if rest is not None else float("nan")}


def _converged(causes, rest: int | None, time_limit: float, t, prefix: str,
               oriented: bool = True) -> dict:
    """``<prefix>_paper`` and ``<prefix>_whole_body``: at rest (step ``rest``) before the time
    limit, with no failure cause of the criterion up to it, and ``oriented``."""
    in_time = rest is not None and t[rest] < time_limit - 1e-9
    out = {}
    for label, names in (("paper", PAPER_CAUSES), ("whole_body", CAUSES)):
        clean = rest is not None and not any(causes[n][: rest + 1].any() for n in names)
        out[f"{prefix}_{label}"] = bool(clean and in_time and oriented)
    return out


def _after_reach(pos_err: np.ndarray, tolerance: float, reach: int | None) -> dict:
    """Whether the hand left the ball after the reach, and the farthest it went [m]."""
    if reach is None:
        return {"left_after_reach": False, "max_error_after_reach_m": float("nan")}
    after = pos_err[reach:]
    return {"left_after_reach": bool((after > tolerance).any()),
            "max_error_after_reach_m": float(after.max())}


def _stall_or_time(t: np.ndarray, ee_position, stall_window: float,
                   stall_distance: float) -> str:
    """A run that never reached the goal and never failed: ``stall`` if the end effector moved
    less than ``stall_distance`` [m] in the last ``stall_window`` [s] (known only with
    ``ee_position``), else ``time``."""
    if ee_position is not None:
        ee = np.asarray(ee_position, dtype=float)
        window = t >= t[-1] - stall_window
        if t[-1] - t[0] >= stall_window:
            moved = np.linalg.norm(ee[window] - ee[-1], axis=1).max()
            if moved < stall_distance:
                return "stall"
    return "time"


def _outcome(label: str, causes, names, reach, settle, in_time: bool, oriented: bool,
             stalled) -> dict:
    """``success_<label>``, ``orientation_success_<label>`` and ``failure_<label>`` judged on the
    causes ``names``: the first cause before the reach, else ``late`` (reached after the time
    limit), else ``stalled()`` (``stall`` or ``time``); empty on success."""
    ok, clean_settle, cause = _judge(causes, names, reach, settle, len(causes[names[0]]))
    success = ok and in_time
    if success:
        failure = ""
    elif cause or reach is not None:
        failure = cause or "late"
    else:
        failure = stalled()
    return {f"success_{label}": bool(success),
            f"orientation_success_{label}": bool(success and clean_settle and oriented),
            f"failure_{label}": failure}


def _recovery(t, reach: int | None, disturbance_time: float | None, success: bool) -> float:
    """t_r − onset when a disturbance began, the goal was first reached after it and the run
    succeeded (whole body); NaN otherwise [s]."""
    if disturbance_time is None or reach is None or not success or t[reach] < disturbance_time:
        return float("nan")
    return float(t[reach] - disturbance_time)


def _compute_stats(compute_ms, compute_cpu_ms=None) -> dict[str, float]:
    """Mean, std, median, p99, max and first of the controller's wall times per step [ms]; the
    median, p99 and max of its CPU times [ms] (NaN without them)."""
    ms = np.asarray(compute_ms, dtype=float)
    cpu = {}
    if compute_cpu_ms is not None and len(compute_cpu_ms):
        c = np.asarray(compute_cpu_ms, dtype=float)
        cpu = {"compute_cpu_ms_median": float(np.median(c)),
               "compute_cpu_ms_p99": float(np.percentile(c, 99)),
               "compute_cpu_ms_max": float(c.max())}
    return {"compute_ms_mean": float(ms.mean()), "compute_ms_std": float(ms.std()),
            "compute_ms_median": float(np.median(ms)),
            "compute_ms_p99": float(np.percentile(ms, 99)), "compute_ms_max": float(ms.max()),
            "compute_ms_first": float(ms[0]), **cpu}


def run_metrics(t: np.ndarray, position_error: np.ndarray, orientation_error: np.ndarray,
                clearance: np.ndarray, obstacle_contact: np.ndarray, ground_contact: np.ndarray,
                q: np.ndarray, q_min: np.ndarray, q_max: np.ndarray, compute_ms: np.ndarray,
                tolerance: float, orientation_tolerance: float = 0.2,
                limit_tolerance: float = 1e-6, time_limit: float = math.inf,
                settle_time: float = 0.0, ee_position: np.ndarray | None = None,
                stall_window: float = 2.0, stall_distance: float = 0.01,
                disturbance_time: float | None = None, error_vector: np.ndarray | None = None,
                rest_window: float = 1.0, rest_distance: float = 0.005,
                rotation_vector: np.ndarray | None = None, rest_angle: float = math.inf,
                compute_cpu_ms: np.ndarray | None = None) -> RunMetrics:
    """Metrics of one run from per-step arrays (T steps): t (T,) [s], end-effector position
    error to the goal (T,) [m], orientation error (T,) [rad], clearance (T,) [m], contact flags
    (T,), q (T, n) [rad], compute_ms (T,) [ms, wall], optional compute_cpu_ms (T,) [ms, the
    step thread's CPU time], optional ee_position (T, 3) [m] (for the stall class).
    tolerance [m]: the scenario's goal tolerance (``scenario.goal_tolerance``);
    time_limit [s]: the goal must be reached strictly before it (the episode horizon);
    settle_time [s]: how long after the reach the orientation is judged;
    error_vector (T, 3) [m]: x_ee − x_g per step, for the rest test (default: ee_position − the
    final goal, exact for a goal that does not move; without either no run converges);
    rest_window [s], rest_distance [m]: the rest test (:func:`at_rest`);
    rotation_vector (T, 3) [rad] and rest_angle [rad]: the pose's rest test (converged with
    orientation; without them it is judged at the position's rest). Live or logged arrays."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    if n == 0:
        raise ValueError("a run with no steps has no metrics")
    pos_err, rot_err, clearance = (np.asarray(a, dtype=float)
                                   for a in (position_error, orientation_error, clearance))
    causes = _failure_causes(clearance, obstacle_contact, ground_contact, q, q_min, q_max,
                             limit_tolerance)
    inside = pos_err <= tolerance
    reach, settle = _reach_and_settle(t, inside, settle_time, disturbance_time)
    in_time = reach is not None and t[reach] < time_limit - 1e-9
    oriented = (settle is not None and bool(inside[settle])
                and rot_err[settle] <= orientation_tolerance)

    stalled = lambda: _stall_or_time(t, ee_position, stall_window, stall_distance)  # noqa: E731
    result = {}
    for label, names in (("paper", PAPER_CAUSES), ("whole_body", CAUSES)):
        result.update(_outcome(label, causes, names, reach, settle, in_time, oriented, stalled))

    return RunMetrics(
        steps=n,
        duration_s=float(t[-1] - t[0]),
        **result,
        time_to_success_s=float(t[reach]) if reach is not None else float("nan"),
        recovery_time_s=_recovery(t, reach, disturbance_time, result["success_whole_body"]),
        settle_time_s=float(settle_time),
        **_rest_outcome(t, error_vector if error_vector is not None else ee_position, inside,
                        reach, rot_err, causes, time_limit, orientation_tolerance,
                        (rest_window, rest_distance, rest_angle), rotation_vector),
        **_after_reach(pos_err, tolerance, reach),
        final_position_error_m=float(pos_err[-1]),
        final_orientation_error_rad=float(rot_err[-1]),
        settled_orientation_error_rad=float(rot_err[settle] if settle is not None else np.nan),
        min_clearance_m=float(clearance.min()),
        **_collisions(causes),
        **_compute_stats(compute_ms, compute_cpu_ms),
    )


def _collisions(causes: dict) -> dict:
    """Whether each collision cause occurred in the run, and the steps past a joint limit."""
    return {"collided": bool(causes["sphere_penetration"].any()
                             or causes["obstacle_contact"].any()),
            "sphere_penetration": bool(causes["sphere_penetration"].any()),
            "obstacle_contact": bool(causes["obstacle_contact"].any()),
            "ground_contact": bool(causes["ground_contact"].any()),
            "joint_limit_violation_steps": int(causes["joint_limit"].sum())}
