"""The safety suite's classification of one run and its tables (``python -m
tamedpuma.safety_suite``, :mod:`tamedpuma.app.safety_suite`).

A run is judged from its per-step signals (:class:`Trace`): the paper's criterion (the goal
reached before any body sphere penetrates an obstacle sphere), the whole-body criterion (also no
robot-obstacle contact, no ground contact and no joint-limit violation before the reach), and for
a failure the first class that applies (``contact``, ``ground``, ``joint_limit``, ``stall``,
``time``; for a paper success failing the whole-body criterion ``mesh``, ``ground``,
``joint_limit``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

STALL_SPEED = 0.05  #: ‖q̇‖ [rad/s] below which the last second counts as a stall


@dataclass(frozen=True)
class Trace:
    """Per-step signals of one run (arrays of one value per step).

    t [s]; error: the hand's distance to the goal [m]; clearance: the body spheres' smallest
    obstacle clearance [m] (< 0: penetration); contact, ground: PyBullet robot-obstacle and
    robot-ground contact; alpha: |α| the method logs [1/s]; speed_ratio: max_j |q̇_j|/q̇_max,j;
    command_ratio: max_j |q̇_j + q̈_j Δt|/q̇_max,j (> 1: the simulator's clamp acts); speed: ‖q̇‖
    [rad/s]; sphere_ground: the body spheres' lowest clearance to the ground [m];
    orientation_error [rad]; mesh_ground: the links' lowest hull point [m] (< 0: below the
    ground); q: joint positions (steps, dof) [rad]."""

    t: np.ndarray
    error: np.ndarray
    clearance: np.ndarray
    contact: np.ndarray
    ground: np.ndarray
    alpha: np.ndarray
    speed_ratio: np.ndarray
    command_ratio: np.ndarray
    speed: np.ndarray
    sphere_ground: np.ndarray
    orientation_error: np.ndarray
    mesh_ground: np.ndarray
    q: np.ndarray


@dataclass(frozen=True)
class Outcome:
    """The judgement of one run: the paper's and the whole-body success, the failure class
    ('' for a whole-body success), the first step within the goal tolerance (None if never)."""

    paper: bool
    whole_body: bool
    failure: str
    reached: int | None
    limit: np.ndarray  #: per step: a joint outside its limits


def classify(trace: Trace, goal_tolerance: float, dt: float, q_min, q_max) -> Outcome:
    """The success criteria and the failure class of one run (see the module)."""
    limit = np.any((trace.q < np.asarray(q_min) - 1e-6) | (trace.q > np.asarray(q_max) + 1e-6),
                   axis=1)
    ground = trace.ground | (trace.mesh_ground < 0)  # a link's mesh below the ground plane
    pen = trace.clearance < 0
    first_pen = int(np.argmax(pen)) if pen.any() else len(trace.t)
    reached = np.flatnonzero(trace.error[:first_pen] <= goal_tolerance)
    paper = reached.size > 0
    end = int(reached[0]) + 1 if paper else len(trace.t)
    mesh, on_ground, at_limit = trace.contact[:end].any(), ground[:end].any(), limit[:end].any()
    whole = paper and not (mesh or on_ground or at_limit)
    if paper:
        failure = "" if whole else ("mesh" if mesh else "ground" if on_ground else "joint_limit")
    elif pen.any():
        failure = "contact"
    elif ground.any():
        failure = "ground"
    elif limit.any():
        failure = "joint_limit"
    elif np.max(trace.speed[-int(1.0 / dt):]) < STALL_SPEED:
        failure = "stall"
    else:
        failure = "time"
    return Outcome(bool(paper), bool(whole), failure, int(reached[0]) if paper else None, limit)


def signals(trace: Trace, outcome: Outcome, ee_position: np.ndarray, q_min, q_max) -> dict:
    """The CSV's per-run signals: errors, path length, clearances, contacts, limits, α, speed."""
    q_end = trace.q[-1]
    return {
        "time_to_success": (float(trace.t[outcome.reached]) if outcome.reached is not None
                            else np.nan),
        "final_error": float(trace.error[-1]), "min_error": float(trace.error.min()),
        "max_error": float(trace.error.max()),
        "path_length": float(np.sum(np.linalg.norm(np.diff(ee_position, axis=0), axis=1))),
        "min_clearance": float(trace.clearance.min()),
        "min_ground_clearance": float(trace.sphere_ground.min()),
        "min_mesh_ground_clearance": float(trace.mesh_ground.min()),
        "mesh_contact": bool(trace.contact.any()), "ground_contact": bool(trace.ground.any()),
        "limit_steps": int(outcome.limit.sum()), "alpha_max": float(trace.alpha.max()),
        "speed_ratio_max": float(trace.speed_ratio.max()),
        "clamp_frac": float(np.mean(trace.command_ratio > 1.0)), "steps": len(trace.t),
        "end_at_limit": int(np.sum(np.minimum(q_end - q_min, q_max - q_end) < 0.05)),
        "end_orientation_error": float(trace.orientation_error[-1])}


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    """Per (task, kind, label): runs, success rates, the largest α and speed, clamp fraction and
    the failure classes counted."""
    g = df.groupby(["task", "kind", "label"])
    out = g.agg(n=("seed", "size"), paper=("success_paper", "mean"),
                whole_body=("success_whole_body", "mean"),
                oriented=("success_orientation_paper", "mean"), alpha_max=("alpha_max", "max"),
                speed_ratio_max=("speed_ratio_max", "max"), clamp_frac=("clamp_frac", "mean"))
    fails = df[df.failure != ""].groupby(["task", "kind", "label"])["failure"].agg(
        lambda s: " ".join(f"{k}:{v}" for k, v in s.value_counts().items()))
    return out.join(fails).fillna("")


def split_by_puma_limits(df: pd.DataFrame, puma_free: pd.DataFrame) -> pd.DataFrame:
    """Success per (task, kind, label), split by whether PUMA alone, on the same scenario
    without obstacles, drove a joint past its limit (``puma_free``: the suite's CSV of
    ``--methods puma --free``; its ``limit_steps`` > 0). Where PUMA's own motion needs a joint
    past its limit, a method that keeps the limits can only reach the goal by another route:
    the split says how much of a method's failure rate is that."""
    puma = puma_free[puma_free.method == "puma"]
    past = puma.assign(puma_past_limit=puma.limit_steps > 0)[
        ["task", "kind", "seed", "puma_past_limit"]]
    both = df.merge(past, on=["task", "kind", "seed"], how="inner")
    if both.empty:
        raise ValueError("no scenario of the runs is in the PUMA obstacle-free CSV")
    out = both.groupby(["task", "kind", "label", "puma_past_limit"]).agg(
        n=("seed", "size"), paper=("success_paper", "mean"),
        whole_body=("success_whole_body", "mean"))
    return out.unstack("puma_past_limit")
