"""A task from its demonstrations alone: goal, workspace and model step Δt derived from the data,
and the check that a hand-set workspace holds the demonstrations and the scenario starts.

Goal. Position p_g = mean of the demonstrations' final positions. Orientation: the final
orientations ζ_i are sign-aligned to the first; if their largest pairwise angle is at most
``spread_limit`` the goal is their normalised chordal mean, otherwise (pouring_v2's final
orientations spread 136°) no mean is meaningful and the goal is the *medoid*: the demonstrated
final orientation with the smallest summed angle to the others (an orientation a demonstration
actually ended in). Training is unaffected (goal convention ``final_pose``: each demonstration is
learned relative to its own final pose, so the model converges to whatever goal it is given); the
derived goal is only the task's default goal for scenarios. The spread is reported.

Workspace (relative to the goal, as :class:`~tamedpuma.puma.training.Workspace`). Positions:
the bounding box of every demonstration sample both relative to its own final position
(``p − p_end``, what training sees) and relative to the derived goal (``p − p_g``, where scenario
starts near the demonstrations' starts lie), enlarged by ``margin`` [m] on each side.
Orientations: the largest angle of any sample to its own final orientation or to the goal
orientation, plus ``angle_margin`` [rad], capped at π.

Δt: the median sample period of the data, rounded to 1 ms, times the smallest integer that
makes it at least ``min_dt`` [s] (a finer model step only slows training down).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ConfigError, DataError
from ..robot.rotations import orientation_error
from .data import RawDemo

if TYPE_CHECKING:
    from .training import Workspace


@dataclass(frozen=True)
class DerivedTask:
    """What :func:`derive` found; ``as_dict`` is written into the checkpoint's report."""

    goal_position: tuple[float, ...]
    goal_quaternion: tuple[float, ...] | None
    goal_rule: str                  # "mean" or "medoid" (orientation), see the module docstring
    final_position_spread: float    # largest distance of a final position from p_g [m]
    final_angle_spread: float       # largest angle between two final orientations [rad]
    workspace: Workspace
    margin: float                   # [m]
    angle_margin: float             # [rad]
    dt: float                       # model step [s]
    data_period: float              # median sample period of the data [s]
    n_demos: int

    def as_dict(self) -> dict:
        return {"goal_position": list(self.goal_position),
                "goal_quaternion": None if self.goal_quaternion is None
                else list(self.goal_quaternion),
                "goal_rule": self.goal_rule,
                "final_position_spread_m": self.final_position_spread,
                "final_angle_spread_rad": self.final_angle_spread,
                "workspace": {"position_low": list(self.workspace.low),
                              "position_high": list(self.workspace.high),
                              "max_angle": self.workspace.max_angle},
                "margin_m": self.margin, "angle_margin_rad": self.angle_margin,
                "dt": self.dt, "data_period_s": self.data_period, "n_demos": self.n_demos}


def derive_goal(raws: list[RawDemo], spread_limit: float = np.deg2rad(30.0)):
    """(goal position (3,), goal quaternion (4,) or None, rule) without torch (for the sweep)."""
    goal_p = np.array([r.pos[-1] for r in raws]).mean(0)
    if raws[0].quat is None:
        return goal_p, None, "none"
    q, rule, _ = goal_orientation(np.array([r.quat[-1] for r in raws]), spread_limit)
    return goal_p, q, rule


