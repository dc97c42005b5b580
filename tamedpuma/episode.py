"""The one control loop: controller -> simulator -> recorders.

Per control step k (period Δt):

1. read the simulator's truth (joint state, link poses, body spheres, contacts, clearance);
2. time the whole controller step ``q̈_k = controller.step(obs_k)`` (kinematics included) [ms];
3. hand a :class:`StepRecord` to every recorder (streams; nothing is held back to the end);
4. stop ``settle_time`` [s] after the goal is first reached (``stop_on_success``; the settle
   period lets the orientation be judged after the position has held) or at the step limit
   (extended to cover the settle period of a reach near the limit), else apply q̈_k.

The loop knows neither the method nor the file formats. It returns the run's
:class:`~tamedpuma.metrics.RunMetrics`, computed from the same per-step values that were recorded.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tamedpuma.metrics import RunMetrics, orientation_error, run_metrics
from tamedpuma.recording.records import Recorder, RunInfo, StepRecord
from tamedpuma.types import NO_OBSTACLE_CLEARANCE, Controller, Scenario
from tamedpuma.worlds.bullet import Simulator


@dataclass(frozen=True)
class EpisodeResult:
    """metrics: the run's scalars; stop_reason: 'goal_reached', 'max_steps' or 'nonfinite_command';
    trajectory: per-step arrays q (T, 7) [rad], ee_position (T, 3) [m], t (T,) [s];
    compute_ms (T,): the controller's wall time per step [ms]."""

    metrics: RunMetrics
    stop_reason: str
    t: np.ndarray
    q: np.ndarray
    ee_position: np.ndarray
    compute_ms: np.ndarray | None = None


def run_episode(
    scenario: Scenario,
    controller: Controller,
    sim: Simulator,
    recorders: Sequence[Recorder] = (),
    info: RunInfo | None = None,
    stop_on_success: bool = True,
    settle_time: float = 0.0,
) -> EpisodeResult:
    """Run one episode of ``scenario`` driven by ``controller`` in ``sim``, streaming to
    ``recorders`` (opened with ``info``, closed with ``complete=False`` if interrupted).
    ``settle_time`` [s]: how long the run continues after the goal is first reached."""
    if not settle_time >= 0:
        raise ValueError(f"settle_time must be >= 0 s, got {settle_time}")
    settle_steps = math.ceil(settle_time / scenario.dt - 1e-9)
    spec = sim.spec
    # the recorders log the true obstacle positions (the controller may see noisy ones)
    truth = ((lambda _obs: sim.obstacle_centers()) if hasattr(sim, "obstacle_centers")
             else (lambda o: o.obstacle_centers))
    ee_index = spec.link_names.index(spec.ee_link)
    obs = sim.reset(scenario)
    controller.reset(scenario)
    for rec in recorders:
        rec.open(info)
    log: dict[str, list] = {k: [] for k in ("t", "q", "ee_p", "pos_err", "rot_err", "clear",
                                            "contact", "ground", "ms")}
    complete = False
    stop_reason = "max_steps"
    limit = scenario.max_steps
    reach_step = None
    # with a discrete disturbance (goal change, push) only a reach at or after its onset counts:
    # the run goes on until then however early it first came near the goal
    onset = getattr(sim, "disturbance_time", None)
    onset = -math.inf if onset is None else onset - 1e-9
    try:
        k = 0
        while k < limit:
            link_pos, link_quat = sim.link_poses()
            centers = sim.body_sphere_centers(link_pos, link_quat)
            contacts = sim.contacts(centers)
            ee_p, ee_q = link_pos[ee_index], link_quat[ee_index]
            pos_err = float(np.linalg.norm(ee_p - obs.goal_position))
            rot_err = float(orientation_error(ee_q, obs.goal_quaternion))

            start = time.perf_counter()
            command = controller.step(obs)
            compute_ms = (time.perf_counter() - start) * 1e3
            qdd = np.asarray(command.qdd, dtype=float)

            clearance = contacts.sphere_clearance
            scalars = {
                "compute_time_ms": compute_ms,
                "clearance_m": clearance if math.isfinite(clearance) else NO_OBSTACLE_CLEARANCE,
                "position_error_m": pos_err,
                "orientation_error_rad": rot_err,
                "obstacle_contact": float(contacts.obstacle_contact),
                "ground_contact": float(contacts.ground_contact),
                **{name: float(v) for name, v in command.scalars.items()},
            }
            record = StepRecord(
                step=k, t=obs.t, q=obs.q, qd=obs.qd, qdd_cmd=qdd,
                link_positions=link_pos, link_quaternions=link_quat,
                ee_position=ee_p, ee_quaternion=ee_q, body_sphere_centers=centers,
                obstacle_centers=truth(obs), obstacle_radii=obs.obstacle_radii,
                goal_position=obs.goal_position, goal_quaternion=obs.goal_quaternion,
                scalars=scalars,
            )
            for rec in recorders:
                rec.write(record)
            for key, value in (("t", obs.t), ("q", obs.q), ("ee_p", ee_p), ("pos_err", pos_err),
                               ("rot_err", rot_err), ("clear", clearance),
                               ("contact", contacts.obstacle_contact),
                               ("ground", contacts.ground_contact), ("ms", compute_ms)):
                log[key].append(value)

            if not np.all(np.isfinite(qdd)) or qdd.shape != (spec.dof,):
                stop_reason = "nonfinite_command"
                break
            if reach_step is None and pos_err <= scenario.goal_tolerance and obs.t >= onset:
                reach_step = k
                limit = (k + settle_steps + 1 if stop_on_success
                         else max(limit, k + settle_steps + 1))
            if stop_on_success and reach_step is not None and k >= reach_step + settle_steps:
                stop_reason = "goal_reached"
                break
            obs = sim.step(qdd)
            k += 1
        complete = True
    finally:
        metrics = None
        if log["t"]:
            metrics = run_metrics(
                t=np.array(log["t"]), position_error=np.array(log["pos_err"]),
                orientation_error=np.array(log["rot_err"]), clearance=np.array(log["clear"]),
                obstacle_contact=np.array(log["contact"]), ground_contact=np.array(log["ground"]),
                q=np.array(log["q"]), q_min=spec.q_min, q_max=spec.q_max,
                compute_ms=np.array(log["ms"]), tolerance=scenario.goal_tolerance,
                time_limit=scenario.max_steps * scenario.dt, settle_time=settle_time,
                ee_position=np.array(log["ee_p"]),
                disturbance_time=None if onset == -math.inf else onset + 1e-9)
        summary = {"stop_reason": stop_reason if complete else "interrupted",
                   **(metrics.as_dict() if metrics else {})}
        close_errors = []
        for rec in recorders:  # close every file, even if one recorder fails
            try:
                rec.close(complete=complete, summary=summary)
            except Exception as exc:  # re-raised below, after the others are closed
                close_errors.append(exc)
        if close_errors and complete:
            raise close_errors[0]
    return EpisodeResult(metrics=metrics, stop_reason=stop_reason, t=np.array(log["t"]),
                         q=np.array(log["q"]), ee_position=np.array(log["ee_p"]),
                         compute_ms=np.array(log["ms"]))
