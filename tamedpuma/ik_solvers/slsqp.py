"""SciPy SLSQP backend: the IK problem with our own vectorised constraints and analytic gradients.

Only the (sphere, obstacle) pairs that can become active inside the bound box are passed to the
solver: with ``Δ_k = max(q_start,k − q_lower,k, q_upper,k − q_start,k)`` and the reach bounds
``L_ik`` (:func:`~tamedpuma.ik_solvers.problem.reach_bounds`), a pair whose gap at q_start exceeds
``Σ_k L_ik Δ_k`` holds everywhere in the box, so dropping it changes nothing (exact pruning; with a
small trust region most obstacles drop out).

The objective is scaled by ``1/s²`` (s = ``options.scale``, 0.01 m by default:
:class:`~tamedpuma.ik_solvers.problem.SolverOptions`) and SLSQP's absolute tolerance is
``options.ftol`` (1e-6) on the scaled value, i.e. ``ftol·s² = 1e-10 m²`` ≈ (10 µm)² on the
objective. Tighter values end in SLSQP's "positive directional derivative in line search" at
optima with active distance bounds (measured), which would be reported as failures.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from scipy.optimize import minimize

from .problem import IKProblem, IKResult, _pair_distances, objective, reach_bounds, robot_key

_REACH: dict[tuple, np.ndarray] = {}


def _reach(kinematics) -> np.ndarray:
    key = robot_key(kinematics)
    if key not in _REACH:
        _REACH[key] = reach_bounds(kinematics)
    return _REACH[key]


def warm_up(kinematics, radii: np.ndarray) -> None:
    """Compute (cache) the reach bounds, outside the timed loop."""
    _reach(kinematics)


def _active_pairs(problem: IKProblem, state) -> np.ndarray:
    """Boolean mask (k·n,) of the pairs that can be active inside the bound box."""
    gap = _pair_distances(problem, state, with_jacobian=False)
    step = np.maximum(problem.q_start - problem.q_lower, problem.q_upper - problem.q_start)
    reach = _reach(problem.kinematics) @ step  # (k,) max displacement of each sphere [m]
    k, n = len(reach), problem.n_obstacles
    return gap <= np.repeat(reach, n) + 1e-6 if k * n else np.zeros(0, bool)


def solve(problem: IKProblem) -> IKResult:
    """Solve ``problem`` with SLSQP (see the module docstring)."""
    kin = problem.kinematics
    zeros = np.zeros(kin.spec.dof)
    scale = 1.0 / float(problem.options.scale) ** 2
    cache: dict = {}

    def state_at(q):
        key = q.tobytes()
        if cache.get("key") != key:
            cache["key"] = key
            cache["state"] = kin.evaluate(q, zeros)
        return cache["state"]

    def fun(q):
        value, grad = objective(problem, state_at(q), q)
        return value * scale, grad * scale

    start = time.perf_counter()
    q0 = np.clip(problem.q_start, problem.q_lower, problem.q_upper)
    constraints = []
    if problem.n_obstacles:
        mask = _active_pairs(problem, state_at(problem.q_start))
        if mask.any():
            def g(q):
                return _pair_distances(problem, state_at(q), False)[mask]

            def g_jac(q):
                return _pair_distances(problem, state_at(q), True)[1][mask]

            constraints.append({"type": "ineq", "fun": g, "jac": g_jac})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # bound/feasibility warnings end up in res.message
        res = minimize(fun, q0, jac=True, method="SLSQP",
                       bounds=list(zip(problem.q_lower, problem.q_upper)),
                       constraints=constraints,
                       options={"maxiter": problem.max_iterations,
                                "ftol": float(problem.options.ftol)})
    elapsed = (time.perf_counter() - start) * 1e3
    return IKResult(q=np.asarray(res.x, float), success=bool(res.success),
                    message=f"SLSQP: {res.message}", iterations=int(res.nit),
                    max_violation=float("nan"), min_distance=float("nan"), backend="slsqp",
                    solve_time_ms=elapsed)
