"""TamedPUMA, Forcing Policy Method (paper eq. 9): the energized avoidance fabric forced by the
pulled PUMA policy,

    q̈ = energize_{L_e}[h](q, q̇) + f_θ^C(q, q̇)                                    [rad/s²]

h = −M⁻¹ f is the summed, pulled-back avoidance geometry (body spheres × obstacles, joint limits);
energization ``h̃ = h − α q̇`` with ``α = q̇ᵀ(M h + f_e)/(q̇ᵀ M q̇ + ε)`` keeps its energy H_{L_e}
constant; f_θ^C is :class:`~tamedpuma.methods.puma.PumaController`'s pulled acceleration.
Scalars: ``energy_fabric`` (H_{L_e}), ``alpha`` (α [1/s]), ``min_clearance`` [m] (body spheres vs
obstacles, 1e3 without obstacles), ``n_clamped``, ``n_limit_clamped``, ``task_acc_norm``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._learned import load_task, null_objective
from tamedpuma.methods.puma import PumaController
from tamedpuma.types import Command, Observation, Scenario

NO_OBSTACLE_CLEARANCE = 1.0e3


def fabric_scalars(av) -> dict[str, float]:
    """The avoidance fabric's log scalars (shared by FPM and CPM)."""
    clearance = av.min_clearance if np.isfinite(av.min_clearance) else NO_OBSTACLE_CLEARANCE
    return {"energy_fabric": float(av.energy), "min_clearance": float(clearance),
            "n_clamped": float(av.n_clamped), "n_limit_clamped": float(av.n_limit_clamped)}


def avoidance_at(kinematics, fabric: Fabric, obs: Observation):
    """(kinematic state, avoidance fabric) at the observation: one kinematics pass."""
    state = kinematics.evaluate(obs.q, obs.qd)
    av = fabric.avoidance(state, obs.q, obs.qd, obs.obstacle_centers, obs.obstacle_radii,
                          obs.obstacle_velocities)
    return state, av


def puma_and_fabric(cfg: Mapping, kinematics) -> tuple[PumaController, Fabric]:
    """The pulled PUMA policy and the avoidance fabric of an fpm/cpm config."""
    puma = PumaController(load_task(cfg), kinematics, float(cfg.get("pinv_damping", 0.01)),
                          null_objective(cfg.get("null_space")))
    gains = FabricGains.from_mapping(cfg.get("fabric"))
    return puma, Fabric(gains, kinematics.spec.q_min, kinematics.spec.q_max)


class FpmController:
    """FPM on one robot: ``fabric`` (a :class:`Fabric`) for avoidance, ``puma`` for forcing."""

    def __init__(self, puma: PumaController, fabric: Fabric):
        self.puma, self.fabric = puma, fabric
        self.kinematics = puma.kinematics

    def reset(self, scenario: Scenario) -> None:
        self.puma.reset(scenario)

    def step(self, obs: Observation) -> Command:
        qd = obs.qd
        state, av = avoidance_at(self.kinematics, self.fabric, obs)
        h = av.acceleration()
        alpha = av.alpha(qd, h, self.fabric.gains.energization_eps)
        qdd_c, xdd = self.puma.joint_acceleration(state, obs)
        qdd = h - alpha * qd + qdd_c
        return Command(qdd=qdd, scalars={**fabric_scalars(av), "alpha": alpha,
                                         "task_acc_norm": float(np.linalg.norm(xdd))})


def make(cfg: Mapping, kinematics) -> FpmController:
    return FpmController(*puma_and_fabric(cfg, kinematics))
