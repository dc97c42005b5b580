"""The ``pink_cbf`` controller: one QP per control period Δt [s] (pin-pink, a qpsolvers backend).

With the hand at pose (p, R), velocity q̇ and PUMA's task acceleration ẍ_d = (a, α)
[m/s², rad/s²], the hand's target twist over the period is PUMA's velocity one step on,

    (v_d, ω_d) = J q̇ + ẍ_d Δt,    target pose (p + v_d Δt, exp(ω_d Δt) R),

tracked by pink's :class:`~pink.tasks.FrameTask`; a :class:`~pink.tasks.PostureTask` towards the
start configuration regularizes the redundancy. The QP in the joint step Δq = v Δt is

    min_Δq  Σ_tasks ‖J_t Δq + e_t‖²_{W_t} + λ‖Δq‖²
    s.t.    q_min + m ≤ q + Δq ≤ q_max − m,  |Δq| ≤ (1 − h) q̇_max Δt    (joint limits)
            ∂h_k/∂q v + ∂h_k/∂t ≥ −γ h_k                              (every barrier row k)

with the barriers (:class:`SphereObstacleBarrier`, :class:`GroundBarrier`)

    h_ij = ‖c_i(q) − o_j(t)‖ − r_i − r_j − d_min     [m]  body sphere i, obstacle j,
    h_i  = z_i(q) − r_i − z_ground                    [m]  body sphere i, ground plane.

The command is the QP's velocity: q̈ = (v − q̇)/Δt, so the simulator's q̇_cmd = q̇ + q̈Δt = v.
Where the QP has no solution the arm holds (v = 0) and ``qp_failures`` counts it.
"""

from __future__ import annotations

import time

import numpy as np
import pinocchio as pin
import qpsolvers
from pink import Configuration, build_ik
from pink.barriers import Barrier
from pink.limits import ConfigurationLimit, VelocityLimit
from pink.tasks import FrameTask, PostureTask

from tamedpuma.types import NO_OBSTACLE_CLEARANCE, Command, Observation, Scenario

_WORLD = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def _spheres(configuration: Configuration, frame_ids) -> tuple[np.ndarray, np.ndarray]:
    """Body-sphere centres (k, 3) [m] and their position Jacobians (k, 3, n) at the
    configuration (its frame placements and joint Jacobians are computed)."""
    model, data = configuration.model, configuration.data
    centers = np.array([data.oMf[i].translation for i in frame_ids]).reshape(-1, 3)
    jacobians = np.array([pin.getFrameJacobian(model, data, i, _WORLD)[:3] for i in frame_ids])
    return centers, jacobians.reshape(len(frame_ids), 3, model.nv)


class _SphereBarrier(Barrier):
    """A barrier of body-sphere rows h_i(q, t) ≥ 0 [m]: a subclass gives ``_rows`` =
    (h (m,), ∂h/∂q (m, n), ∂h/∂t (m,)); the CBF constraint ∂h/∂q q̇ + ∂h/∂t ≥ −γ h enters the
    QP as G Δq ≤ b with G = −∂h/∂q / Δt, b = γ h + ∂h/∂t. No objective term of its own."""

    def _rows(self, configuration: Configuration):
        raise NotImplementedError

    def compute_barrier(self, configuration: Configuration) -> np.ndarray:
        return self._rows(configuration)[0]

    def compute_jacobian(self, configuration: Configuration) -> np.ndarray:
        return self._rows(configuration)[1]

    def compute_qp_objective(self, configuration: Configuration):
        nv = configuration.model.nv
        return np.zeros((nv, nv)), np.zeros(nv)

    def compute_qp_inequalities(self, configuration: Configuration, dt: float = 1e-3):
        h, jac, dh_dt = self._rows(configuration)
        self.dim = len(h)
        return -jac / dt, self.gamma * h + dh_dt


class SphereObstacleBarrier(_SphereBarrier):
    """h_ij = ‖c_i − o_j‖ − r_i − r_j − d_min [m] for the pairs closer than the activation
    distance; ∂h/∂q = n_ijᵀ J_i with n_ij = (c_i − o_j)/‖c_i − o_j‖; moving obstacles add
    ∂h/∂t = −n_ij·ȯ_j. Set the obstacles with :meth:`update` before each solve."""

    def __init__(self, frame_ids, radii, gain: float, d_min: float, activation: float):
        super().__init__(dim=0, gain=gain, safe_displacement_gain=0.0)
        self.frame_ids, self.radii = tuple(frame_ids), np.asarray(radii, float)
        self.d_min, self.activation, self.gamma = float(d_min), float(activation), float(gain)
        self.centers = np.zeros((0, 3))
        self.obstacle_radii = np.zeros(0)
        self.velocities = np.zeros((0, 3))
        self.min_clearance = NO_OBSTACLE_CLEARANCE

    def update(self, centers, radii, velocities) -> None:
        self.centers = np.asarray(centers, float).reshape(-1, 3)
        self.obstacle_radii = np.asarray(radii, float).reshape(-1)
        self.velocities = np.asarray(velocities, float).reshape(-1, 3)

    def _rows(self, configuration: Configuration):
        """(h (m,), ∂h/∂q (m, n), ∂h/∂t (m,)) of the active pairs."""
        nv = configuration.model.nv
        if not len(self.centers):
            self.min_clearance = NO_OBSTACLE_CLEARANCE
            return np.zeros(0), np.zeros((0, nv)), np.zeros(0)
        c, jac = _spheres(configuration, self.frame_ids)
        diff = c[:, None, :] - self.centers[None, :, :]                 # (k, n_obs, 3)
        dist = np.linalg.norm(diff, axis=2)
        h = dist - self.radii[:, None] - self.obstacle_radii[None, :]
        self.min_clearance = float(h.min())
        i, j = np.nonzero(h - self.d_min < self.activation)
        normal = diff[i, j] / np.maximum(dist[i, j], 1e-9)[:, None]     # (m, 3)
        rows = np.einsum("mk,mkn->mn", normal, jac[i])
        moving = np.linalg.norm(rows, axis=1) > 1e-9  # a fixed sphere has no say in the QP
        dh_dt = -np.einsum("mk,mk->m", normal, self.velocities[j])
        return (h[i, j] - self.d_min)[moving], rows[moving], dh_dt[moving]


