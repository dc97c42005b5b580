"""Modulation-IK, the paper's baseline: a modulated first-order position PUMA tracked by a
collision-aware IK.

Each control step (period Δt [s]), everything in the robot base (= world) frame:

1. nominal velocity of the first-order position primitive at the end-effector position p [m]:
   ``v = f(p − p_g) + ṗ_g`` [m/s] (the goal velocity is fed forward, so a moving goal is a moving
   frame), its norm clipped to ``max_speed``;
2. modulation around the obstacles (Khansari-Zadeh and Billard 2012,
   :mod:`tamedpuma.methods._modulation`)
   with the obstacles inflated by ``safety_radius``: ``v_mod = M(p)(v − ȯ) + ȯ``;
3. targets: ``p* = p + v_mod Δt``; orientation by a separate first-order attractor toward the goal
   orientation, ``R* = exp(k_R Δt [log(R_g Rᵀ)]) R`` (``orientation_gain`` k_R [1/s]), tracked by
   the IK's soft term ``w_R (1 − cos θ)``;
4. collision-aware IK (:func:`tamedpuma.ik_solvers.solve_ik`)::

       min_q w_p ‖p(q) − p*‖² + w_R (1 − cos θ(R(q), R*)) + w_q ‖q − q_k‖²
       s.t. joint limits shrunk by ``limit_margin``,
            |q − q_k| ≤ trust · q̇_max Δt (what the joints can do in one step),
            ‖c_i(q) − (o_j + ȯ_j Δt)‖ − r_i − r_j ≥ d_min'  (every body sphere, every obstacle at
            the time the step ends);

   ``d_min' = d_min``, or with ``hold_clearance`` (the default), where the current
   configuration's smallest clearance c_k to those obstacles is below d_min,
   ``d_min' = max(0, min(d_min, c_k + r))`` (r = ``clearance_recovery`` [m per step]): the arm
   must move back out towards d_min by r per step; if no step in the trust box can (the solve
   fails), it is solved again with ``d_min' = max(0, c_k)``: the arm may not come closer but q_k
   itself is admissible, so it can always stay or move away. With a fixed d_min an arm that
   starts within it has no admissible step, every solve fails and the arm is held for the whole
   run. Beyond d_min the bound is d_min, as without the option;

5. joint acceleration for the simulator's velocity control ``q̇_cmd = clip(q̇ + q̈ Δt, ±q̇_max)``:
   ``q̈ = (κ (q_ik − q)/Δt − q̇)/Δt`` so that ``q̇_cmd = κ (q_ik − q)/Δt`` (κ = ``tracking_gain``;
   κ = 1 is dead-beat: the joints reach q_ik at the end of the step). The constant-acceleration
   form ``2(q_ik − q − q̇Δt)/Δt²`` would command ``2(q_ik − q)/Δt − q̇`` to a velocity-controlled
   joint and oscillate, so it is not used. With trust ≤ 1 the command is within the velocity
   limits, so the simulator's clip never changes it.

A failed solve (solver failure, or a "success" whose answer violates a constraint) is never
ignored: the IK returns the safest configuration it knows (its iterate if it satisfies every
constraint, else the current q); the controller moves there only if it satisfies every constraint,
and otherwise brakes (``q_ik = q``: ``q̇_cmd = 0``); ``ik_brake`` = 1 when a failed step holds the
current configuration. Logged scalars per step: ``ik_success``,
``ik_iterations``, ``ik_constraint_violation_m``, ``ik_solve_ms``, ``ik_brake``, ``ik_d_min_m``
(the step's bound d_min'), ``ik_failures``
(failed solves so far in the episode; the first one's solver message is also a log warning),
``ik_position_error_m`` (‖p(q_ik) − p*‖), ``modulation_gamma_min``, ``min_clearance_m`` (the
commanded configuration's clearance to the obstacles at the end of the step, as the IK sees it),
``nominal_speed_mps``, ``modulated_speed_mps``.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Protocol

import numpy as np

from tamedpuma.errors import CheckpointError, ConfigError
from tamedpuma.ik_solvers import BACKENDS, IKProblem, placement, solve_ik, violation, warm_up
from tamedpuma.methods._modulation import modulate
from tamedpuma.methods._policy import episode_primitive
from tamedpuma.methods._settings import MODEL_CHOICES, check
from tamedpuma.paths import resolve
from tamedpuma.robot.kinematics import Kinematics
from tamedpuma.robot.rotations import exp_so3, quat_to_matrix, rotation_error
from tamedpuma.types import NO_OBSTACLE_CLEARANCE, Command, Observation, Scenario

log = logging.getLogger(__name__)



class VelocityField(Protocol):
    """Anything with a first-order ``velocity(x (3,) [m], goal (3,) [m]) -> (3,) [m/s]``."""

    def velocity(self, x: np.ndarray, goal: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class LinearVelocityField:
    """Analytic stand-in for a first-order PUMA: ``v = −k (x − x_g)`` [m/s], gain k [1/s]."""

    gain: float = 1.0

    def velocity(self, x: np.ndarray, goal: np.ndarray) -> np.ndarray:
        return -self.gain * (np.asarray(x, float) - np.asarray(goal, float))


@dataclass(frozen=True)
class ModulationIKParams:
    """Gains of :class:`ModulationIK` (units in brackets; see the module docstring).

    safety_radius: added to every obstacle radius in Γ [m]; gamma_power: p in Γ = (d/R)^(2p);
    max_speed: clip of the nominal speed [m/s]; orientation_gain: k_R [1/s];
    ik_backend: 'drake' or 'slsqp'; d_min: IK clearance bound [m]; hold_clearance: an arm
    within d_min backs out by clearance_recovery [m] per step, or if it cannot, does not come
    closer (module docstring, step 4);
    position_weight [1/m²], orientation_weight [-], regularization_weight [1/rad²]: IK cost weights;
    trust: step box as a fraction of q̇_max Δt [-]; limit_margin: the IK keeps this far inside the
    joint limits [rad] (the simulator's tracking overshoots a target on the limit slightly);
    tracking_gain: κ [-];
    ik_tolerance: allowed constraint violation [m]; ik_max_iterations: solver limit.
    """

    safety_radius: float = 0.15
    gamma_power: float = 1.0
    max_speed: float = 0.5
    orientation_gain: float = 1.0
    ik_backend: str = "drake"
    d_min: float = 0.05
    hold_clearance: bool = True
    clearance_recovery: float = 0.002
    position_weight: float = 1.0
    orientation_weight: float = 0.1
    regularization_weight: float = 1e-4
    trust: float = 1.0
    limit_margin: float = 0.01
    tracking_gain: float = 1.0
    ik_tolerance: float = 1e-5
    ik_max_iterations: int = 100

    def __post_init__(self):
        positive = ("gamma_power", "max_speed", "trust", "tracking_gain", "ik_tolerance",
                    "ik_max_iterations", "position_weight")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"method.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("safety_radius", "orientation_gain", "d_min", "orientation_weight",
                     "clearance_recovery",
                     "regularization_weight", "limit_margin"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"method.{name} must be >= 0, got {getattr(self, name)!r}")
        if self.ik_backend not in BACKENDS:
            raise ConfigError(f"method.ik_backend {self.ik_backend!r}: choose one of "
                              f"{sorted(BACKENDS)}")


@dataclass
class ModulationEpisode:
    """What the step writes (the controller's episode state, made afresh by ``reset``): the
    primitive the episode evaluates (its own buffers: :func:`episode_primitive`), the control
    step Δt [s] (the scenario's) and the number of failed IK solves so far."""

    primitive: VelocityField
    dt: float = 0.02
    failures: int = 0


class ModulationIK:
    """The Modulation-IK controller (module docstring). ``episode``: the episode state
    (:class:`ModulationEpisode`), made by :meth:`reset`."""

    def __init__(self, kinematics: Kinematics, primitive: VelocityField,
                 params: ModulationIKParams = ModulationIKParams()):
        if not callable(getattr(primitive, "velocity", None)):
            raise ConfigError("modulation_ik needs a primitive with velocity(x, goal)")
        self.kinematics = kinematics
        self.primitive = primitive
        self.params = params
        self.episode = ModulationEpisode(episode_primitive(primitive))

    def reset(self, scenario: Scenario) -> None:
        """New episode: Δt from the scenario; the IK backend's one-off set-up (Drake's plant for
        these obstacle radii) happens here, outside the timed steps."""
        self.episode = ModulationEpisode(episode_primitive(self.primitive), float(scenario.dt))
        warm_up(self.kinematics, scenario.obstacles.radii, self.params.ik_backend)

    def _targets(self, obs: Observation, p: np.ndarray, rot: np.ndarray):
        """(p⁺ target, R⁺ target, v, modulated v, the Modulation) from the hand's position p
        [m] and rotation R."""
        prm, dt = self.params, self.episode.dt
        v = np.asarray(self.episode.primitive.velocity(p, obs.goal_position), float).reshape(3)
        v = v + obs.goal_velocity
        speed = float(np.linalg.norm(v))
        if speed > prm.max_speed:
            v = v * (prm.max_speed / speed)
        v_mod, mod = modulate(v, p, obs.obstacle_centers, obs.obstacle_radii,
                              obs.obstacle_velocities, safety=prm.safety_radius,
                              power=prm.gamma_power)
        rot_goal = quat_to_matrix(obs.goal_quaternion)
        omega = rotation_error(rot, rot_goal)
        rot_target = exp_so3(min(prm.orientation_gain * dt, 1.0) * omega) @ rot
        return p + v_mod * dt, rot_target, v, v_mod, mod

    def step(self, obs: Observation) -> Command:
        prm, dt = self.params, self.episode.dt
        q, qd = np.asarray(obs.q, float), np.asarray(obs.qd, float)
        # the hand's pose and the body spheres' centres from one placement pass (the numbers
        # evaluate() gives)
        hand_p, hand_rot, centers = placement(self.kinematics, q)
        p_target, rot_target, v, v_mod, mod = self._targets(obs, hand_p, hand_rot)
        spec = self.kinematics.spec
        box = prm.trust * spec.qd_max * dt
        upper = np.minimum(q + box, spec.q_max - prm.limit_margin)
        lower = np.minimum(np.maximum(q - box, spec.q_min + prm.limit_margin), upper)
        obstacles_next = obs.obstacle_centers + dt * obs.obstacle_velocities
        problem = IKProblem(
            kinematics=self.kinematics, q_start=q, target_position=p_target,
            target_rotation=rot_target, obstacle_centers=obstacles_next,
            obstacle_radii=obs.obstacle_radii, d_min=prm.d_min, q_lower=lower,
            q_upper=upper, position_weight=prm.position_weight,
            orientation_weight=prm.orientation_weight,
            regularization_weight=prm.regularization_weight, tolerance=prm.ik_tolerance,
            max_iterations=prm.ik_max_iterations)
        current = np.inf  # c_k, the current clearance (module docstring, step 4)
        if prm.hold_clearance and problem.n_obstacles:
            current = violation(problem, q, centers)[1]
            if current + prm.clearance_recovery < prm.d_min:
                problem = dataclasses.replace(
                    problem, d_min=max(0.0, current + prm.clearance_recovery))
        result = solve_ik(problem, prm.ik_backend)
        if not result.success and problem.d_min > max(0.0, current):  # cannot back out:
            problem = dataclasses.replace(problem, d_min=max(0.0, current))  # no closer
            result = solve_ik(problem, prm.ik_backend)
        safe = result.max_violation <= prm.ik_tolerance
        q_ik = result.q if safe else q
        brake = not safe or (not result.success and np.array_equal(result.q, q))
        if not result.success:
            self.episode.failures += 1
            (log.warning if self.episode.failures == 1 else log.debug)(
                "step %d: IK failed (%s); %s", obs.step, result.message,
                "holding the current configuration" if brake else "moving to its safe answer")
        qdd = (prm.tracking_gain * (q_ik - q) / dt - qd) / dt
        # p(q_ik) and the clearance from the placement passes already made: solve_ik's check
        # of its answer (it always places it), or this step's at q
        p_ik = result.ee_position if safe else hand_p
        clearance = result.min_distance if safe else violation(problem, q, centers)[1]
        scalars = {
            "ik_success": float(result.success),
            "ik_iterations": float(result.iterations),
            "ik_constraint_violation_m": float(result.max_violation),
            "ik_solve_ms": float(result.solve_time_ms),
            "ik_brake": float(brake),
            "ik_d_min_m": float(problem.d_min),
            "ik_failures": float(self.episode.failures),
            "ik_position_error_m": float(np.linalg.norm(p_ik - p_target)),
            "modulation_gamma_min": min(mod.gamma_min, NO_OBSTACLE_CLEARANCE),
            "min_clearance_m": min(float(clearance), NO_OBSTACLE_CLEARANCE),
            "nominal_speed_mps": float(np.linalg.norm(v)),
            "modulated_speed_mps": float(np.linalg.norm(v_mod)),
        }
        return Command(qdd=qdd, scalars=scalars, logged_later=self._psi_later(hand_p, obs))

    def _psi_later(self, p: np.ndarray, obs: Observation):
        """``{"psi": ψ}`` of the position primitive (PUMA's potential) at the hand's position p
        [m], computed only for the log (``Command.logged_later``); None for a field without ψ."""
        psi = getattr(self.episode.primitive, "psi", None)
        if psi is None:
            return None
        goal = obs.goal_position
        return lambda: {"psi": float(psi(p, goal))}


def _train_hint(settings, path: str) -> str:
    task = settings.task or "<task>"
    out = Path(path).parent if Path(path).name == "puma.pt" else Path(path)
    return (f"train it with: python -m tamedpuma.train task={task} puma=position "
            f"out_dir={out}" + ("" if Path(path).name == "puma.pt" else " (and point "
                                "method.checkpoint at <out_dir>/puma.pt)"))


def load_position_primitive(settings: ModulationIkSettings) -> VelocityField:
    """The first-order R³ primitive of ``settings.checkpoint``; a CheckpointError (one line,
    with the train command) if it is missing, corrupt or not a first-order 3-D position model."""
    path = settings.checkpoint
    from tamedpuma.puma.primitive import VectorPrimitive, load_primitive

    if path:
        resolved = resolve(str(path))
    elif settings.task:
        from tamedpuma.puma import store

        resolved = store.resolve(str(settings.task), 1, None, str(settings.model)).path
        path = str(resolved)
    else:
        raise ConfigError("method.checkpoint and method.task are not set; name a first-order "
                          "position PUMA (puma=position)")
    try:
        primitive = load_primitive(resolved)
    except CheckpointError as exc:
        raise CheckpointError(f"{exc}; {_train_hint(settings, str(path))}") from None
    spec = getattr(primitive, "spec", None)
    if (not isinstance(primitive, VectorPrimitive) or spec.order != 1
            or getattr(spec, "n_pos", 3) != 3):
        raise CheckpointError(f"checkpoint {resolved}: modulation_ik needs a first-order 3-D "
                              f"position primitive, got {spec}; "
                              f"{_train_hint(settings, str(path))}")
    return primitive


@dataclass(frozen=True)
class ModulationIkSettings(ModulationIKParams):
    """method=modulation_ik (``conf/method/modulation_ik.yaml``): the controller's gains and
    which first-order position PUMA drives it."""

    task: str | None = None        # the task whose position primitive drives it
    checkpoint: str | None = None  # a first-order position PUMA (puma=position); null: best at hand
    model: str = "auto"            # with checkpoint null: auto | real (error if none) | shipped

    def __post_init__(self):
        super().__post_init__()
        check(self.model in MODEL_CHOICES, "method.model", " | ".join(MODEL_CHOICES), self.model)

    def params(self) -> ModulationIKParams:
        """The controller's gains alone."""
        return ModulationIKParams(**{f.name: getattr(self, f.name)
                                     for f in fields(ModulationIKParams)})


#: the settings ``make`` takes
SETTINGS = ModulationIkSettings


def make(settings: ModulationIkSettings, kinematics: Kinematics,
         primitive: VelocityField | None = None) -> ModulationIK:
    """The controller of ``settings``; ``primitive`` overrides the checkpoint (any object with
    ``velocity(x, goal)``, e.g. :class:`LinearVelocityField`)."""
    params = settings.params()
    if params.trust > 1.0:  # here, not in the settings: they are built more than once per run
        log.warning("method.trust %.3g > 1: IK steps can exceed the velocity limits and be "
                    "clipped by the simulator", params.trust)
    if params.ik_backend == "drake":
        from tamedpuma.ik_solvers import drake

        if not drake.available():
            raise ConfigError("method.ik_backend=drake needs Drake: pip install drake "
                              "(or set method.ik_backend=slsqp)")
    if primitive is None:
        primitive = load_position_primitive(settings)
    return ModulationIK(kinematics, primitive, params)
