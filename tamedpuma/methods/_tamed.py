"""Shared by the methods built on a trained PUMA primitive (puma, fpm, cpm): the pulled PUMA
policy, its construction from a method config, and the avoidance fabric FPM and CPM add to it.

Methods never import each other; what two of them share lives here.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._learned import load_task, null_objective
from tamedpuma.methods._policy import NullSpaceObjective, pull_to_joints
from tamedpuma.types import NO_OBSTACLE_CLEARANCE, Command, Observation, Scenario


class PumaController:
    """PUMA pulled to joint space (see :mod:`tamedpuma.methods.puma`):
    ``q̈ = J⁺(ẍ_d − J̇q̇) + N q̈_null`` [rad/s²]. task: a
    :class:`~tamedpuma.methods._policy.PoseTask` or :class:`~tamedpuma.methods._policy.PlanarTask`;
    damping: λ of the pseudo-inverse."""

    def __init__(self, task, kinematics, damping: float = 0.01,
                 null_space: NullSpaceObjective | None = None):
        self.task, self.kinematics = task, kinematics
        self.damping, self.null_space = damping, null_space

    def reset(self, scenario: Scenario) -> None:
        pass

    def joint_acceleration(self, state, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """(q̈_C, ẍ_d): the pulled PUMA acceleration at the observation (state = kinematics)."""
        task = self.task.acceleration(state, obs.qd, obs.goal_position, obs.goal_quaternion)
        null = self.null_space.acceleration(self.kinematics, obs.qd) if self.null_space else None
        return pull_to_joints(task, self.damping, null), task.xdd

    def step(self, obs: Observation) -> Command:
        state = self.kinematics.evaluate(obs.q, obs.qd)
        qdd, xdd = self.joint_acceleration(state, obs)
        return Command(qdd=qdd, scalars={"task_acc_norm": float(np.linalg.norm(xdd)),
                                         "joint_acc_norm": float(np.linalg.norm(qdd))})


def pulled_puma(cfg: Mapping, kinematics) -> PumaController:
    """The pulled PUMA policy of a puma/fpm/cpm method config (checkpoint, pinv_damping,
    null_space)."""
    return PumaController(load_task(cfg), kinematics, float(cfg["pinv_damping"]),
                          null_objective(cfg.get("null_space")))


def puma_and_fabric(cfg: Mapping, kinematics) -> tuple[PumaController, Fabric]:
    """The pulled PUMA policy and the avoidance fabric of an fpm/cpm config."""
    gains = FabricGains.from_mapping(cfg.get("fabric"))
    return pulled_puma(cfg, kinematics), Fabric(gains, kinematics.spec.q_min,
                                                kinematics.spec.q_max)


def avoidance_at(kinematics, fabric: Fabric, obs: Observation):
    """(kinematic state, avoidance fabric) at the observation: one kinematics pass."""
    state = kinematics.evaluate(obs.q, obs.qd)
    av = fabric.avoidance(state, obs.q, obs.qd, obs.obstacle_centers, obs.obstacle_radii,
                          obs.obstacle_velocities)
    return state, av


def fabric_scalars(av) -> dict[str, float]:
    """The avoidance fabric's log scalars (shared by FPM and CPM); ``min_clearance_m`` is
    :data:`~tamedpuma.types.NO_OBSTACLE_CLEARANCE` without obstacles."""
    clearance = av.min_clearance if np.isfinite(av.min_clearance) else NO_OBSTACLE_CLEARANCE
    return {"energy_fabric": float(av.energy), "min_clearance_m": float(clearance),
            "n_clamped": float(av.n_clamped), "n_limit_clamped": float(av.n_limit_clamped)}
