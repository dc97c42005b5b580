"""Vanilla geometric Fabrics (method.md sections 2 and 4): the paper's ``Fabrics`` baseline.

Avoidance leaves (body spheres × obstacles, joint limits, optional ground) + goal attractor
(position and orientation) + speed control, as a :class:`~tamedpuma.types.Controller`.
Select it with ``method=fabrics``; its gains are the ``fabric:`` block of the composed method config
(``conf/fabric/default.yaml``; missing keys take :class:`~tamedpuma.fabrics.FabricGains` defaults).

Every step logs to ``Command.scalars``: ``energy_fabric`` (H of the avoidance fabric's energy),
``energy_execution`` (‖q̇‖² [rad²/s²]), ``potential`` (goal ψ), ``alpha_geometry`` (α_G),
``alpha_0``, ``alpha_psi``, ``alpha_ex`` (energization coefficients [1/s]), ``eta``, ``beta``
(damping [1/s]), ``min_clearance_m`` [m] (body spheres vs obstacles; absent without obstacles),
``ground_clearance`` [m] (only with the ground leaf), ``n_clamped`` (obstacle/ground barrier
distances clamped at the margin: penetration), ``n_limit_clamped`` (joint-limit distances clamped:
a state on or past a limit), ``goal_distance`` [m] and ``orientation_error`` [m].
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import Fabric, FabricBuffers, FabricGains, quaternion_to_rotation
from tamedpuma.types import Command, Observation, Scenario

_KEYS = {"name", "fabric", "defaults"}  # defaults: Hydra's list, when loaded without Hydra


@dataclass
class FabricsEpisode:
    """What the step writes (the controller's episode state, made afresh by ``reset``): the
    fabric's work buffers (:class:`~tamedpuma.fabrics.FabricBuffers`), the warnings given (once
    each per episode) and the goal's rotation matrix for the goal quaternion it was made from
    (``goal_key``: its bytes; None: none yet)."""

    buffers: FabricBuffers
    warned: set[str] = field(default_factory=set)
    goal_key: bytes | None = None
    goal_rotation: np.ndarray = field(default_factory=lambda: np.eye(3))


class FabricsController:
    """The vanilla Fabrics method on one robot (see the module docstring).

    gains: :class:`FabricGains`; kinematics: a :class:`~tamedpuma.robot.kinematics.Kinematics` whose
    ``spec`` supplies the joint limits; its body spheres are the avoidance spheres.
    ``episode``: the episode state (:class:`FabricsEpisode`), made by :meth:`reset`.
    """

    def __init__(self, gains: FabricGains, kinematics):
        self.gains = gains
        self.kinematics = kinematics
        spec = kinematics.spec
        self.fabric = Fabric(gains, spec.q_min, spec.q_max)
        self.episode = FabricsEpisode(self.fabric.buffers())

    def reset(self, scenario: Scenario) -> None:
        """Start an episode: forget warnings and the cached goal; warn if q0 is on/past a limit."""
        self.episode = FabricsEpisode(self.fabric.buffers())
        self.fabric.prepare_at_start(self.kinematics, scenario, self.episode.buffers,
                                     with_goal=True)
        spec = self.kinematics.spec
        q0 = np.asarray(scenario.q0, dtype=float)
        margin = self.gains.barrier_margin
        if np.any(q0 < spec.q_min + margin) or np.any(q0 > spec.q_max - margin):
            self._warn("limit", f"start q0 {q0.tolist()} is within {margin} rad of or past a "
                                "joint limit: its barrier is clamped at the margin")

    def _warn(self, key: str, message: str) -> None:
        if key not in self.episode.warned:
            self.episode.warned.add(key)
            warnings.warn(f"fabrics: {message}", RuntimeWarning, stacklevel=3)

    def _rotation(self, quaternion: np.ndarray) -> np.ndarray:
        key, ep = np.asarray(quaternion, dtype=float).tobytes(), self.episode
        if key != ep.goal_key:
            ep.goal_rotation = quaternion_to_rotation(quaternion)
            ep.goal_key = key
        return ep.goal_rotation

    def step(self, obs: Observation) -> Command:
        """One control step: q̈ [rad/s²] from the observation (simulator truth)."""
        state = self.kinematics.evaluate(obs.q, obs.qd)
        qdd, diag = self.fabric.evaluate(
            state, obs.q, obs.qd, obs.obstacle_centers, obs.obstacle_radii,
            obs.obstacle_velocities, obs.goal_position, self._rotation(obs.goal_quaternion),
            self.episode.buffers)
        if diag.n_limit_clamped:
            self._warn("limit", f"step {obs.step}: {diag.n_limit_clamped} joint-limit distances "
                                "below the margin were clamped")
        if diag.n_clamped:
            self._warn("penetration", f"step {obs.step}: {diag.n_clamped} body sphere barrier "
                                      "distances below the margin (penetration) were clamped")
        scalars = diag.as_scalars()
        scalars["min_clearance_m"] = scalars.pop("min_clearance")  # the name every method logs
        for key in ("min_clearance_m", "ground_clearance"):
            if not math.isfinite(scalars[key]):
                del scalars[key]
        return Command(qdd=qdd, scalars=scalars)


def gains_from_config(cfg: Mapping | None) -> FabricGains:
    """:class:`FabricGains` from a method config (``name`` and a ``fabric:`` block of gains)."""
    cfg = dict(cfg or {})
    unknown = sorted(set(cfg) - _KEYS)
    if unknown:
        raise ConfigError(f"unknown keys {unknown} in method fabrics; known: {sorted(_KEYS)}")
    if cfg.get("name") not in (None, "fabrics"):
        raise ConfigError(f"method config is for {cfg['name']!r}, not 'fabrics'")
    return FabricGains.from_mapping(cfg.get("fabric"))


@dataclass(frozen=True)
class FabricsSettings:
    """method=fabrics: the fabric's gains (``conf/fabric/default.yaml``)."""

    fabric: FabricGains = field(default_factory=FabricGains)


#: the settings ``make`` takes
SETTINGS = FabricsSettings


def make(settings: FabricsSettings, kinematics) -> FabricsController:
    """The method registry's constructor."""
    return FabricsController(settings.fabric, kinematics)