def workspace_numbers(raws: list[RawDemo], goal_p, goal_q, margin: float,
                      angle_margin: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(position_low, position_high, max_angle) of the derived workspace (module docstring)."""
    goal_p = np.asarray(goal_p, float)
    rel = np.concatenate([np.concatenate([r.pos - r.pos[-1], r.pos - goal_p]) for r in raws])
    low, high = rel.min(0) - margin, rel.max(0) + margin
    high = np.maximum(high, low + 1e-6)
    max_angle = 0.0
    if raws[0].quat is not None and goal_q is not None:
        worst = max(max(orientation_error(r.quat, r.quat[-1]).max(),
                        orientation_error(r.quat, goal_q).max())
                    for r in raws)
        max_angle = float(min(np.pi, worst + angle_margin))
    return low, high, max_angle


def goal_orientation(finals: np.ndarray, spread_limit: float) -> tuple[np.ndarray, str, float]:
    """(goal quaternion, rule, largest pairwise angle [rad]) of final orientations (D, 4)."""
    q = finals / np.linalg.norm(finals, axis=1, keepdims=True)
    q = q * np.where(q @ q[0] < 0, -1.0, 1.0)[:, None]
    pair = orientation_error(q[:, None], q[None])
    spread = float(pair.max())
    if spread <= spread_limit:
        mean = q.mean(0)
        return mean / np.linalg.norm(mean), "mean", spread
    return q[int(np.argmin(pair.sum(1)))], "medoid", spread


def model_step(raws: list[RawDemo], min_dt: float) -> tuple[float, float]:
    """(model Δt, median data period) [s]; see the module docstring."""
    period = float(np.median(np.concatenate([r.delta_t[1:] for r in raws])))
    base = max(round(period, 3), 1e-3)
    return float(round(base * max(1, int(np.ceil(min_dt / base - 1e-9))), 6)), period


def derive(raws: list[RawDemo], *, margin: float = 0.05, angle_margin: float = 0.15,
           spread_limit: float = np.deg2rad(30.0), min_dt: float = 0.02) -> DerivedTask:
    """Goal, workspace and Δt of a set of demonstrations (see the module docstring)."""
    from .training import Workspace  # torch: only when a workspace is built
    if not raws:
        raise DataError("no demonstrations")
    if margin < 0 or angle_margin < 0:
        raise ConfigError("task.margin and task.angle_margin must be >= 0")
    finals = np.array([r.pos[-1] for r in raws])
    goal_p = finals.mean(0)
    goal_q, rule, spread = None, "none", 0.0
    if raws[0].quat is not None:
        goal_q, rule, spread = goal_orientation(np.array([r.quat[-1] for r in raws]),
                                                spread_limit)
    low, high, max_angle = workspace_numbers(raws, goal_p, goal_q, margin, angle_margin)
    dt, period = model_step(raws, min_dt)
    return DerivedTask(
        goal_position=tuple(float(v) for v in goal_p),
        goal_quaternion=None if goal_q is None else tuple(float(v) for v in goal_q),
        goal_rule=rule,
        final_position_spread=float(np.linalg.norm(finals - goal_p, axis=1).max()),
        final_angle_spread=spread,
        workspace=Workspace(tuple(float(v) for v in low), tuple(float(v) for v in high),
                            max_angle),
        margin=float(margin), angle_margin=float(angle_margin), dt=dt, data_period=period,
        n_demos=len(raws))


@dataclass(frozen=True)
class Excursion:
    """How far a set of points leaves a workspace: ``distance`` [m] outside the box (largest
    over the points), ``angle`` [rad] beyond max_angle, and which item it is."""

    what: str
    distance: float
    angle: float

    def __str__(self) -> str:
        parts = []
        if self.distance > 0:
            parts.append(f"{self.distance:.3f} m outside the position box")
        if self.angle > 0:
            parts.append(f"{np.rad2deg(self.angle):.1f} deg beyond max_angle")
        return f"{self.what}: " + " and ".join(parts)


def excursion(rel_pos: np.ndarray, rel_angle: np.ndarray | None, ws: Workspace,
              what: str) -> Excursion | None:
    """Points ``rel_pos`` (N, 3) relative to the goal and their angles to it (N,) vs ``ws``."""
    lo, hi = np.asarray(ws.low), np.asarray(ws.high)
    rel_pos = np.asarray(rel_pos, float).reshape(-1, len(lo))
    out = np.maximum(lo - rel_pos, 0.0) + np.maximum(rel_pos - hi, 0.0)
    dist = float(np.linalg.norm(out, axis=1).max()) if len(rel_pos) else 0.0
    ang = 0.0
    if rel_angle is not None and len(rel_angle) and ws.max_angle > 0:
        ang = float(max(0.0, np.max(rel_angle) - ws.max_angle))
    if dist <= 1e-9 and ang <= 1e-9:
        return None
    return Excursion(what, dist, ang)


def demo_excursions(raws: list[RawDemo], ws: Workspace) -> list[Excursion]:
    """Each demonstration that leaves ``ws`` (relative to its own final pose, as trained)."""
    out = []
    for r in raws:
        ang = None if r.quat is None else orientation_error(r.quat, r.quat[-1])
        ex = excursion(r.pos - r.pos[-1], ang, ws, f"demonstration {r.source}")
        if ex:
            out.append(ex)
    return out


def start_excursions(starts: list[tuple[str, np.ndarray, np.ndarray | None]], goal_p, goal_q,
                     ws: Workspace) -> list[Excursion]:
    """Each scenario start (name, ee position, ee quaternion) that leaves ``ws`` around the goal."""
    out = []
    for name, p, q in starts:
        ang = None if q is None or goal_q is None else np.atleast_1d(orientation_error(q, goal_q))
        ex = excursion(np.asarray(p) - np.asarray(goal_p), ang, ws, f"scenario start {name}")
        if ex:
            out.append(ex)
    return out
