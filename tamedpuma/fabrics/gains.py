"""Every gain of the geometric fabric, as one frozen dataclass with the reference defaults.

The defaults are those of the reference implementation (the ``fabrics`` package's standard planner,
method.md section 2), except where a field's comment says otherwise. Units: task distances of
obstacles are dimensionless (``x = ‖c_i − o_j‖ / (r_i + r_j) − 1``), of joint limits radians, of the
ground plane metres; velocities per second.

Barrier leaves share one family of energies and geometries (method.md section 2 table):

- energy (Finsler/Lagrangian) ``L = k_L s_L(ẋ) ẋ² / x^{p_L}``, metric ``M_L = 2 k_L s_L / x^{p_L}``;
- geometry ``ẍ = −h`` with ``h = −k_h s_h(ẋ) ẋ² / x^{p_h}`` (pushes x up, HD2 in ẋ);

where ``s(ẋ) = 1`` if ẋ < 0 (approaching) else 0 when the leaf is *directional*, and 1 otherwise.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

from tamedpuma.errors import ConfigError


@dataclass(frozen=True)
class BarrierGains:
    """One barrier leaf: ``L = energy_gain s_L ẋ²/x^energy_exponent``,
    ``h = −geometry_gain s_h ẋ²/x^geometry_exponent``.

    energy_gain k_L [1] and geometry_gain k_h [1] (x and ẋ carry the leaf's units);
    *_directional: whether s(ẋ) (active only while approaching, ẋ < 0) multiplies the term.
    """

    energy_gain: float
    energy_exponent: float
    energy_directional: bool
    geometry_gain: float
    geometry_exponent: float
    geometry_directional: bool

    def __post_init__(self):
        for name in ("energy_gain", "geometry_gain"):
            if not getattr(self, name) > 0:
                raise ConfigError(
                    f"fabric barrier {name} must be positive, got {getattr(self, name)}")
        for name in ("energy_exponent", "geometry_exponent"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"fabric barrier {name} must be >= 0, got {getattr(self, name)}")


# Reference: collision_geometry "-0.5 / x**5 * s(xdot) * xdot**2",
# collision_finsler "0.1/x * xdot**2".
OBSTACLE_DEFAULT = BarrierGains(0.1, 1.0, False, 0.5, 5.0, True)
# Reference: limit_geometry "-0.1 / x * xdot**2", limit_finsler "0.1/x * s(xdot) * xdot**2".
LIMIT_REFERENCE = BarrierGains(0.1, 1.0, True, 0.1, 1.0, False)
# Ours (tuned; conf/method/fabrics.yaml says why): energy 0.1 s ẋ²/x², geometry ẋ²/x².
# With L ∝ ẋ²/x^p a bounded energy gives |ẋ| ≤ c x^{p/2}, so the limit is reached in finite time
# unless p ≥ 2; and ẍ = k ẋ²/x brakes a joint only as |ẋ| ∝ x^k, useless for k = 0.1: the
# reference values let joints creep past their limits (up to 0.2 rad) on Table 1.
LIMIT_DEFAULT = BarrierGains(0.05, 2.0, True, 0.05, 2.0, False)
# Reference: geometry_plane_constraint and finsler_plane_constraint: as the obstacle leaf.
GROUND_DEFAULT = BarrierGains(0.1, 1.0, False, 0.5, 5.0, True)


@dataclass(frozen=True)
class FabricGains:
    """All gains of the fabric, the goal attractor and speed control (method.md section 2).

    base_metric: m_b of the base energy ``L_b = ½ m_b ‖q̇‖²`` (metric m_b I) [1].
    obstacle, joint_limit, ground: barrier leaves (see :class:`BarrierGains`).
    obstacle_activation: x_a of the obstacle leaf [1, in its x = ‖c_i − o_j‖/(r_i + r_j) − 1]:
      the energy is ``L = k s w(x) ẋ²/x^p`` with the taper ``w = (1 − (x/x_a)²)²`` below x_a, 0
      beyond (energy.activation_taper), so a pair's metric, forces and energy vanish beyond x_a
      (C¹) and tend to the reference's as x → 0; ``inf``: no taper, the reference leaf.
    ground_enabled: add the ground-plane leaf ``x = c_{i,z} − r_i − ground_height`` [m] per
      body sphere.
    barrier_margin: a barrier distance below this is clamped up to it and counted [task units].
    goal_*: position attractor. Potential gradient
      ``∇ψ = goal_potential_gain · goal_weight · tanh(goal_sharpness ‖e‖) e/‖e‖`` [m/s²], metric
      ``goal_metric_scale ((goal_metric_max − goal_metric_min) exp(−(goal_metric_width ‖e‖)²)
      + goal_metric_min) I``.
    orientation_weight: weight of the orientation attractor (same potential and metric) on the
      vectors ``R_ee a_k`` towards ``R_g a_k``, ``a_k = orientation_offset e_k`` [m] for the axes
      in orientation_axes (0 = x, 1 = y, 2 = z); 0 disables it.
    speed control: ``η = ½(tanh(−eta_gain ‖q̇‖² − eta_shift) + 1)``,
      ``β = ½ damping_close (tanh(−damping_slope (‖e‖ − damping_radius)) + 1) + damping_far
      + max(0, α_G − α_ex)`` [1/s].
    energization_eps: ε added to ``q̇ᵀMq̇`` in energization denominators [(rad/s)²].
    kernel: how the pair rows, the barrier kernel, the goal rows and the solve are computed:
      ``numpy`` (the reference), ``numba`` (:mod:`tamedpuma.fabrics.compiled`: the same maths
      compiled, equal to rounding; needs the ``fast`` extra) or ``auto`` (numba where it is
      installed, else numpy).
    """

    base_metric: float = 0.2
    obstacle: BarrierGains = OBSTACLE_DEFAULT
    joint_limit: BarrierGains = LIMIT_DEFAULT
    ground: BarrierGains = GROUND_DEFAULT
    obstacle_activation: float = 2.0  # ours; the reference: inf (conf/fabric/default.yaml says why)
    ground_enabled: bool = False
    ground_height: float = 0.0
    barrier_margin: float = 1.0e-3
    goal_weight: float = 1.0
    goal_potential_gain: float = 5.0
    goal_sharpness: float = 10.0
    goal_metric_scale: float = 2.0
    goal_metric_max: float = 2.0
    goal_metric_min: float = 0.3
    goal_metric_width: float = 0.75
    orientation_weight: float = 1.0
    orientation_offset: float = 0.045
    orientation_axes: tuple[int, ...] = (0, 1)
    eta_gain: float = 0.45
    eta_shift: float = 0.5
    damping_close: float = 6.5
    damping_slope: float = 0.5
    damping_radius: float = 0.02
    damping_far: float = 0.01
    energization_eps: float = 1.0e-6
    kernel: str = "auto"

    def __post_init__(self):
        positive = ("base_metric", "barrier_margin", "goal_potential_gain", "goal_sharpness",
                    "goal_metric_scale", "goal_metric_min", "orientation_offset",
                    "energization_eps")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"fabric.{name} must be positive, got {getattr(self, name)}")
        nonneg = ("goal_weight", "orientation_weight", "goal_metric_width", "eta_gain",
                  "damping_close", "damping_slope", "damping_far")
        for name in nonneg:
            if not getattr(self, name) >= 0:
                raise ConfigError(f"fabric.{name} must be >= 0, got {getattr(self, name)}")
        if not self.obstacle_activation > 0:
            raise ConfigError("fabric.obstacle_activation must be positive (inf: no taper), got "
                              f"{self.obstacle_activation}")
        if self.goal_metric_max < self.goal_metric_min:
            raise ConfigError("fabric.goal_metric_max must be >= fabric.goal_metric_min")
        axes = tuple(int(a) for a in self.orientation_axes)
        if len(set(axes)) != len(axes) or any(a not in (0, 1, 2) for a in axes):
            raise ConfigError(f"fabric.orientation_axes must be distinct of 0, 1, 2; got {axes}")
        object.__setattr__(self, "orientation_axes", axes)
        from tamedpuma.fabrics import compiled

        try:
            compiled.check(self.kernel)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None

    @classmethod
    def from_mapping(cls, cfg: Mapping | None) -> FabricGains:
        """Gains from a plain mapping (e.g. the ``fabric:`` block of a method config).

        Missing keys keep their defaults; unknown keys raise :class:`ConfigError`.
        ``obstacle``, ``joint_limit`` and ``ground`` are sub-mappings of :class:`BarrierGains`.
        """
        cfg = dict(cfg or {})
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(cfg) - names)
        if unknown:
            raise ConfigError(f"unknown fabric gains {unknown}; known: {sorted(names)}")
        kwargs = {}
        defaults = cls()
        for key, value in cfg.items():
            if key in ("obstacle", "joint_limit", "ground"):
                base = dataclasses.asdict(getattr(defaults, key))
                sub = dict(value or {})
                bad = sorted(set(sub) - set(base))
                if bad:
                    raise ConfigError(f"unknown fabric.{key} gains {bad}; known: {sorted(base)}")
                base.update(sub)
                kwargs[key] = BarrierGains(**{k: (bool(v) if k.endswith("directional")
                                                  else float(v)) for k, v in base.items()})
            elif key == "orientation_axes":
                kwargs[key] = tuple(int(a) for a in value)
            elif key == "ground_enabled":
                kwargs[key] = bool(value)
            elif key == "kernel":
                kwargs[key] = str(value)
            elif key == "obstacle_activation" and value is None:
                kwargs[key] = float("inf")
            else:
                try:
                    kwargs[key] = float(value)
                except (TypeError, ValueError) as exc:
                    raise ConfigError(f"fabric.{key} must be a number, got {value!r}") from exc
        return cls(**kwargs)

    def to_mapping(self) -> dict:
        """Plain-dict form (the inverse of :meth:`from_mapping`)."""
        out = dataclasses.asdict(self)
        out["orientation_axes"] = list(self.orientation_axes)
        if out["obstacle_activation"] == float("inf"):
            out["obstacle_activation"] = None  # plain YAML/JSON; None reads back as inf
        return out
