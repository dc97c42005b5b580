"""Where one controller step's time goes: its parts timed one by one at one state.

The parts are what a controller exposes publicly: its kinematics (``controller.kinematics``), its
fabric (``controller.fabric``: the whole evaluation for vanilla Fabrics, the avoidance fabric and
its solve for FPM/CPM), its network (``controller.puma.task`` or ``controller.task``:
the acceleration, for CPM also ψ and ∂ψ), and for Modulation-IK the IK solve the step logs
(``ik_solve_ms``). The step's remainder is the method's own arithmetic (forcing, pullback,
filters) and log scalars. Methods without a part skip it. For the parts that use a trained
model, also with the network's reference path (``primitive.single = None``: the batched numpy
copy).
"""

from __future__ import annotations

import numpy as np

from tamedpuma.app.bench_timing import ROUNDS, method_overrides, prepare, timed_calls


def _fabric_parts(ctrl, method: str, state, obs) -> dict:
    """The fabric's parts: its whole evaluation (vanilla Fabrics) or the avoidance and its
    solve (a method that forces the fabric)."""
    from tamedpuma.fabrics import quaternion_to_rotation

    fabric = getattr(ctrl, "fabric", None)
    if fabric is None or state is None:
        return {}
    buffers = fabric.buffers()  # kept across the timed calls, as an episode keeps its own
    if method == "fabrics":
        goal_r = quaternion_to_rotation(obs.goal_quaternion)
        return {"fabric (all leaves, solve, speed control)": lambda: fabric.evaluate(
            state, obs.q, obs.qd, obs.obstacle_centers, obs.obstacle_radii,
            obs.obstacle_velocities, obs.goal_position, goal_r, buffers)}
    args = (state, obs.q, obs.qd, obs.obstacle_centers, obs.obstacle_radii,
            obs.obstacle_velocities, buffers)
    av = fabric.avoidance(*args)
    return {"avoidance fabric": lambda: fabric.avoidance(*args),
            "its solve and energization": lambda: av.alpha(obs.qd, av.acceleration())}


def _network_parts(ctrl, method: str, state, obs) -> dict:
    """The network's parts: the task-space acceleration, for CPM with ψ and ∂ψ."""
    task = episode_task(ctrl)
    if task is None or state is None:
        return {}
    goal = (obs.goal_position, obs.goal_quaternion)
    parts = {"network: acceleration": lambda: task.acceleration(state, obs.qd, *goal)}
    if method == "cpm":
        parts["network: acceleration + ψ and ∂ψ"] = lambda: (
            task.acceleration(state, obs.qd, *goal), task.potential(state, *goal))
    return parts


def step_parts(ctrl, method: str, obs) -> dict:
    """{part name: a call} of one step at ``obs``, the whole step first."""
    kin = getattr(ctrl, "kinematics", None)
    state = kin.evaluate(obs.q, obs.qd) if kin is not None else None
    parts = {"step": lambda: ctrl.step(obs)}
    if kin is not None:
        parts["kinematics"] = lambda: kin.evaluate(obs.q, obs.qd)
    parts.update(_fabric_parts(ctrl, method, state, obs))
    parts.update(_network_parts(ctrl, method, state, obs))
    return parts


def episode_task(ctrl):
    """PUMA's task of the controller's current episode (whose primitive its steps evaluate),
    None for a controller without one."""
    puma = getattr(ctrl, "puma", ctrl)
    return getattr(getattr(puma, "episode", None), "task", None)


def primitive_of(ctrl):
    """The trained network the controller's current episode evaluates, where it has one with
    a reference path."""
    primitive = getattr(episode_task(ctrl), "primitive", None)
    return primitive if primitive is not None and hasattr(primitive, "single") else None


def interleaved(parts: dict, primitive, calls: int) -> dict:
    """Every (part, reference path?) timed in :data:`ROUNDS` rounds of ``calls / ROUNDS`` calls,
    interleaved, so that a burst of load on the shared machine spreads over all of them; the
    first round warms up and is dropped. {(part, reference): median [µs]}."""
    jobs = [(part, False) for part in parts] + [
        (part, True) for part in parts
        if primitive is not None and (part == "step" or part.startswith("network"))]
    times = {job: [] for job in jobs}
    for _ in range(ROUNDS + 1):
        for part, ref in jobs:
            fast = primitive.single if ref else None
            if ref:
                primitive.single = None
            try:
                times[(part, ref)].append(timed_calls(parts[part], max(1, calls // ROUNDS)))
            finally:
                if ref:
                    primitive.single = fast
    return {job: round(float(np.median(np.concatenate(t[1:]))) * 1e6, 2)
            for job, t in times.items()}


def ik_row(ctrl, obs, label: str, n_obstacles: int) -> list[dict]:
    """Modulation-IK: its IK solve as the step logs it (``ik_solve_ms``, median of 20 steps)."""
    solve_ms = [ctrl.step(obs).scalars.get("ik_solve_ms", np.nan) for _ in range(20)]
    if not np.isfinite(np.nanmedian(solve_ms)):
        return []
    return [{"method": label, "n_obstacles": n_obstacles,
             "part": "IK solve (Drake SNOPT; the step's ik_solve_ms)",
             "us": float(np.nanmedian(solve_ms)) * 1e3}]


def time_parts(label: str, n_obstacles: int = 2, calls: int = 1000, overrides=(),
               seed: int = 0) -> list[dict]:
    """Where one step of ``label`` (a method, or method+variant) at ``n_obstacles`` goes.
    Rows: ``{method, n_obstacles, part, us[, reference_us]}`` (medians [µs])."""
    method, _ = method_overrides(label)
    bench = prepare(label, overrides, seed)
    ctrl = bench.controller
    obs = bench.reset(n_obstacles)[1]
    parts = step_parts(ctrl, method, obs)
    rows = ik_row(ctrl, obs, label, n_obstacles) if method == "modulation_ik" else []
    us = interleaved(parts, primitive_of(ctrl), calls)
    for part in parts:
        row = {"method": label, "n_obstacles": n_obstacles, "part": part, "us": us[(part, False)]}
        if (part, True) in us:
            row["reference_us"] = us[(part, True)]
        rows.append(row)
    return rows
