"""The one control loop: controller -> simulator -> recorders.

Per control step k (period Δt):

1. read the simulator's truth (joint state, link poses, body spheres, contacts, clearance);
2. time the whole controller step ``q̈_k = controller.step(obs_k)`` (kinematics included) [ms];
3. hand a :class:`StepRecord` to every recorder (streams; nothing is held back to the end);
4. stop once the hand's pose rests inside the goal ball, at least ``settle_time`` [s] after it
   first reached it (``stop_on_success``; the settle period lets the orientation be judged after
   the position has held, the rest test tells a converged run from one passing through the
   ball, and a hand still turning towards the goal orientation from one at rest:
   :class:`~tamedpuma.metrics.RestMonitor`), or at the step limit (extended to cover the settle
   period of a reach near the limit), else apply q̈_k.

A termination a signal asked for (:mod:`tamedpuma.termination`) ends the loop at the top of a
step, as if the signal's exception had been raised there.

Python's cyclic garbage collector does not run inside the loop (:func:`collector_paused`). It
runs when allocations pass a threshold, wherever that happens: in a sweep's worker, whose heap
holds torch, Hydra, pinocchio and the cached models, one full collection takes 120-220 ms and a
young one up to 5 ms, and one that lands inside a controller step is that step's time (a
cpm_literal step of 46 ms CPU time in Table 1, a PUMA step of 31 ms in the randomized suite, not
reproducible alone). The loop makes no reference cycles (an FPM or CPM episode leaves none for
the collector: 0 unreachable objects after it); what a controller's cycles hold is kept until the
episode ends and collected then.

The loop knows neither the method nor the file formats. It returns the run's
:class:`~tamedpuma.metrics.RunMetrics`, computed from the same per-step values that were recorded.
"""

from __future__ import annotations

import contextlib
import gc
import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, fields
from typing import NamedTuple

import numpy as np

from tamedpuma import termination
from tamedpuma.metrics import (
    ERROR_VECTOR_FIELDS,
    ROTATION_VECTOR_FIELDS,
    RestMonitor,
    RunMetrics,
    run_metrics,
)
from tamedpuma.records import Recorder, RunInfo, StepRecord
from tamedpuma.robot.rotations import error_to_goal
from tamedpuma.types import NO_OBSTACLE_CLEARANCE, Contacts, Controller, Scenario, World


@dataclass(frozen=True)
class EpisodeResult:
    """metrics: the run's scalars; stop_reason: 'converged' (at rest in the goal ball),
    'max_steps' or 'nonfinite_command';
    trajectory: per-step arrays q (T, dof) [rad], ee_position (T, 3) [m], t (T,) [s];
    compute_ms (T,): the controller's wall time per step [ms]; compute_cpu_ms (T,): the CPU time
    of the thread that ran it [ms] (the step's own work: the wall time also holds the time the
    operating system gave other processes); simulator_s: the wall time of the simulator's steps
    [s] (its physics over each control period and the next observation)."""

    metrics: RunMetrics
    stop_reason: str
    t: np.ndarray
    q: np.ndarray
    ee_position: np.ndarray
    compute_ms: np.ndarray | None = None
    compute_cpu_ms: np.ndarray | None = None
    simulator_s: float = 0.0


@dataclass(frozen=True)
class RestTest:
    """When the hand is at rest: its error vector x_ee − x_g moved less than ``distance`` [m]
    and the error rotation's vector log(ζ ⊗ ζ_g⁻¹) less than ``angle`` [rad] over the last
    ``window`` [s] (:func:`tamedpuma.metrics.at_rest`)."""

    window: float = 1.0
    distance: float = 0.005
    angle: float = 0.02


@dataclass
class _Trace:
    """The per-step values the run's metrics are computed from (the same ones recorded)."""

    t: list = field(default_factory=list)
    q: list = field(default_factory=list)
    ee_position: list = field(default_factory=list)
    error_vector: list = field(default_factory=list)
    rotation_vector: list = field(default_factory=list)
    position_error: list = field(default_factory=list)
    orientation_error: list = field(default_factory=list)
    clearance: list = field(default_factory=list)
    obstacle_contact: list = field(default_factory=list)
    ground_contact: list = field(default_factory=list)
    compute_ms: list = field(default_factory=list)
    compute_cpu_ms: list = field(default_factory=list)

    def add(self, **values) -> None:
        for name, value in values.items():
            getattr(self, name).append(value)

    def metrics(self, spec, scenario: Scenario, settle_time: float,
                disturbance_time: float | None, rest: RestTest) -> RunMetrics | None:
        if not self.t:
            return None
        arrays = {f.name: np.array(getattr(self, f.name)) for f in fields(self)}
        return run_metrics(
            **arrays, q_min=spec.q_min, q_max=spec.q_max, tolerance=scenario.goal_tolerance,
            time_limit=scenario.max_steps * scenario.dt, settle_time=settle_time,
            disturbance_time=disturbance_time, rest_window=rest.window,
            rest_distance=rest.distance, rest_angle=rest.angle)


