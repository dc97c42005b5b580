"""Shared by the methods built on a trained PUMA primitive (puma, fpm, cpm): the pulled PUMA
policy, its construction from a method config, and the avoidance fabric FPM and CPM add to it.

Methods never import each other; what two of them share lives here.

Episode state. Everything a reset or a step writes lives in the controller's ``episode`` (made
afresh by ``reset``): :class:`PumaEpisode` (PUMA's task with its own network buffers) and
:class:`TamedEpisode` (the fabric's work buffers, Δt, the stall monitor, the configuration pull's
monitor). The rest of a controller is its configuration, fixed after construction; a step is
a function of (episode, observation) (``tests/test_episode_state.py``).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np

from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import Fabric, FabricBuffers, solve_acceleration
from tamedpuma.fabrics.discrete import barrier_step
from tamedpuma.methods._configuration_pull import ConfigurationMonitor, ConfigurationPull, Ground
from tamedpuma.methods._ground_rows import HullTable, hull_ground_rows
from tamedpuma.methods._kernels import STEP, warm_up
from tamedpuma.methods._learned import load_task, null_objective
from tamedpuma.methods._policy import (
    Damping,
    NullSpaceObjective,
    episode_primitive,
    pull_through_metric,
    pull_to_joints,
    weighted_rows,
)
from tamedpuma.methods._stall import StallMonitor, StallPull
from tamedpuma.robot.ground import (
    GroundRows,
    link_hulls,
)
from tamedpuma.types import NO_OBSTACLE_CLEARANCE, Command, Observation, Scenario


def episode_task(task):
    """``task`` for one episode: a copy holding its own primitive wrapper
    (:func:`~tamedpuma.methods._policy.episode_primitive`: the network shared, its buffers the
    episode's; ``task`` itself, the template, is never written)."""
    own = copy.copy(task)
    if getattr(task, "primitive", None) is not None:
        own.primitive = episode_primitive(task.primitive)
    return own


@dataclass
class PumaEpisode:
    """What :class:`PumaController`'s step writes (see the module docstring): ``task``, PUMA's
    task with this episode's network buffers (:func:`episode_task`):
    every evaluation of the network in a step goes through it."""

    task: object


class PumaController:
    """PUMA pulled to joint space (see :mod:`tamedpuma.methods.puma`):
    ``q̈ = J⁺(ẍ_d − J̇q̇) + N q̈_null`` [rad/s²]. task: a
    :class:`~tamedpuma.methods._policy.PoseTask` or :class:`~tamedpuma.methods._policy.PlanarTask`;
    damping: λ of the pseudo-inverse, or a :class:`~tamedpuma.methods._policy.Damping` rule
    (singularity-robust); feed_goal_velocity: the primitive sees ``ṗ − v_g`` (moving goals).
    ``episode``: the episode state (:class:`PumaEpisode`), made by :meth:`reset`."""

    def __init__(self, task, kinematics, damping: float | Damping = 0.01,
                 null_space: NullSpaceObjective | None = None, feed_goal_velocity: bool = True):
        self.task, self.kinematics = task, kinematics
        self.damping, self.null_space = damping, null_space
        self.feed_goal_velocity = feed_goal_velocity
        self.episode = PumaEpisode(episode_task(task))

    def reset(self, scenario: Scenario) -> None:
        self.episode = PumaEpisode(episode_task(self.task))

    def joint_acceleration(self, state, obs: Observation, stall: StallMonitor | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
        """(q̈_C, ẍ_d): the pulled PUMA acceleration at the observation (state = kinematics)."""
        task, null = self.task_and_null(state, obs, stall=stall)
        return pull_to_joints(task, self.damping, null), task.xdd

    def task_and_null(self, state, obs: Observation, stall: StallMonitor | None = None,
                      configuration: ConfigurationMonitor | None = None):
        """(PUMA's TaskAcceleration, the secondary objective's q̈_null or None); stall: FPM's
        and CPM's stall pull (:mod:`tamedpuma.methods._stall`), added to the
        position rows while armed; configuration: the configuration pull
        (:mod:`tamedpuma.methods._configuration_pull`), a joint-space spec (J = I) replacing the
        task rows while engaged."""
        vg = obs.goal_velocity if self.feed_goal_velocity else None
        own = self.episode.task
        task = own.acceleration(state, obs.qd, obs.goal_position, obs.goal_quaternion, vg)
        if stall is not None:
            task = stall.applied(obs.t, state.ee_position, obs.goal_position, task, lambda: (
                own.psi(state, obs.goal_position, obs.goal_quaternion)),
                lambda: state.ee_jacobian[:3] @ obs.qd - np.asarray(obs.goal_velocity)[:3])
            if configuration is not None:
                task = configuration.applied(obs.q, obs.qd, stall.distance, stall, obs, task)
        null = self.null_space.acceleration(self.kinematics, obs.qd) if self.null_space else None
        return task, null

    def with_avoidance(self, state, obs: Observation, av, forcing: Forcing,
                       stall: StallMonitor | None = None,
                       configuration: ConfigurationMonitor | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(h, q̈_C, ẍ_d): the avoidance geometry ``h = −M⁻¹f`` of ``av`` and PUMA's forcing,
        pulled by the damped pseudo-inverse (``additive``) or through the avoidance fabric's
        metric M (``metric``; :class:`Forcing`), with the stall pull of
        ``stall`` (:mod:`tamedpuma.methods._stall`) added to PUMA's position rows while armed
        (and the configuration pull's joint-space spec in their place while it is engaged)."""
        if forcing.metric:
            task, null = self.task_and_null(state, obs, stall, configuration)
            qdd_c, h = pulled_through_metric(av, task, forcing, null, self.damping)
            return h, qdd_c, task.xdd
        qdd_c, xdd = self.joint_acceleration(state, obs, stall)
        return av.acceleration(), qdd_c, xdd

    def step(self, obs: Observation) -> Command:
        state = self.kinematics.evaluate(obs.q, obs.qd)
        qdd, xdd = self.joint_acceleration(state, obs)
        return Command(qdd=qdd, scalars={"task_acc_norm": vector_norm(xdd),
                                         "joint_acc_norm": vector_norm(qdd)},
                       logged_later=self.psi_later(state, obs))

    def psi_later(self, state, obs: Observation):
        """``{"psi": ψ}`` at the hand's pose, computed when called: the log's ψ for a step that
        never evaluates ψ itself (``Command.logged_later``, off the control path). state: the
        kinematics' evaluation at obs, current until the next step."""
        task, goal_p, goal_q = self.episode.task, obs.goal_position, obs.goal_quaternion
        return lambda: {"psi": task.psi(state, goal_p, goal_q)}


class Forced(NamedTuple):
    """What FPM's and CPM's laws start from at one observation (:meth:`TamedController.forced`):
    the kinematics' evaluation ``state``, the avoidance fabric ``av`` (M, f, barrier rows), its
    geometry ``h`` [rad/s²], PUMA's forcing ``qdd_c`` = f_θ^C [rad/s²], PUMA's task acceleration
    ``xdd`` [m/s², rad/s²] and the ground rows of the barrier step (None without it)."""

    state: object
    av: object
    h: np.ndarray
    qdd_c: np.ndarray
    xdd: np.ndarray
    ground: GroundRows | None


@dataclass
class TamedEpisode:
    """What FPM's and CPM's step writes (see the module docstring), None where off: the
    avoidance fabric's work buffers (:class:`~tamedpuma.fabrics.FabricBuffers`), the stall monitor
    (:mod:`tamedpuma.methods._stall`), the configuration pull's monitor
    (:mod:`tamedpuma.methods._configuration_pull`), the control step Δt [s] (the scenario's;
    NaN before the first ``reset``) and where the ground rows were last computed empty: the
    configuration ``ground_at`` and how far [rad] any joint may move from it before a hull can
    need a row (``ground_reach``; :meth:`TamedController.ground_rows`)."""

    fabric: FabricBuffers
    stall: StallMonitor | None
    configuration: ConfigurationMonitor | None
    dt: float = float("nan")
    ground_at: np.ndarray | None = None
    ground_reach: float = 0.0


class TamedController:
    """What FPM and CPM share: PUMA pulled to the joints, the avoidance fabric energized, the
    forcing and the control-rate filters.
    Subclasses implement ``step`` from :meth:`forced`; ``creep_fraction``: the stall pull's
    creep criterion (0: off; :mod:`tamedpuma.methods._stall`). ``episode``: the episode state
    (an ``Episode``, :class:`TamedEpisode` or a subclass's), made by :meth:`reset`."""

    creep_fraction = 0.0
    Episode = TamedEpisode

    def __init__(self, puma: PumaController, fabric: Fabric, rate: ControlRate | None = None,
                 forcing: Forcing | None = None):
        self.puma, self.fabric = puma, fabric
        self.kinematics = puma.kinematics
        self.forcing, self.rate = forcing or Forcing(), rate or ControlRate()
        self.qd_max = np.asarray(self.kinematics.spec.qd_max, dtype=float)
        self.hulls = link_hulls(self.kinematics) if self.rate.barrier_step else None
        self.hull_table = HullTable.of(self.hulls) if self.hulls is not None else None
        n = len(self.qd_max)  # the rows where no hull is low (shared: never written)
        self.no_ground_rows = GroundRows(np.empty(0), np.empty((0, n)), np.empty(0))
        self.episode = self.new_episode()
        warm_up()  # the step's kernels compiled now, never inside a step (methods/_kernels.py)

    def new_episode(self, dt: float = float("nan")) -> TamedEpisode:
        """A fresh episode state (the monitors of the forcing's settings, nothing seen yet) of
        control step dt [s]."""
        forcing = self.forcing
        return self.Episode(self.fabric.buffers(), forcing.make_stall_monitor(self.creep_fraction),
                            forcing.make_configuration_monitor(self.kinematics.spec,
                                                               self.ground()), dt)

    @property
    def dt(self) -> float:
        """The control step Δt [s] of the current episode (the scenario's)."""
        return self.episode.dt

    def reset(self, scenario: Scenario) -> None:
        self.puma.reset(scenario)
        self.episode = self.new_episode(float(scenario.dt))
        self.fabric.prepare_at_start(self.kinematics, scenario, self.episode.fabric)
        configuration = self.episode.configuration
        if configuration is not None:  # the goal's IK before the first step
            configuration.prepare(scenario.goal.position, scenario.goal.quaternion, scenario.q0)

    def ground(self) -> Ground | None:
        """The ground the barrier step keeps (its geometry and plane), for the configuration
        pull's goal configuration; None when the step has no ground rows."""
        if self.hulls is None:
            return None
        return Ground(GROUND_HEIGHT_M, self.hulls)

    def forced(self, obs: Observation) -> Forced:
        """The fabric and PUMA's forcing at the observation (:class:`Forced`)."""
        ep = self.episode
        state, av = avoidance_at(self.kinematics, self.fabric, obs, ep.fabric)
        ground = self.ground_rows(state, obs.q, obs.qd)  # from the pass that evaluated state
        h, qdd_c, xdd = self.puma.with_avoidance(state, obs, av, self.forcing, ep.stall,
                                                 ep.configuration)
        return Forced(state, av, h, qdd_c, xdd, ground)

    def ground_rows(self, state, q: np.ndarray, qd: np.ndarray) -> GroundRows | None:
        """The heights above the ground the barrier step keeps (each moving link's lowest hull
        point), or None without the barrier step; ``state`` must be the kinematics' last
        evaluation, at (q, qd) (the rows read its pass).

        A hull needs a row only below ``bound Δt / κ`` (its vertical speed bound), and between
        two configurations its lowest point moves up or down by at most its Lipschitz constant
        times the largest joint displacement (:func:`~tamedpuma.robot.ground.vertical_bounds`).
        So where the rows came out empty, they stay empty while no joint has moved
        ``ground_reach`` from there: those steps skip the computation and get the same (empty)
        rows."""
        if self.hulls is None:
            return None
        ep, table = self.episode, self.hull_table
        if ep.ground_at is not None and float(_max(np.abs(q - ep.ground_at))) < ep.ground_reach:
            return self.no_ground_rows
        dt = ep.dt  # a hull higher than below needs no row
        below = table.speeds * (dt / BARRIER_KAPPA) if math.isfinite(dt) else np.inf
        rows = hull_ground_rows(self.kinematics, table, qd, below)  # (reach 0 where found)
        ep.ground_at, ep.ground_reach = (np.array(q, dtype=float), rows.reach) if rows.reach else (
            None, 0.0)
        return rows

    def stall_scalars(self) -> dict[str, float]:
        """``stall_pull``: 1 while the stall pull is armed, else 0; with the configuration pull
        on, ``configuration_pull``: 1 while it is engaged; ``psi``: PUMA's potential ψ as the
        stall monitor last sampled it (every 0.1 s; the step computes it anyway, so logging it
        costs nothing) (log scalars)."""
        stall, configuration = self.episode.stall, self.episode.configuration
        out = {"stall_pull": float(stall is not None and stall.armed)}
        if stall is not None and math.isfinite(stall.psi):
            out["psi"] = float(stall.psi)
        if configuration is not None:
            out["configuration_pull"] = float(configuration.engaged)
        return out


_max = np.maximum.reduce  # np.max without its Python wrapper
#: no barrier rows (the kernels' empty arguments)
_NO_ROWS = np.empty((0, 0))
_NO_METRIC = np.empty(0)


def free_pull(task, target: np.ndarray, damping, null: np.ndarray | None) -> np.ndarray:
    """PUMA's obstacle-free pull q̈_P = J⁺(ẍ_d − J̇q̇) + (I − J⁺J) q̈_null [rad/s²]
    (:func:`~tamedpuma.methods._policy.pull_to_joints`, fused: :func:`_kernels.damped_pull`);
    target: ẍ_d − J̇q̇."""
    lam = damping(task.J) if callable(damping) else damping
    has_null = null is not None
    return STEP["damped_pull"](task.J, target, lam**2, null if has_null else target[:0],
                               has_null)


def pulled_through_metric(av, task, forcing: Forcing, null, damping
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(q̈_C, h) [rad/s²] of ``forcing.mode`` metric or task_metric with the directional
    forcing's q̈_P (:func:`free_pull`, damping: PUMA's pseudo-inverse damping): one kernel call
    (:func:`_kernels.pulled_forcing`), the numbers of :func:`free_pull` then
    :func:`forced_through_metric`, which answer (and raise) where the system is singular or the
    result not finite."""
    target = task.xdd - task.jdqd
    rows, m, weight = av.barrier_rows, av.barrier_metric, forcing.weight
    if type(weight) is float:
        if rows is None or m is None:
            rows, m = _NO_ROWS, _NO_METRIC
        lam = damping(task.J) if callable(damping) else damping
        has_null = null is not None
        try:
            qdd_c, h, size = STEP["pulled_forcing"](
                av.M, av.f, rows, m, task.J, weight, target, forcing.null_metric,
                null if has_null else target[:0], has_null, lam**2, forcing.directional,
                forcing.mode == "task_metric")
            if math.isfinite(float(size)):
                return qdd_c, h
        except np.linalg.LinAlgError:  # a singular system: the calls below answer or raise
            pass
    qdd_free = free_pull(task, target, damping, null) if forcing.directional else None
    return forced_through_metric(av, task, target, forcing, null, qdd_free)


def forced_through_metric(av, task, target: np.ndarray, forcing: Forcing, null, qdd_free
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(q̈_C, h) [rad/s²] of ``forcing.mode`` metric or task_metric: PUMA's forcing through
    the avoidance metric (directional: settled on q̈_C, :func:`restore_approached`) and the
    geometry (−M⁻¹f, or :func:`geometry_with_task_metric`), fused in one kernel
    (:func:`_kernels.metric_forcing`); its numbers are those of :func:`forced_reference`,
    which answers (and raises: LinAlgError, FabricError) where the kernel's system is singular
    or its result not finite."""
    rows, m, weight = av.barrier_rows, av.barrier_metric, forcing.weight
    if type(weight) is float:
        if rows is None or m is None:
            rows, m = _NO_ROWS, _NO_METRIC
        has_null = null is not None
        try:
            qdd_c, h = STEP["metric_forcing"](
                av.M, av.f, rows, m, task.J, weight, target, forcing.null_metric,
                null if has_null else target[:0], has_null,
                target[:0] if qdd_free is None else qdd_free, forcing.directional,
                forcing.mode == "task_metric")
        except np.linalg.LinAlgError:  # a singular system: the reference path below raises it
            qdd_c = h = np.full(1, np.nan)
        if math.isfinite(float(qdd_c @ qdd_c + h @ h)):
            return qdd_c, h
    return forced_reference(av, task, forcing, null, qdd_free)


def forced_reference(av, task, forcing: Forcing, null, qdd_free
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(q̈_C, h) as :func:`forced_through_metric`, by the numpy functions it fuses."""
    weights = forcing.weight

    def solve(W: np.ndarray) -> np.ndarray:
        return pull_through_metric(task, W, weights, forcing.null_metric, null)

    if forcing.directional:
        receding = receding_rows(av, qdd_free)
        W = metric_without(av, receding)
        qdd_c, _ = restore_approached(av, receding, W, solve(W), solve)
    else:
        qdd_c = solve(av.M)
    if forcing.mode == "task_metric":
        return qdd_c, geometry_with_task_metric(av, task.J, weights)
    return qdd_c, av.acceleration()


def geometry_with_task_metric(av, J: np.ndarray, weights: float | np.ndarray) -> np.ndarray:
    """The avoidance geometry with PUMA's task metric as one more leaf [rad/s²]::

        h = −(M + Jᵀ diag(w) J)⁻¹ f

    M, f: the avoidance fabric's metric and geometry force (base, obstacle pairs, joint
    limits); J (m, n): PUMA's task Jacobian; w [1]: its task metric (scalar or (m,)). The task
    leaf is ``ẍ = 0`` with the constant metric w: a Finsler energy ½ẋᵀ diag(w) ẋ with a zero
    (degree-2 homogeneous) geometry, so the sum is still a fabric, energized the same way.
    Without it, h = −M⁻¹f moves the hand however the barriers' curvature terms (m_r J̇q̇ along
    each barrier row, at full strength wherever a barrier's metric exceeds the base's) and the
    joint-limit braking dictate, and PUMA's forcing, added after, is not weighed against it.
    With it, h acts where PUMA's task metric does not hold the hand: in free space it leaves
    the hand's acceleration to PUMA, near a barrier whose metric exceeds w it is the barrier's."""
    return solve_acceleration(av.M + J.T @ weighted_rows(weights, J), av.f)


def approached_metric(av, qdd_free: np.ndarray) -> np.ndarray:
    """The avoidance metric without the barrier rows PUMA's free acceleration q̈_P recedes from
    (``forcing.directional``): ``M − Σ_{r: a_r·q̈_P > 0} m_r a_r a_rᵀ`` (n, n), a fresh array.

    M = m_b I + Σ_r m_r a_r a_rᵀ over the barrier rows (pairs, joint limits, ground) of ``av``.
    A directional barrier's metric is on while its distance shrinks (s(ẋ) = [ẋ < 0]); at rest
    that is decided by the motors' noise, and a joint resting at its limit barrier (metric
    2k/x² with x clamped to 10⁻³: 10⁵) then holds PUMA's pull *away* from the limit as firmly
    as a push into it: the arm stays where it is for good, however far the goal and however
    clear the way. Here s is evaluated on the direction the forcing moves each barrier,
    ``a_r·q̈_P``: the forcing is resisted only along the barriers it approaches. The fabric (h,
    its metric, energization) is unchanged."""
    return metric_without(av, receding_rows(av, qdd_free))


def receding_rows(av, qdd: np.ndarray) -> np.ndarray | None:
    """The barrier rows of ``av`` the joint acceleration ``qdd`` [rad/s²] recedes from
    (``a_r·q̈ > 0``, metric on): a boolean mask over ``av.barrier_rows`` (None without rows).
    These are the rows :func:`approached_metric` leaves out."""
    rows, m = av.barrier_rows, av.barrier_metric
    if rows is None or m is None or rows.shape[0] == 0:
        return None
    return (rows @ qdd > 0.0) & (m > 0.0)


def metric_without(av, rows_out: np.ndarray | None) -> np.ndarray:
    """``M − Σ_{r ∈ rows_out} m_r a_r a_rᵀ`` (n, n), a fresh array (M itself when none)."""
    W = av.M.copy()
    if rows_out is not None and rows_out.any():
        r = av.barrier_rows[rows_out]
        W -= (r.T * av.barrier_metric[rows_out]) @ r
    return W


def restore_approached(av, receding: np.ndarray | None, W: np.ndarray, qdd_c: np.ndarray,
                       solve) -> tuple[np.ndarray, np.ndarray | None]:
    """(q̈_C [rad/s²], the rows still left out): PUMA's forcing with the directional metric
    settled on q̈_C itself.

    :func:`approached_metric` decides which barriers resist the forcing from PUMA's *free* pull
    q̈_P (the damped pseudo-inverse). The weighted solution ``q̈_C = solve(W)`` is not q̈_P:
    where an approached barrier's metric holds one joint, q̈_C moves the others instead, and it
    can drive one of them towards a limit whose row q̈_P recedes from and which W therefore
    leaves out. Nothing then weighs that joint against PUMA, and q̈_C accelerates it into its
    limit by self-motion, which PUMA's task rows do not see, even with no obstacle in the scene.
    Here every left-out row that q̈_C approaches (``a_r·q̈_C < 0``) is put back with its metric
    and q̈_C solved again, until no left-out row is approached: an active set that only grows,
    so at most as many solves as rows left out. The result is the same weighted pseudo-inverse
    of PUMA's spec through a metric between ``approached_metric`` and M, so the zero set of the
    forcing and the statements of :class:`Forcing` are unchanged.

    receding: the mask of :func:`receding_rows` (None: nothing left out); W: the metric without
    them; qdd_c: ``solve(W)``; solve: W ↦ q̈_C."""
    if receding is None:
        return qdd_c, None
    out = receding.copy()
    rows, m = av.barrier_rows, av.barrier_metric
    while out.any():
        back = out & (rows @ qdd_c < 0.0)
        if not back.any():
            break
        r = rows[back]
        W = W + (r.T * m[back]) @ r
        out &= ~back
        qdd_c = solve(W)
    return qdd_c, out


def damping_rule(settings) -> Damping:
    """The pseudo-inverse damping of PUMA's settings: ``pinv_damping`` λ₀, ``pinv_damping_max``
    λ_max (0: constant λ₀), ``manipulability_threshold`` w₀ (see :mod:`tamedpuma.methods.puma`)."""
    return Damping(float(settings.pinv_damping), float(settings.pinv_damping_max),
                   float(settings.manipulability_threshold))


def pulled_puma(settings, kinematics) -> PumaController:
    """The pulled PUMA policy of puma/fpm/cpm settings
    (:class:`~tamedpuma.methods._settings.PumaSettings`: checkpoint, pinv_damping and the
    singularity-robust rule, null_space, goal_velocity)."""
    task = load_task(settings)
    return PumaController(task, kinematics, damping_rule(settings),
                          null_objective(settings.null_space),
                          settings.goal_velocity == "feedforward")


def puma_and_fabric(settings, kinematics) -> tuple[PumaController, Fabric]:
    """The pulled PUMA policy and the avoidance fabric of fpm/cpm settings
    (:class:`~tamedpuma.methods._settings.FpmSettings`); the fabric's joint-limit leaves (and
    barrier rows) sit ``limit_margin`` [rad] inside the robot's limits, so the tracking error of
    the joint controller (PyBullet's velocity motors sag by ~1e-3 rad/s under gravity) cannot
    carry a joint past the real limit while its barrier holds."""
    margin = float(settings.limit_margin)
    q_min, q_max = np.asarray(kinematics.spec.q_min), np.asarray(kinematics.spec.q_max)
    if not 0.0 <= margin < 0.25 * float(np.min(q_max - q_min)):
        raise ConfigError(f"method.limit_margin must be in [0, a quarter of the smallest joint "
                          f"range), got {margin}")
    return pulled_puma(settings, kinematics), Fabric(settings.fabric, q_min + margin,
                                                     q_max - margin)


def avoidance_at(kinematics, fabric: Fabric, obs: Observation,
                 buffers: FabricBuffers | None = None):
    """(kinematic state, avoidance fabric) at the observation: one kinematics pass; buffers:
    the fabric's work buffers (the episode's; None: fresh ones)."""
    state = kinematics.evaluate(obs.q, obs.qd)
    av = fabric.avoidance(state, obs.q, obs.qd, obs.obstacle_centers, obs.obstacle_radii,
                          obs.obstacle_velocities, buffers)
    return state, av


def vector_norm(x: np.ndarray) -> float:
    """‖x‖ of a vector, as ``np.linalg.norm`` computes it (√(x·x), the same number) without
    its Python wrapper."""
    return math.sqrt(float(x.dot(x)))


def fabric_scalars(av) -> dict[str, float]:
    """The avoidance fabric's log scalars (shared by FPM and CPM); ``min_clearance_m`` is
    :data:`~tamedpuma.types.NO_OBSTACLE_CLEARANCE` without obstacles."""
    clearance = av.min_clearance if math.isfinite(av.min_clearance) else NO_OBSTACLE_CLEARANCE
    return {"energy_fabric": float(av.energy), "min_clearance_m": float(clearance),
            "n_clamped": float(av.n_clamped), "n_limit_clamped": float(av.n_limit_clamped)}


#: κ [1]: the largest fraction of a barrier distance one control period may use (barrier step)
BARRIER_KAPPA = 0.5
#: the barrier step lets a barrier distance shrink towards this, not 0 (each row's units:
#: obstacle pairs in radius sums, joint limits in rad, ground in m)
BARRIER_STANDOFF = 1.0e-3
#: [m] the plane the barrier step keeps every moving link's lowest hull point above
GROUND_HEIGHT_M = 0.01
#: h [1]: the speed limit scales q̇⁺ onto (1 − h) q̇_max, a margin for the joint velocity loop
#: (PyBullet's velocity motors, given a target at the limit, ran up to 1.0009× it)
SPEED_HEADROOM = 0.01


@dataclass(frozen=True)
class ControlRate:
    """What FPM and CPM do to stay safe at the control rate (:mod:`tamedpuma.fabrics.discrete`;
    the ``control_rate`` block of conf/method/fpm.yaml and cpm.yaml). Each only removes energy
    (see that module), so the paper's energy arguments still hold.

    barrier_step: project the next velocity so that no barrier is crossed within one period:
    body sphere × obstacle pairs, joint limits and the ground (each moving link's lowest
    collision-hull point kept :data:`GROUND_HEIGHT_M` above z = 0: the geometry the whole-body
    criterion judges; :mod:`tamedpuma.robot.ground`), a barrier distance shrinking by at most
    :data:`BARRIER_KAPPA` of itself per period, towards :data:`BARRIER_STANDOFF`.
    speed_limit: scale the next velocity uniformly onto ``(1 − SPEED_HEADROOM) q̇_max``
    (direction kept) instead of leaving the per-joint clamp to the simulator.
    semi_implicit: take the velocity-proportional terms implicitly along q̇ over the period (FPM:
    −α q̇; CPM: its whole coefficient c), so that a large |c|Δt brakes towards rest instead of
    reversing q̇, and leaves the push across q̇ whole
    (:func:`~tamedpuma.fabrics.discrete.energized_velocity_step`).

    ``ControlRate()`` has every filter off (the paper's laws as written); FPM's and CPM's
    settings give their own, every filter on
    (:func:`~tamedpuma.methods._settings.all_control_rate_filters`)."""

    barrier_step: bool = False
    speed_limit: bool = False
    semi_implicit: bool = False

    @staticmethod
    def from_mapping(cfg: Mapping | None) -> ControlRate:
        cfg = dict(cfg or {})
        unknown = sorted(set(cfg) - {field.name for field in fields(ControlRate)})
        if unknown:
            raise ConfigError(f"unknown method.control_rate keys {unknown}")
        return ControlRate(**cfg)  # missing keys: the dataclass defaults

    def next_velocity(self, qd_next, av, dt: float, qd_max, ground: GroundRows | None = None,
                      qd=None) -> tuple[np.ndarray, dict]:
        """Filter the next velocity q̇⁺ [rad/s] (ground: the robot's heights above the ground
        and their rows, :meth:`TamedController.ground_rows`; qd: the current velocity, whose
        rows' rates give the moving obstacles' drift); returns it and the log scalars
        ``n_barrier_active`` (rows projected) and ``speed_scale`` (s ≤ 1)."""
        n_active, scale = 0, 1.0
        if (self.barrier_step and av.barrier_rows is not None
                and not keeps_velocity(av, ground, qd_next, qd, dt)):
            rows, x, jd, drift = barrier_system(av, ground, qd)
            qd_next, n_active = barrier_step(qd_next, rows, x, dt, BARRIER_KAPPA, av.M, jd,
                                             drift, av.far_rows, BARRIER_STANDOFF)
        if self.speed_limit:
            qd_next, scale = STEP["limit_speed"](qd_next, (1.0 - SPEED_HEADROOM) * qd_max)
        return qd_next, {"n_barrier_active": float(n_active), "speed_scale": scale}


def barrier_system(av, ground: GroundRows | None, qd):
    """The barrier step's rows J (r, n), distances x (r,) [m | rad], J̇q̇ (r,) and drift (r,)
    (the obstacles' part of ẋ at the current velocity qd, None without moving obstacles): the
    avoidance's rows of ``av``, then the ground's (heights above :data:`GROUND_HEIGHT_M`, no
    drift)."""
    rows, x, jd = av.barrier_rows, av.barrier_x, av.barrier_jdqd
    drift = None if av.barrier_xd is None or qd is None else av.barrier_xd - rows @ qd
    if ground is not None:
        rows = np.concatenate((rows, ground.rows))
        x = np.concatenate((x, ground.heights - GROUND_HEIGHT_M))
        jd = np.concatenate((jd, ground.jdqd))
        if drift is not None:
            drift = np.concatenate((drift, np.zeros(len(ground.heights))))
    return rows, x, jd, drift


def keeps_velocity(av, ground: GroundRows | None, v: np.ndarray, qd, dt: float) -> bool:
    """Whether the barrier step keeps the next velocity v [rad/s] as it is (the common case:
    no row of ``av`` or ``ground`` would be violated, with or without the obstacles' drift,
    and the rows left out provably hold), by one kernel (:func:`_kernels.rows_free`) instead of
    the step's concatenations and products; False sends the step the whole way
    (:func:`~tamedpuma.fabrics.discrete.barrier_step`), which then decides the same."""
    if av.barrier_jdqd is None:
        return False
    has_drift = av.barrier_xd is not None and qd is not None
    n = len(v)
    g_rows, g_heights, g_jdqd = ((ground.rows, ground.heights, ground.jdqd) if ground is not None
                                 else (np.empty((0, n)), v[:0], v[:0]))
    if not STEP["rows_free"](v, av.barrier_rows, av.barrier_x, av.barrier_jdqd,
                             av.barrier_xd if has_drift else v[:0], qd if has_drift else v,
                             has_drift, g_rows, g_heights, g_jdqd, GROUND_HEIGHT_M, dt,
                             BARRIER_KAPPA, BARRIER_STANDOFF):
        return False
    far = av.far_rows
    return far is None or far.holds(v, dt, BARRIER_KAPPA, BARRIER_STANDOFF)


#: w [1]: PUMA's task metric in the metric forcing (outweighs the base metric 0.2 and a barrier's
#: metric until the barrier is within a few millimetres)
TASK_WEIGHT = 100.0
#: m_null [1]: the metric of the secondary (elbow) objective in the metric forcing
NULL_METRIC = 0.05
#: how PUMA's forcing may meet the avoidance fabric (``method.forcing.mode``)
FORCING_MODES = ("additive", "metric", "task_metric")


@dataclass(frozen=True)
class Forcing:
    """How FPM and CPM pull PUMA's forcing into joint space (``method.forcing``).

    mode ``additive``: paper eq. 9/10 with f_θ^C = J⁺(ẍ_d − J̇q̇) + N q̈_null (damped
    pseudo-inverse): PUMA's push is blind to the obstacles; only the barriers' geometry (∝ ‖q̇‖²,
    so nothing at low speed) resists it, and the arm hovers against an obstacle that lies on
    PUMA's path. ``metric``: the pullback of PUMA's task spec ``(w I, −w ẍ_d)`` summed with the
    avoidance fabric's metric M (base, obstacle pairs, joint limits), as a forced fabric sums
    its forcing spec: ``f_θ^C = (M + wJᵀJ + m_null I)⁻¹(wJᵀ(ẍ_d − J̇q̇) + m_null q̈_null)``
    (:func:`~tamedpuma.methods._policy.pull_through_metric`; w = :data:`TASK_WEIGHT`, m_null =
    :data:`NULL_METRIC`), a weighted pseudo-inverse which in free space realises ẍ_d as the
    damped one does (λ² ≈ (m_b + m_null)/w) and near a barrier suppresses the push along its
    normal (M ~ 0.2/x per obstacle pair, 0.1/x² per approached joint limit), so the arm slides
    along the obstacle instead of hovering against it. h is the paper's and the zero set of
    f_θ^C is unchanged (q̇ = 0, ẍ_d = 0 leaves only the damped elbow objective), so FPM's and
    CPM's statements hold as with ``additive``. ``task_metric``: ``metric``, and PUMA's task
    metric one more leaf of the geometry, ``h = −(M + Jᵀ w J)⁻¹f``
    (:func:`geometry_with_task_metric`).
    directional: leave out of the metric the barrier rows the forcing recedes from
    (:func:`approached_metric`, settled on q̈_C itself: rows q̈_C approaches are put back and
    q̈_C solved again, :func:`restore_approached`; not with ``additive``);
    stall_pull: g [m/s²] of the goal attractor added to PUMA's position rows once the hand
    stops making progress (0: off; :mod:`tamedpuma.methods._stall`); configuration_pull:
    whether a joint-space attractor to a clear goal configuration replaces PUMA's rows after
    the stall pull arms (:mod:`tamedpuma.methods._configuration_pull`).

    ``Forcing()`` is the paper's (``additive``, nothing added); FPM's and CPM's settings give
    their own (:func:`~tamedpuma.methods._settings.fpm_forcing`,
    :func:`~tamedpuma.methods.cpm.cpm_forcing`)."""

    mode: str = "additive"
    directional: bool = False
    stall_pull: float = 0.0
    configuration_pull: bool = False

    @property
    def weight(self) -> float:
        """w [1], PUMA's task metric (:data:`TASK_WEIGHT`)."""
        return TASK_WEIGHT

    @property
    def null_metric(self) -> float:
        """m_null [1] (:data:`NULL_METRIC`)."""
        return NULL_METRIC

    @property
    def metric(self) -> bool:
        """Whether PUMA's forcing is pulled through the avoidance fabric's metric."""
        return self.mode != "additive"

    def make_configuration_monitor(self, spec, ground: Ground | None = None
                                   ) -> ConfigurationMonitor | None:
        """A fresh :class:`~tamedpuma.methods._configuration_pull.ConfigurationMonitor` for the
        robot ``spec`` and the controller's ``ground`` (None when ``configuration_pull`` is off
        or there is no stall pull)."""
        if not self.configuration_pull or self.stall_pull <= 0.0:
            return None
        return ConfigurationMonitor(ConfigurationPull(), spec, ground)

    def make_stall_monitor(self, progress_fraction: float = 0.0) -> StallMonitor | None:
        """A fresh :class:`~tamedpuma.methods._stall.StallMonitor` (None when ``stall_pull``
        is 0); progress_fraction: the creep criterion (CPM's, :mod:`tamedpuma.methods._stall`)."""
        if self.stall_pull <= 0.0:
            return None
        return StallMonitor(StallPull(gain=self.stall_pull, progress_fraction=progress_fraction))

    def __post_init__(self):
        if self.mode not in FORCING_MODES:
            raise ConfigError(f"method.forcing.mode must be one of {FORCING_MODES}, got "
                              f"{self.mode!r}")
        if not isinstance(self.configuration_pull, bool):
            raise ConfigError(f"method.forcing.configuration_pull must be true or false, got "
                              f"{self.configuration_pull!r}")
        if not self.stall_pull >= 0:
            raise ConfigError(f"method.forcing.stall_pull [m/s²] must be ≥ 0, got "
                              f"{self.stall_pull}")

    @staticmethod
    def from_mapping(cfg: Mapping | None) -> Forcing:
        cfg = dict(cfg or {})
        unknown = sorted(set(cfg) - {field.name for field in fields(Forcing)})
        if unknown:
            raise ConfigError(f"unknown method.forcing keys {unknown}")
        return Forcing(**cfg)  # checked in __post_init__
