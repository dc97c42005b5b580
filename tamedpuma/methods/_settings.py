"""The settings of the methods driven by a trained PUMA primitive (puma, fpm, cpm, modulation_ik):
frozen dataclasses, their defaults the only defaults, their ranges checked in ``__post_init__``
(a :class:`~tamedpuma.errors.ConfigError` naming the key). The defaults are what
``method=<name>`` runs, the project's additions included (``tests/test_method_settings.py``
composes every ``conf/method/<name>.yaml`` and checks it equals ``SETTINGS()``); the paper's laws
as written are the variants ``conf/method/fpm_literal.yaml`` and ``cpm_literal.yaml``, which
override them. Each method's ``make(settings, kinematics)`` takes one of them; ``app/schema.py``
types a composed config into them (with the method's ``name`` and ``label``).

The shared ones live here because methods never import each other: :class:`PumaSettings`
(method=puma) and :class:`FpmSettings` (method=fpm, PUMA's plus the avoidance fabric's), which
CPM's settings extend in :mod:`tamedpuma.methods.cpm`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from tamedpuma.errors import ConfigError
from tamedpuma.fabrics.gains import FabricGains
from tamedpuma.methods._tamed import ControlRate, Forcing

#: how a learned method finds its model with ``checkpoint`` null (:mod:`tamedpuma.puma.store`)
MODEL_CHOICES = ("auto", "real", "shipped")


def check(ok: bool, key: str, rule: str, value) -> None:
    """A :class:`ConfigError` ``"<key> must be <rule>, got <value>"`` unless ``ok``."""
    if not ok:
        raise ConfigError(f"{key} must be {rule}, got {value!r}")


def finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def positive(key: str, value) -> None:
    check(finite(value) and value > 0, key, "a finite number > 0", value)


def nonneg(key: str, value) -> None:
    check(finite(value) and value >= 0, key, "a finite number >= 0", value)


@dataclass(frozen=True)
class NullSpaceSettings:
    """The secondary "elbow up" objective in the null space of J (``method.null_space``; a
    robot config's ``null_space`` replaces link and target)."""

    link: str | None = "lbr_iiwa_link_3"  # null: no null-space objective
    target: list[float] = field(default_factory=lambda: [0.2, 0.0, 0.45])  # [m]
    stiffness: float = 1.0           # [1/s²]
    damping: float = 1.0             # [1/s]

    def __post_init__(self):
        check(len(self.target) == 3, "method.null_space.target", "3 numbers [m]", self.target)
        nonneg("method.null_space.stiffness", self.stiffness)
        nonneg("method.null_space.damping", self.damping)


@dataclass(frozen=True)
class PumaSettings:
    """method=puma: the pulled PUMA policy (:func:`tamedpuma.methods._tamed.pulled_puma`)."""

    task: str | None = None        # whose model to use (conf: ${task.name})
    checkpoint: str | None = None  # a puma.pt; null: the best model at hand (puma/store.py)
    model: str = "auto"            # with checkpoint null: auto | real (error if none) | shipped
    pinv_damping: float = 0.01        # λ₀ of J⁺ = Jᵀ(JJᵀ + λ²I)⁻¹
    pinv_damping_max: float = 0.0     # λ_max of the singularity-robust inverse (0: constant λ₀)
    manipulability_threshold: float = 0.02  # w₀: λ grows below this manipulability
    goal_velocity: str = "feedforward"  # feedforward: the primitive sees ṗ − v_g | ignore
    null_space: NullSpaceSettings | None = field(default_factory=NullSpaceSettings)

    def __post_init__(self):
        check(self.model in MODEL_CHOICES, "method.model", " | ".join(MODEL_CHOICES), self.model)
        nonneg("method.pinv_damping", self.pinv_damping)
        nonneg("method.pinv_damping_max", self.pinv_damping_max)
        positive("method.manipulability_threshold", self.manipulability_threshold)
        check(self.goal_velocity in ("feedforward", "ignore"), "method.goal_velocity",
              "feedforward or ignore", self.goal_velocity)


def tamed_fabric() -> FabricGains:
    """FPM's avoidance fabric: the Fabrics method's gains
    (:class:`~tamedpuma.fabrics.gains.FabricGains`) with the joint-limit energy ×30 (0.05 →
    1.5): PUMA's forcing metric w = 100 outweighs the Fabrics goal metric (0.3-2) that gain is
    tuned against, and joints run into their limits. The obstacle energy stays 0.1: at ×30 the
    obstacle barriers hold the hand off the goal where an obstacle stands near it (CPM keeps
    the Fabrics gains: there the barriers' energy also enters the regulator's metric,
    docs/method.md)."""
    gains = FabricGains()
    return replace(gains, joint_limit=replace(gains.joint_limit, energy_gain=1.5))


def all_control_rate_filters() -> ControlRate:
    """FPM's and CPM's safety at the control rate: every filter of :class:`ControlRate` on."""
    return ControlRate(barrier_step=True, speed_limit=True, semi_implicit=True)


def fpm_forcing() -> Forcing:
    """How FPM's forcing meets the fabric: through its metric, directional, a stall pull of
    1.5 m/s² and the configuration pull at every arming of it."""
    return Forcing(mode="metric", directional=True, stall_pull=1.5, configuration_pull=True)


@dataclass(frozen=True)
class FpmSettings(PumaSettings):
    """method=fpm: PUMA's settings, the avoidance fabric and how they meet
    (:mod:`tamedpuma.methods.fpm`). The defaults are ``method=fpm``'s; ``conf/method/
    fpm_literal.yaml`` switches each addition off (paper eq. 9 as written)."""

    fabric: FabricGains = field(default_factory=tamed_fabric)  # the joint-limit energy ×30
    control_rate: ControlRate = field(default_factory=all_control_rate_filters)  # safety at the
    #                                   control rate: every filter on (all off: eq. 9 as written)
    forcing: Forcing = field(default_factory=fpm_forcing)  # how PUMA's forcing meets the fabric
    #                                   (Forcing(), additive and nothing added: eq. 9 as written)
    limit_margin: float = 0.01        # [rad] the fabric's joint limits sit this far inside