class GroundBarrier(_SphereBarrier):
    """h_i = z_i − r_i − z_ground [m] for every body sphere on a moving link; ∂h/∂q = J_i[z]."""

    def __init__(self, frame_ids, radii, gain: float, height: float):
        super().__init__(dim=0, gain=gain, safe_displacement_gain=0.0)
        self.frame_ids, self.radii = tuple(frame_ids), np.asarray(radii, float)
        self.height, self.gamma = float(height), float(gain)
        self.min_clearance = NO_OBSTACLE_CLEARANCE

    def _rows(self, configuration: Configuration):
        c, jac = _spheres(configuration, self.frame_ids)
        h = c[:, 2] - self.radii - self.height
        rows = jac[:, 2, :]
        moving = np.linalg.norm(rows, axis=1) > 1e-9
        self.min_clearance = float(h[moving].min()) if moving.any() else NO_OBSTACLE_CLEARANCE
        return h[moving], rows[moving], np.zeros(int(moving.sum()))  # a ground that stays put


class PinkCbf:
    """The controller (module docstring). kinematics: tamedpuma's
    :class:`~tamedpuma.robot.kinematics.Kinematics` of the controller body (its pinocchio model
    carries the body spheres as frames); task: PUMA's task adapter
    (:func:`tamedpuma.methods.puma_task`); settings: :class:`pink_cbf.PinkCbfSettings`."""

    def __init__(self, kinematics, task, settings):
        if settings.solver not in qpsolvers.available_solvers:
            raise ValueError(f"method.solver {settings.solver!r} is not installed; choose one "
                             f"of {qpsolvers.available_solvers}")
        self.kinematics, self.task, self.settings = kinematics, task, settings
        spec, s = kinematics.spec, settings
        limits_model = pin.Model(kinematics.model)  # the robot config's limits, not the URDF's
        limits_model.lowerPositionLimit = np.asarray(spec.q_min, float) + s.limit_margin
        limits_model.upperPositionLimit = np.asarray(spec.q_max, float) - s.limit_margin
        self.limits = [ConfigurationLimit(limits_model, s.limit_gain),
                       VelocityLimit(kinematics.model, (1 - s.speed_headroom)
                                     * np.asarray(spec.qd_max, float))]
        radii = kinematics.sphere_radii
        self.obstacles = SphereObstacleBarrier(kinematics.sphere_ids, radii, s.barrier_gain,
                                               s.d_min, s.activation_distance)
        self.barriers = [self.obstacles]
        self.ground = None
        if s.ground_height is not None:
            self.ground = GroundBarrier(kinematics.sphere_ids, radii, s.barrier_gain,
                                        s.ground_height)
            self.barriers.append(self.ground)
        self.hand = FrameTask(spec.ee_link, position_cost=s.position_cost,
                              orientation_cost=s.orientation_cost)
        self.posture = PostureTask(cost=s.posture_cost)
        self.dt, self.failures = 0.02, 0

    def reset(self, scenario: Scenario) -> None:
        self.dt, self.failures = float(scenario.dt), 0
        self.posture.set_target(np.asarray(scenario.q0, float))

    def step(self, obs: Observation) -> Command:
        q, qd, dt = np.asarray(obs.q, float), np.asarray(obs.qd, float), self.dt
        state = self.kinematics.evaluate(q, qd)  # also fills the model's data for pink below
        xdd = self.task.acceleration(state, qd, obs.goal_position, obs.goal_quaternion,
                                     obs.goal_velocity).xdd
        twist = state.ee_jacobian @ qd + dt * xdd
        target = pin.SE3(pin.exp3(dt * twist[3:]) @ state.ee_rotation,
                         state.ee_position + dt * twist[:3])
        self.hand.set_target(target)
        configuration = Configuration(self.kinematics.model, self.kinematics.data, q,
                                      copy_data=False, forward_kinematics=False)
        self.obstacles.update(obs.obstacle_centers, obs.obstacle_radii, obs.obstacle_velocities)
        start = time.perf_counter()
        problem = build_ik(configuration, [self.hand, self.posture], dt, self.settings.damping,
                           self.limits, self.barriers)
        result = qpsolvers.solve_problem(problem, solver=self.settings.solver)
        solve_ms = 1e3 * (time.perf_counter() - start)
        if result.found and result.x is not None and np.all(np.isfinite(result.x)):
            v = result.x / dt
        else:
            self.failures += 1
            v = np.zeros_like(q)
        scalars = {"qp_failures": float(self.failures), "qp_solve_ms": solve_ms,
                   "qp_barrier_rows": float(sum(b.dim for b in self.barriers)),
                   "min_clearance_m": min(self.obstacles.min_clearance, NO_OBSTACLE_CLEARANCE),
                   "task_acc_norm": float(np.linalg.norm(xdd))}
        if self.ground is not None:
            scalars["ground_clearance_m"] = self.ground.min_clearance
        return Command(qdd=(v - qd) / dt, scalars=scalars)
