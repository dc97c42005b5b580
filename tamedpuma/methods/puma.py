"""Vanilla PUMA (method.md §4): the network's task acceleration pulled back to the joints.

    q̈ = J⁺(ẍ_d − J̇q̇) + N q̈_null,   ẍ_d = f_θ^T(x_ee, ẋ_ee)          [rad/s²]

with a damped pseudo-inverse and the "elbow up" null-space objective. No obstacle avoidance: it is
the paper's reference for paths (path difference 0) and its unsafe baseline.
Scalars: ``task_acc_norm`` ‖ẍ_d‖ and ``joint_acc_norm`` ‖q̈‖.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from tamedpuma.methods._learned import load_task, null_objective
from tamedpuma.methods._policy import NullSpaceObjective, pull_to_joints
from tamedpuma.types import Command, Observation, Scenario


class PumaController:
    """PUMA pulled to joint space. task: a :class:`~tamedpuma.methods._policy.PoseTask` or
    :class:`~tamedpuma.methods._policy.PlanarTask`; damping: λ of the pseudo-inverse."""

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


def make(cfg: Mapping, kinematics) -> PumaController:
    return PumaController(load_task(cfg), kinematics, float(cfg.get("pinv_damping", 0.01)),
                          null_objective(cfg.get("null_space")))
