"""The benchmark's timing of ``controller.step`` on prepared states (``python -m tamedpuma.bench``).

Each method is built exactly as ``tamedpuma.sweep`` builds it (same config, same model lookup);
its states are the scenario's start plus small seeded perturbations (16 states, cycled, zero goal
velocity), its obstacles seeded and kept clear of the arm (``bench_fabrics.random_obstacles``).
A cell is one (method, obstacle count): median, p10, p90 [ms] of the timed calls; the first call
at each count is reported apart (it allocates that count's buffers), warm-up calls are not timed.
:func:`time_parts` breaks one step into the parts the controller exposes publicly (kinematics,
fabric, network), each timed alone.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from tamedpuma.app.bench_fabrics import random_obstacles

#: "<method>+<variant>": the method with extra overrides (numpy: the fabric's reference
#: computation; numba: its compiled kernels, what the default ``auto`` is where numba is
#: installed)
VARIANTS = {"numpy": ["method.fabric.kernel=numpy"], "numba": ["method.fabric.kernel=numba"]}
N_STATES = 16  #: prepared joint states cycled through by every cell
ROUNDS = 10  #: rounds of interleaved calls per part in :func:`time_parts` (one more warms up)


def method_overrides(label: str) -> tuple[str, list[str]]:
    """``"fabrics+numpy"`` -> ``("fabrics", ["method.fabric.kernel=numpy"])``; a plain method
    name -> (it, []). ValueError for an unknown variant, or numba asked for but not installed."""
    method, _, variant = label.partition("+")
    if not variant:
        return method, []
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r} (known: {sorted(VARIANTS)})")
    if variant == "numba":
        from tamedpuma.fabrics import compiled

        if not compiled.AVAILABLE:
            raise ValueError("numba is not installed (pip install 'tamedpuma[fast]')")
    return method, list(VARIANTS[variant])


def observation(scenario, q, qd, obstacles, t: float = 0.0, step: int = 0):
    """The :class:`~tamedpuma.types.Observation` of joint state (q, q̇) in ``scenario``."""
    from tamedpuma.types import Observation

    goal = scenario.goal
    return Observation(t=t, step=step, q=q, qd=qd, obstacle_centers=obstacles.centers,
                       obstacle_radii=obstacles.radii,
                       obstacle_velocities=obstacles.velocities,
                       goal_position=goal.position, goal_quaternion=goal.quaternion,
                       goal_velocity=goal.velocity)


@dataclasses.dataclass
class Bench:
    """One method built as the sweep builds it, with the prepared states of its cells.

    states: (q [rad], q̇ [rad/s]) pairs near the start; centers0: the body spheres' centres [m]
    at the start (obstacles are kept clear of them); model: the model's provenance, or None."""

    spec: object
    scenario: object
    controller: object
    states: list
    centers0: np.ndarray
    rng: np.random.Generator
    model: str | None

    def obstacles(self, n: int):
        """``n`` seeded obstacles at least 0.15 m from the arm at the start."""
        from tamedpuma.types import Obstacles

        c, r, v = random_obstacles(self.rng, n, self.centers0, self.spec.sphere_radii, 0.15)
        return Obstacles(centers=c, radii=r, velocities=v)

    def reset(self, n: int) -> list:
        """Reset the controller with ``n`` obstacles; the observations of the prepared states."""
        obstacles = self.obstacles(n)
        self.controller.reset(dataclasses.replace(self.scenario, obstacles=obstacles))
        return [observation(self.scenario, q, qd, obstacles) for q, qd in self.states]


def model_label(model) -> str | None:
    """``"<origin> `<folder>` (sha256 <12 hex>)"`` of a loaded model, None without one."""
    if model is None:
        return None
    meta = model.metadata()
    return (f"{meta['model_origin']} `{Path(meta['model_path']).parent.name}` "
            f"(sha256 {meta['model_sha256'][:12]})")


def prepare(method: str, overrides=(), seed: int = 0) -> Bench:
    """``method`` (a label such as ``fpm+numba``) built as the sweep builds it, without
    recorders, and its seeded states."""
    from tamedpuma.app.compose import compose
    from tamedpuma.app.sweep import build
    from tamedpuma.robot.kinematics import Kinematics

    method, extra = method_overrides(method)
    built = build(compose("sweep", [f"method={method}", "recorder=none", *extra, *overrides]))
    spec, scenario = built.spec, built.scenario
    rng = np.random.default_rng(seed)
    q0 = np.asarray(scenario.q0, dtype=float)
    states = [(np.clip(q0 + rng.normal(scale=0.05, size=q0.size), spec.q_min, spec.q_max),
               rng.normal(scale=0.2, size=q0.size)) for _ in range(N_STATES)]
    centers0 = Kinematics(spec).evaluate(q0, np.zeros(q0.size)).sphere_centers
    return Bench(spec, scenario, built.controller, states, centers0, rng,
                 model_label(getattr(built, "model", None)))


def timed_steps(controller, observations, start: int, calls: int,
                budget_s: float = np.inf) -> list[float]:
    """Up to ``calls`` individually timed ``controller.step`` calls [s] on ``observations``
    (cycled from index ``start``); stops after ``budget_s`` seconds once 5 calls are in."""
    out, stop = [], time.perf_counter() + budget_s
    for i in range(start, start + calls):
        obs = observations[i % len(observations)]
        t0 = time.perf_counter()
        controller.step(obs)
        out.append(time.perf_counter() - t0)
        if len(out) >= 5 and time.perf_counter() > stop:
            break
    return out


def cell(method: str, n: int, ms: np.ndarray, first_ms: float, model) -> dict:
    """One row of the controller table: statistics of the timed calls ``ms`` [ms]."""
    ms = np.asarray(ms, dtype=float)
    return {"method": method, "n_obstacles": n, "median_ms": round(float(np.median(ms)), 5),
            "p10_ms": round(float(np.percentile(ms, 10)), 5),
            "p90_ms": round(float(np.percentile(ms, 90)), 5),
            "mean_ms": round(float(ms.mean()), 5), "n_calls": int(ms.size),
            "first_call_ms": round(first_ms, 5), "model": model}


def first_call(controller, observations) -> float:
    """The first step after a reset [ms] (it allocates the obstacle count's buffers)."""
    t0 = time.perf_counter()
    controller.step(observations[0])
    return (time.perf_counter() - t0) * 1e3


def warm_calls(first_ms: float, budget_s: float) -> int:
    """Untimed warm-up calls before a cell: ≤ 50, ≤ a tenth of the budget (≤ 1 s) of time."""
    return max(1, min(50, int(min(1.0, budget_s / 10) * 1e3 / max(first_ms, 1e-3))))


def time_controller(method: str, counts, calls: int, budget_s: float, overrides=(),
                    seed: int = 0) -> list[dict]:
    """Per obstacle count: timing of ``controller.step`` of ``method`` built as the sweep does.

    A cell stops after ``calls`` timed calls or ``budget_s`` seconds, whichever comes first
    (Modulation-IK at 1000 obstacles takes seconds per call)."""
    bench = prepare(method, overrides, seed)
    rows = []
    for n in counts:
        observations = bench.reset(n)
        first_ms = first_call(bench.controller, observations)
        warm = min(calls, warm_calls(first_ms, budget_s))
        timed_steps(bench.controller, observations, 1, warm)
        out = timed_steps(bench.controller, observations, 1 + warm, calls, budget_s)
        rows.append(cell(method, n, np.array(out) * 1e3, first_ms, bench.model))
    return rows


def timed_calls(fn, calls: int) -> np.ndarray:
    """``calls`` individually timed calls of ``fn`` [s]."""
    out = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out
