"""TamedPUMA, Forcing Policy Method (paper eq. 9): the energized avoidance fabric forced by the
pulled PUMA policy,

    q̈ = energize_{L_e}[h](q, q̇) + f_θ^C(q, q̇)                                    [rad/s²]

h = −M⁻¹ f is the summed, pulled-back avoidance geometry (body spheres × obstacles, joint limits);
energization ``h̃ = h − α q̇`` with ``α = q̇ᵀ(M h + f_e)/(q̇ᵀ M q̇ + ε)`` keeps its energy H_{L_e}
constant; f_θ^C is :class:`~tamedpuma.methods.puma.PumaController`'s pulled acceleration.
Scalars: ``energy_fabric`` (H_{L_e}), ``alpha`` (α [1/s]), ``min_clearance_m`` [m] (body
spheres vs obstacles, 1e3 without obstacles), ``n_clamped``, ``n_limit_clamped``, ``task_acc_norm``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from tamedpuma.fabrics import Fabric
from tamedpuma.methods._tamed import PumaController, avoidance_at, fabric_scalars, puma_and_fabric
from tamedpuma.types import Command, Observation, Scenario


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