class Seen(NamedTuple):
    """The simulator's truth at a step (:func:`_observe`): link poses (n, 3) [m] and (n, 4)
    quaternions (x, y, z, w), body-sphere centres [m], contacts, the hand's error to the goal
    (vector and distance [m]), the angle [rad] and the error rotation's vector
    log(ζ ⊗ ζ_g⁻¹) [rad]. A named tuple: built every control step, at a tuple's cost."""

    link_pos: np.ndarray
    link_quat: np.ndarray
    ee_index: int
    centers: np.ndarray
    contacts: Contacts
    error: np.ndarray
    pos_err: float
    rot_err: float
    rotation: np.ndarray


def _observe(sim: World, obs, ee_index: int) -> Seen:
    """What the simulator shows at ``obs`` (:class:`Seen`)."""
    link_pos, link_quat = sim.link_poses()
    centers = sim.body_sphere_centers(link_pos, link_quat)
    error = link_pos[ee_index] - obs.goal_position
    rot_err, rotation = error_to_goal(link_quat[ee_index], obs.goal_quaternion)
    return Seen(link_pos=link_pos, link_quat=link_quat, ee_index=ee_index, centers=centers,
                contacts=sim.contacts(centers), error=error,
                pos_err=math.sqrt(float(error.dot(error))),  # = np.linalg.norm, no wrapper
                rot_err=rot_err, rotation=rotation)


def _step_record(k: int, obs, truth: np.ndarray, command, qdd: np.ndarray, seen: Seen,
                 compute_ms: float, compute_cpu_ms: float) -> StepRecord:
    """What the recorders receive for step k (simulator truth, the command and its scalars)."""
    clearance = seen.contacts.sphere_clearance
    scalars = {
        "compute_time_ms": compute_ms,
        "compute_cpu_time_ms": compute_cpu_ms,
        "clearance_m": clearance if math.isfinite(clearance) else NO_OBSTACLE_CLEARANCE,
        "position_error_m": seen.pos_err,
        **dict(zip(ERROR_VECTOR_FIELDS, seen.error.tolist())),
        "orientation_error_rad": seen.rot_err,
        **dict(zip(ROTATION_VECTOR_FIELDS, seen.rotation.tolist())),
        "obstacle_contact": float(seen.contacts.obstacle_contact),
        "ground_contact": float(seen.contacts.ground_contact),
        **{name: float(v) for name, v in command.scalars.items()},
    }
    if command.logged_later is not None:  # after the step's timing: off the control path
        scalars.update((name, float(v)) for name, v in command.logged_later().items())
    ee = seen.ee_index
    return StepRecord(
        step=k, t=obs.t, q=obs.q, qd=obs.qd, qdd_cmd=qdd,
        link_positions=seen.link_pos, link_quaternions=seen.link_quat,
        ee_position=seen.link_pos[ee], ee_quaternion=seen.link_quat[ee],
        body_sphere_centers=seen.centers, obstacle_centers=truth,
        obstacle_radii=obs.obstacle_radii, goal_position=obs.goal_position,
        goal_quaternion=obs.goal_quaternion, scalars=scalars)


def _timed_step(controller: Controller, obs, dof: int):
    """(command, q̈, wall time of the whole controller step [ms], the CPU time its thread spent
    on it [ms]); a q̈ of the wrong shape is a controller bug (ValueError).

    The wall time is what a robot waits for; it also counts the time the operating system gave
    other processes while the step ran (a sweep on every core preempts a step for a scheduler
    slice, 3-5 ms). The thread's CPU time is the step's own work. A controller that runs its
    work on other threads would show it in the wall time only (the shipped ones do not: torch
    runs one intra-op thread)."""
    start = time.perf_counter()
    cpu_start = time.thread_time_ns()
    command = controller.step(obs)
    compute_cpu_ms = (time.thread_time_ns() - cpu_start) * 1e-6
    compute_ms = (time.perf_counter() - start) * 1e3
    qdd = np.array(command.qdd, dtype=float)  # a copy: recorders may hold it after the step
    if qdd.shape != (dof,):
        raise ValueError(f"controller returned q̈ of shape {qdd.shape}, not ({dof},)")
    return command, qdd, compute_ms, compute_cpu_ms


def _close(recorders: Sequence[Recorder], complete: bool, summary: dict) -> None:
    """Close every recorder, even if one fails; re-raise the first failure of a complete run."""
    errors = []
    for rec in recorders:
        try:
            rec.close(complete=complete, summary=summary)
        except Exception as exc:  # re-raised below, after the others are closed
            errors.append(exc)
    if errors and complete:
        raise errors[0]


