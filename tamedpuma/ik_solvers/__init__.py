"""Collision-aware inverse kinematics behind a small backend registry (qpsolvers style).

    result = solve_ik(problem, backend="drake")      # or "slsqp"

Every backend solves the same :class:`IKProblem` (equations in :mod:`.problem`); ``solve_ik`` then
checks the answer independently with pinocchio (one placement pass, which also gives the end
effector's position at the answer): a result is a success only if the solver says so
AND every bound and distance constraint holds within ``problem.tolerance``. A failed solve never
returns an unsafe configuration when a safe one is known: it returns the solver's iterate if that
satisfies the constraints, else ``q_start`` if that does, else whichever of the two violates less
(with ``max_violation`` saying by how much).

Backends (module ``tamedpuma/ik_solvers/<name>.py``, each exposing ``solve(problem) -> IKResult``
and ``warm_up(kinematics, radii)``):

- ``drake``: Drake's ``InverseKinematics`` with ``AddMinimumDistanceLowerBoundConstraint``, SNOPT
  (the solver the paper cites; needs ``pip install drake``);
- ``slsqp``: SciPy SLSQP with our vectorised distance constraints and analytic Jacobians (no extra
  dependency).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from tamedpuma.errors import ConfigError

from . import drake, slsqp
from .problem import (
    IKProblem,
    IKResult,
    SolverOptions,
    distances,
    objective,
    placement,
    reach_bounds,
    violation,
)

#: name -> solve(problem) -> IKResult
BACKENDS: dict[str, Callable[[IKProblem], IKResult]] = {"drake": drake.solve, "slsqp": slsqp.solve}

DEFAULT_BACKEND = "drake"

#: name -> warm_up(kinematics, obstacle_radii): one-off set-up (imports, model builds) to run
#: before a timed loop
WARM_UP: dict[str, Callable] = {"drake": drake.warm_up, "slsqp": slsqp.warm_up}

__all__ = ["BACKENDS", "DEFAULT_BACKEND", "IKProblem", "IKResult", "SolverOptions",
           "available_backends", "distances", "objective", "placement", "reach_bounds", "solve_ik",
           "violation", "warm_up"]


def available_backends() -> list[str]:
    """The backends whose dependencies are installed."""
    return [name for name in BACKENDS if name != "drake" or drake.available()]


def warm_up(kinematics, obstacle_radii, backend: str = DEFAULT_BACKEND) -> None:
    """Do ``backend``'s one-off set-up for this robot and these obstacle radii [m] (optional: the
    first solve does it otherwise, and its time then includes it)."""
    if backend in WARM_UP:
        WARM_UP[backend](kinematics, np.asarray(obstacle_radii, float))


def solve_ik(problem: IKProblem, backend: str = DEFAULT_BACKEND) -> IKResult:
    """Solve ``problem`` with ``backend`` and check the answer (module docstring)."""
    if backend not in BACKENDS:
        raise ConfigError(f"unknown ik backend {backend!r}; choose one of {sorted(BACKENDS)}")
    raw = BACKENDS[backend](problem)
    q = np.asarray(raw.q, float)
    if not np.all(np.isfinite(q)) or q.shape != problem.q_start.shape:
        q = problem.q_start
        raw = dataclasses.replace(raw, success=False, message=raw.message + "; non-finite answer")
    viol, dmin, ee = _check(problem, q)
    ok = viol <= problem.tolerance
    if raw.success and ok:
        return dataclasses.replace(raw, q=q, max_violation=viol, min_distance=dmin,
                                   ee_position=ee)
    message = raw.message
    if raw.success:
        message += f"; rejected: constraint violation {viol:.3g} > tolerance {problem.tolerance:g}"
    if not ok:  # fall back to the start if it is safer
        viol_0, dmin_0, ee_0 = _check(problem, problem.q_start)
        if viol_0 < viol:
            q, viol, dmin, ee = problem.q_start, viol_0, dmin_0, ee_0
            message += "; returned q_start"
    return dataclasses.replace(raw, q=q, success=False, message=message, max_violation=viol,
                               min_distance=dmin, ee_position=ee)


def _check(problem: IKProblem, q: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(:func:`violation` at q, the end-effector position at q (3,) [m]) from one placement
    pass."""
    ee, _, centers = placement(problem.kinematics, q)
    return (*violation(problem, q, centers), ee)
