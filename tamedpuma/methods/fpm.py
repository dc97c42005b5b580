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
from tamedpuma.fabrics.discrete import implicit_velocity_step
from tamedpuma.methods._tamed import (
    ControlRate,
    PumaController,
    alpha_floor,
    avoidance_at,
    bounded_alpha,
    fabric_scalars,
    puma_and_fabric,
)
from tamedpuma.types import Command, Observation, Scenario


class FpmController:
    """FPM on one robot: ``fabric`` (a :class:`Fabric`) for avoidance, ``puma`` for forcing."""

    def __init__(self, puma: PumaController, fabric: Fabric, alpha_min: float | None = None,
                 rate: ControlRate | None = None):
        self.puma, self.fabric = puma, fabric
        self.kinematics = puma.kinematics
        self.alpha_min, self.rate = alpha_min, rate or ControlRate()
        self.qd_max = np.asarray(self.kinematics.spec.qd_max, dtype=float)
        self.dt = 0.02

    def reset(self, scenario: Scenario) -> None:
        self.puma.reset(scenario)
        self.dt = float(scenario.dt)

    def step(self, obs: Observation) -> Command:
        qd = obs.qd
        state, av = avoidance_at(self.kinematics, self.fabric, obs)
        h = av.acceleration()
        alpha_raw = av.alpha(qd, h, self.fabric.gains.energization_eps)
        alpha = bounded_alpha(alpha_raw, self.alpha_min)
        qdd_c, xdd = self.puma.joint_acceleration(state, obs)
        if self.rate.semi_implicit:
            qd_next = implicit_velocity_step(qd, h + qdd_c, -alpha, self.dt)
        else:
            qd_next = qd + self.dt * (h - alpha * qd + qdd_c)
        qd_next, extra = self.rate.next_velocity(qd_next, av, self.dt, self.qd_max, state)
        qdd = (qd_next - qd) / self.dt
        return Command(qdd=qdd, scalars={**fabric_scalars(av), "alpha": alpha,
                                         "alpha_raw": alpha_raw, **extra,
                                         "task_acc_norm": float(np.linalg.norm(xdd))})


def make(cfg: Mapping, kinematics) -> FpmController:
    return FpmController(*puma_and_fabric(cfg, kinematics), alpha_floor(cfg),
                         ControlRate.from_mapping(cfg["control_rate"]))