class _StopRule:
    """When the loop stops: at the first step at least ``settle_time`` [s] after the first reach
    at which the hand rests inside the goal ball (with ``stop_on_success``), else at the step
    limit, which a reach near it extends to cover the settle period. With a discrete
    disturbance (goal change, push; onset [s]) only a reach at or after its onset counts: the run
    goes on until then however early it first came near the goal."""

    def __init__(self, scenario: Scenario, settle_time: float, rest: RestTest,
                 onset: float | None, stop_on_success: bool):
        if not settle_time >= 0:
            raise ValueError(f"settle_time must be >= 0 s, got {settle_time}")
        self.settle_steps = math.ceil(settle_time / scenario.dt - 1e-9)
        self.tolerance, self.enabled = scenario.goal_tolerance, stop_on_success
        self.after_onset = -math.inf if onset is None else onset - 1e-9
        self.monitor = RestMonitor(rest.window, rest.distance, rest.angle)
        self.limit, self.reach_step = scenario.max_steps, None

    def converged(self, k: int, t: float, error: np.ndarray, rotation: np.ndarray,
                  distance: float) -> bool:
        inside = distance <= self.tolerance
        if self.reach_step is None and inside and t >= self.after_onset:
            self.reach_step = k
            self.limit = max(self.limit, k + self.settle_steps + 1)
        due = (self.enabled and self.reach_step is not None
               and k >= self.reach_step + self.settle_steps and inside)
        return self.monitor.update(t, error, rotation, check=due) and due  # tested when due


def _loop(sim: World, obs, controller: Controller, recorders: Sequence[Recorder],
          trace: _Trace, stop: _StopRule, ee_index: int, clock: list[float]) -> str:
    """The control steps from ``obs`` until the stop rule ends them; the stop reason.
    ``clock[0]`` accumulates the simulator steps' wall time [s]."""
    spec = sim.spec
    k = 0
    while k < stop.limit:
        termination.check()  # a signal's SystemExit lost in a finaliser is raised here
        seen = _observe(sim, obs, ee_index)
        command, qdd, compute_ms, compute_cpu_ms = _timed_step(controller, obs, spec.dof)
        if recorders:  # (no record is built for none: recorder=none costs nothing)
            # the true obstacle positions (the controller may see noisy ones)
            record = _step_record(k, obs, sim.obstacle_centers(), command, qdd, seen,
                                  compute_ms, compute_cpu_ms)
            for rec in recorders:
                rec.write(record)
        trace.add(t=obs.t, q=obs.q, ee_position=seen.link_pos[ee_index],
                  error_vector=seen.error, rotation_vector=seen.rotation,
                  position_error=seen.pos_err, orientation_error=seen.rot_err,
                  clearance=seen.contacts.sphere_clearance,
                  obstacle_contact=seen.contacts.obstacle_contact,
                  ground_contact=seen.contacts.ground_contact, compute_ms=compute_ms,
                  compute_cpu_ms=compute_cpu_ms)
        if not np.isfinite(qdd).all():
            return "nonfinite_command"
        if stop.converged(k, obs.t, seen.error, seen.rotation, seen.pos_err):
            return "converged"
        start = time.perf_counter()
        obs = sim.step(qdd)
        clock[0] += time.perf_counter() - start
        k += 1
    return "max_steps"


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """Python's automatic cyclic garbage collection off inside the block, as it was after it
    (reference counting still frees everything that is not in a cycle)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def run_episode(scenario: Scenario, controller: Controller, sim: World,
                recorders: Sequence[Recorder] = (), info: RunInfo | None = None,
                stop_on_success: bool = True, settle_time: float = 0.0,
                rest: RestTest = RestTest()) -> EpisodeResult:
    """Run one episode of ``scenario`` driven by ``controller`` in ``sim``, streaming to
    ``recorders`` (opened with ``info``, closed with ``complete=False`` if interrupted).
    ``settle_time`` [s]: the run continues at least this long after the goal is first reached;
    with ``stop_on_success`` it ends at the first step after that at rest (``rest``) inside the
    goal ball, else at the step limit."""
    spec = sim.spec
    ee_index = spec.link_names.index(spec.ee_link)
    obs = sim.reset(scenario)
    controller.reset(scenario)
    trace, complete, stop_reason, clock = _Trace(), False, "max_steps", [0.0]
    onset = sim.disturbance_time
    stop = _StopRule(scenario, settle_time, rest, onset, stop_on_success)
    started: list[Recorder] = []  # each recorder whose open began: an interrupt while the
    try:  # next one opens (a slow Rerun start) still closes the logs already created
        for rec in recorders:
            started.append(rec)
            rec.open(info)
        with collector_paused():
            stop_reason = _loop(sim, obs, controller, recorders, trace, stop, ee_index, clock)
        complete = True
    finally:
        metrics = trace.metrics(spec, scenario, settle_time, onset, rest)
        _close(started, complete, {"stop_reason": stop_reason if complete else "interrupted",
                                     **(metrics.as_dict() if metrics else {})})
    return EpisodeResult(metrics=metrics, stop_reason=stop_reason, t=np.array(trace.t),
                         q=np.array(trace.q), ee_position=np.array(trace.ee_position),
                         compute_ms=np.array(trace.compute_ms),
                         compute_cpu_ms=np.array(trace.compute_cpu_ms), simulator_s=clock[0])
