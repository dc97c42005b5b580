"""Seeded synthetic demonstrations for the tomato and pouring tasks (no external data needed).

Each demonstration is a critically damped reach
``s(τ) = (1 − (1 + aτ)e^{−aτ}) / (1 − (1 + a)e^{−a})`` (a = 8: it starts at rest and approaches the
goal exponentially, speed proportional to the remaining distance at the end, like a stable
dynamical system; a minimum-jerk law's polynomial tail ``v ∝ d^{2/3}`` taught PUMA to creep: 2% of
random starts within 1 cm after 40 s) from a random start pose to the task's goal pose, with a
smooth lateral detour ``16 s²(1 − s)²`` through a random via offset (largest half way along the
path), sampled at about 33 Hz (Δt ≈ 0.030 s with small jitter, like the real KUKA recordings),
positions [m] and orientations slerped along the same time law. Start regions, rotation angles
and rotation axes follow the real demonstrations' (the start relative to the final pose of each
demonstration in ``pick_tomato_31may`` and ``pouring_v2``; the numbers are at ``TASKS``). The
axes matter: with pouring's about (1, 0.2, 0.1) instead of the real (0.64, −0.70, −0.12), the
default scenario's start (2.25 rad about (0.65, −0.72, 0.22) from the goal) lies far outside the
data, and PUMA alone sweeps the joints through their range from there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..robot.rotations import quat_mul
from . import manifold
from .data import RawDemo


@dataclass(frozen=True)
class SyntheticTask:
    """Start region relative to the goal: mean offset [m] ± spread [m], rotation angle range."""

    start_offset: tuple[float, float, float]
    start_spread: tuple[float, float, float]
    angle_range: tuple[float, float]  # [rad]
    rotation_axis: tuple[float, float, float]
    duration: tuple[float, float]  # [s]


TASKS = {
    # tomato: pick_tomato_31may (10 demonstrations: offset mean (−0.02, 0.46, 0.20) m, within
    # (−0.24..0.14, 0.12..0.61, −0.05..0.57); rotations 1.04-1.39 rad about axes around
    # (0.90, −0.32, 0.21))
    "tomato": SyntheticTask((-0.02, 0.4, 0.25), (0.15, 0.2, 0.25), (1.05, 1.4), (0.90, -0.32, 0.21),
                            (8.0, 10.0)),
    # pouring: offsets and rotation axis of pouring_v2 (38 demonstrations, start relative to
    # final pose: offset mean (0.13, 0.11, 0.01) m, within (−0.33..0.50, −0.13..0.34,
    # −0.16..0.32); rotations 0.4-2.3 rad about axes around (0.64, −0.70, −0.12))
    "pouring": SyntheticTask((0.13, 0.11, 0.05), (0.3, 0.2, 0.2), (1.2, 2.3), (0.64, -0.70, -0.12),
                             (9.0, 13.0)),
    # a short reach with a small twist (the Franka Panda's task panda_reach: from about its
    # ready pose down and to the side)
    "reach": SyntheticTask((-0.15, 0.25, 0.25), (0.08, 0.08, 0.06), (0.2, 0.5), (0.0, 0.3, 1.0),
                           (5.0, 7.0)),
}


def _approach(tau: np.ndarray, a: float = 8.0) -> np.ndarray:
    """Critically damped time law on τ ∈ [0, 1]: s(0) = 0, s'(0) = 0, s(1) = 1."""
    return (1.0 - (1.0 + a * tau) * np.exp(-a * tau)) / (1.0 - (1.0 + a) * np.exp(-a))


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk time law ``s(τ) = 10τ³ − 15τ⁴ + 6τ⁵`` (rest to rest; slow polynomial tail)."""
    return 10 * tau**3 - 15 * tau**4 + 6 * tau**5


TIME_LAWS = {"approach": _approach, "min_jerk": _min_jerk}


def generate(task: str, goal_position, goal_quaternion, n_demos: int = 10, seed: int = 0,
             period: float = 0.030, time_law: str = "approach") -> list[RawDemo]:
    """``n_demos`` seeded demonstrations of ``task`` (a key of ``TASKS``) ending at the goal,
    along ``time_law`` (a key of ``TIME_LAWS``)."""
    if time_law not in TIME_LAWS:
        raise ConfigError(f"unknown synthetic time law {time_law!r}; one of {sorted(TIME_LAWS)}")
    if task not in TASKS:
        raise ConfigError(f"no synthetic demonstrations for task '{task}' "
                          f"(one of: {', '.join(TASKS)}); set task.demos to a folder")
    spec = TASKS[task]
    rng = np.random.default_rng(seed)
    goal_p = np.asarray(goal_position, float)
    goal_q = np.asarray(goal_quaternion, float)
    goal_q = goal_q / np.linalg.norm(goal_q)
    axis0 = np.asarray(spec.rotation_axis) / np.linalg.norm(spec.rotation_axis)
    demos = []
    for i in range(n_demos):
        start = goal_p + np.asarray(spec.start_offset) + rng.uniform(-1, 1, 3) * spec.start_spread
        via = rng.normal(scale=0.06, size=3)
        axis = axis0 + rng.normal(scale=0.15, size=3)
        axis /= np.linalg.norm(axis)
        rotvec0 = axis * rng.uniform(*spec.angle_range)  # start orientation relative to the goal
        duration = rng.uniform(*spec.duration)
        dts = period + rng.normal(scale=2e-4, size=int(duration / period) + 1)
        t = np.concatenate(([0.0], np.cumsum(dts[1:])))
        tau = np.clip(t / t[-1], 0.0, 1.0)
        if time_law == "min_jerk":  # the detour as first generated: a bump in time
            s, bump = _min_jerk(tau)[:, None], (16 * tau**2 * (1 - tau) ** 2)[:, None]
        else:
            s = TIME_LAWS[time_law](tau)[:, None]
            bump = 16 * s**2 * (1 - s) ** 2  # the detour peaks half way along the path
        pos = start + s * (goal_p - start) + bump * via
        rel = manifold.np_quat_exp((1.0 - s) * rotvec0)
        quat = quat_mul(rel, goal_q[None])
        dts[0] = 1e-6
        demos.append(RawDemo(pos, quat, dts, f"synthetic:{task}[{i}]"))
    return demos
