"""A damped attractor in joint space: the simplest real controller of the episode loop.

At reset, damped least-squares IK finds a target configuration q* for the scenario's goal pose
(starting from q0). Each step::

    q̈ = −k (q − q*) − d q̇          [rad/s²]

with stiffness k [1/s²] and damping d [1/s] (critically damped for d = 2√k). No obstacle avoidance.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from tamedpuma.methods._settings import nonneg, positive
from tamedpuma.robot.ik import solve_pose_ik
from tamedpuma.robot.kinematics import Kinematics
from tamedpuma.types import Command, Observation, Scenario

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JointEpisode:
    """The episode state: q* [rad], the IK solution of the episode's goal pose (made by
    ``reset``; the step only reads it)."""

    q_target: np.ndarray


class JointAttractor:
    """q̈ = −k (q − q*) − d q̇ towards the IK solution q* of the goal pose. ``episode``: the
    episode state (:class:`JointEpisode`), made by :meth:`reset`."""

    def __init__(self, kinematics: Kinematics, stiffness: float, damping: float):
        if not (stiffness > 0 and damping > 0):
            raise ValueError("joint_attractor stiffness and damping must be positive")
        self.kinematics = kinematics
        self.stiffness = stiffness
        self.damping = damping
        self.episode = JointEpisode(np.zeros(kinematics.spec.dof))

    def reset(self, scenario: Scenario) -> None:
        result = solve_pose_ik(self.kinematics, scenario.goal.position,
                               scenario.goal.quaternion, scenario.q0)
        if not result.converged:
            log.warning("IK for the goal pose did not converge (position error %.3g m, "
                        "orientation error %.3g rad)", result.position_error,
                        result.orientation_error)
        self.episode = JointEpisode(result.q)

    def step(self, obs: Observation) -> Command:
        error = obs.q - self.episode.q_target
        qdd = -self.stiffness * error - self.damping * obs.qd
        return Command(qdd=qdd, scalars={"joint_error_rad": float(np.linalg.norm(error))})


@dataclass(frozen=True)
class JointAttractorSettings:
    """method=joint_attractor (``conf/method/joint_attractor.yaml``)."""

    stiffness: float = 4.0           # k [1/s²]
    damping: float = 4.0             # d [1/s]; 2√k = critically damped

    def __post_init__(self):
        positive("method.stiffness", self.stiffness)
        nonneg("method.damping", self.damping)


#: the settings ``make`` takes
SETTINGS = JointAttractorSettings


def make(settings: JointAttractorSettings, kinematics: Kinematics) -> JointAttractor:
    return JointAttractor(kinematics, float(settings.stiffness), float(settings.damping))
