"""TamedPUMA, Compatible Potential Method (paper eq. 10 and appendix; Ratliff et al. 2023,
Theorem III.5):

    q̈ = energize_{L_e}[h + f_θ^C] + γ,
    γ = −(q̇ q̇ᵀ / (q̇ᵀ M q̇ + ε)) ∂ψ/∂q − β q̇,                                     [rad/s²]

with the compatible potential ψ(x) = k_ψ ‖ρ_θ(x_g, 0) − ρ_θ(x, 0)‖² at the *current* state and
∂ψ/∂q = (∂ψ/∂x) J. The scale k_ψ > 0 (:data:`POTENTIAL_SCALE`) keeps ψ compatible; with β it sets
the speed along the path: energization removes f_θ^C's component along q̇, so the speed comes from
ψ alone (steady speed ≈ k_ψ |∂ψ/∂q · u| / (β uᵀMu) along the direction u), while f_θ^C's normal
component steers. PUMA's path is reproduced when that speed is close to PUMA's own.
Energization conserves H_{L_e}; γ makes the total energy H = H_{L_e} + ψ decrease as
dH/dt = −β q̇ᵀ M q̇ (static obstacles), so the system converges to the zero set of f_θ^C for
β > 0.

``damping: matched`` uses the state-dependent damping β(q, q̇) = max(β, r − α) ≥ β > 0, with
r = −q̇ᵀ∂ψ/(q̇ᵀMq̇ + ε) the regulator's coefficient and α the energization coefficient: then
q̈ = h + f_θ^C exactly whenever that motion loses energy at least at the rate β q̇ᵀMq̇, and the
arm brakes along q̇ otherwise. dH/dt = −β(q, q̇) q̇ᵀMq̇ ≤ −β q̇ᵀMq̇ keeps the convergence
argument; the speed along the path is then PUMA's own wherever the potential is strong enough
(k_ψ large), so CPM follows PUMA's paths. ``damping: constant`` is the paper's literal β.

``energy`` and ``forcing`` as FPM's (:mod:`tamedpuma.methods.fpm`). With ``energy: execution``
the metric of energization and of γ is M = I: it is bounded and strictly positive definite
everywhere and does not degenerate as q̇ → 0, which is exactly the assumption on M_{L_e} under
which eq. 10 converges (paper, section 4.2; the barrier metric 0.2/x does not meet it). Then
dH/dt = −β ‖q̇‖² with H = ½‖q̇‖² + ψ (static obstacles).
With ``forcing.mode: metric`` f_θ^C is PUMA pulled through the avoidance fabric's metric
(:class:`~tamedpuma.methods._tamed.Forcing`), so near an obstacle PUMA's push into it is
suppressed and the regulator's energy goes into sliding along it. f_θ^C keeps its zero set; ψ
stays compatible with it wherever ``P = wJA⁻¹Jᵀ ≈ I`` (free space: −∂ψᵀf_θ^C = −∂ψ_xᵀ P ẍ_d);
near an obstacle P bends f_θ^C away from PUMA's direction and compatibility is no longer
guaranteed there, where the barrier already keeps ψ from decreasing along PUMA's path.
With ``forcing.mode: task_metric`` (CPM's default; FPM keeps ``metric``)
h = −(M + JᵀwJ)⁻¹f: PUMA's task metric is one more leaf of the fabric (ẍ = 0, metric w), so
the geometry no longer drives the hand against PUMA near barriers
(:func:`~tamedpuma.methods._tamed.geometry_with_task_metric`); the sum is still a fabric,
energized the same way, so dH/dt = −β‖q̇‖² holds unchanged.

``forcing.stall_pull`` (default 1.5 m/s², as FPM's; :mod:`tamedpuma.methods._stall`): a goal
attractor added to PUMA's position rows while the hand has stopped approaching the goal. It is
part of f_θ^C, whose power along q̇ energization takes away, so dH/dt = −β q̇ᵀMq̇ holds with it as
without it: the pull steers CPM out of the direction it was pressing into a barrier.
``forcing.configuration_pull`` (:mod:`tamedpuma.methods._configuration_pull`): the joint-space
attractor that replaces PUMA's rows after such a stall (CPM's default ``always``: at every
arming farther than 0.15 m from the goal; ``limits``: only with a joint at a limit) is part of
f_θ^C too. Were the regulator to watch ψ meanwhile, the pull would only steer CPM where ψ's
energy lets it (the way out climbs ψ: CPM crawls); so the regulator watches the attractor's own
potential φ(q) = g ρ_ℓ(‖q − q_g‖) while it acts (−∂φ is its pull: compatible), so
dH/dt ≤ −β q̇ᵀq̇ holds with H = ½‖q̇‖² + φ then and with ψ elsewhere; the argument holds on
every interval on one potential and, after the last engagement, ψ's (scalar
``potential_attractor``: 1 while φ is used).

ε [(rad/s)²] (the fabric's ``energization_eps``, as FPM's energization; conf/method/cpm.yaml
sets 1e-3, cpm_literal the fabric's 1e-6): the regulariser of the energization and regulator
denominators ``q̇ᵀMq̇ + ε``. Below the speed √ε both fade out and the law becomes
``h + f_θ^C − β q̇``, PUMA's own start from rest. It must exceed the square of the joint
controller's velocity noise: in PyBullet the velocity motors sag under gravity by ~1e-3 rad/s,
and with ε no larger than that squared (1e-6) the sag sets the direction of q̇ at rest:
energization removes f_θ^C's push along it, and where ψ *rises* along the sag the regulator
brakes it, so the arm at rest never starts. Above √ε the law is eq. 10 exactly (docs/method.md,
"CPM's regulator and damping").

Discretisation (``control_rate.semi_implicit``, default): over one control period Δt the law is
q̈ = a + c q̇ with a = h + f_θ^C and c = r − α − β ≤ 0 (the regulator, energization and damping
all act along q̇); the velocity-proportional part is taken implicitly,
q̇⁺ = (q̇ + Δt a)/(1 − Δt c), a first-order step like the explicit one, which instead flips q̇
whenever |c| Δt > 1 and amplifies it beyond 2 (α ~ ‖a‖/‖q̇‖ is large at low speed; matched β
reaches 100 /s): the arm chatters and moves by numerical noise rather than by the law.

``tank`` κ (energy tank, :class:`EnergyTank`; 0: off): a passive system may only go where its energy
lets it, so CPM stops at every local minimum of ψ on the free space, e.g. in front of an obstacle
that is only passed by first moving away from the goal, where FPM, from the same state, goes round.
The tank holds κ k_ψ ψ(q₀) at the start; wherever CPM's regulator would brake FPM's law
``energize[h] + f_θ^C`` the tank pays the energy that law needs, and CPM's law takes over where the
tank is empty; a share σ (:data:`TANK_REFILL`) of the energy CPM dissipates beyond β q̇ᵀq̇ refills
it. W = H + T still falls at least at β q̇ᵀq̇ and T is bounded, so the convergence argument above is
unchanged; only the basin CPM ends in changes.

``variant: original`` reproduces the authors' public code instead, for comparison: no
energization, β = 0, and the regulator scaled by 0.05: ``q̈ = h + f_θ^C − 0.05 (q̇q̇ᵀ/(q̇ᵀMq̇)) ∂ψ``
(ψ squared, at the current state, with the correct quaternion Jacobian: the authors' code
departs from these by defects this project does not reproduce).
Scalars: ``psi`` (ψ), ``psi_rate`` (∂ψ/∂q · q̇ [1/s]), ``dissipation`` (β q̇ᵀMq̇, the predicted
−dH/dt), ``energy_fabric`` (H_{L_e}), ``energy_total`` (H + ψ, H the energized energy:
H_{L_e}, or ½‖q̇‖² with ``energy: execution``), ``alpha``, ``beta``, ``min_clearance_m`` [m],
``n_clamped``, ``n_limit_clamped``, ``task_acc_norm``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._settings import FpmSettings, check, fpm_forcing, nonneg, tamed_fabric
from tamedpuma.methods._tamed import (
    ControlRate,
    Forcing,
    PumaController,
    TamedController,
    TamedEpisode,
    alpha_floor,
    bounded_alpha,
    braking_split,
    energization_alpha,
    energy_times_velocity,
    fabric_scalars,
    puma_and_fabric,
)
from tamedpuma.types import Command, Observation

VARIANTS = ("paper", "original")
DAMPINGS = ("constant", "matched")
#: k_ψ [1]: the regulator watches k_ψ ψ (still a compatible potential); with β it sets the speed
#: along the path, about k_ψ|∂ψ/∂q·u|/(β uᵀMu)
POTENTIAL_SCALE = 0.3
#: σ [1]: the share of CPM's surplus dissipation that refills the energy tank
TANK_REFILL = 0.5
#: [m] the tank pays only while a body sphere is this close to an obstacle
TANK_CLEARANCE_M = 0.03
#: the creep criterion of CPM's stall pull (:mod:`tamedpuma.methods._stall`): the hand's
#: distance counts as progress only when it falls by this fraction of what is left
CREEP_FRACTION = 0.05


@dataclass(frozen=True)
class EnergyTank:
    """An energy tank for CPM (``method.tank``): where CPM's regulator
    would brake FPM's law ``q̈ = energize[h] + f_θ^C``, the tank pays the energy that law
    injects, as long as it holds any (passivity with an energy tank: Ferraguti, Secchi &
    Fantuzzi 2013; Kronander & Billard 2016, for dynamical systems that are not conservative).

    The law is ``q̈ = a + c q̇`` with a = h + f_θ^C [rad/s²]; its total energy
    H = ½‖q̇‖² + k_ψ ψ changes at ``P(c) = q̇ᵀa + c‖q̇‖² + k_ψ ∂ψ·q̇`` (static obstacles).
    CPM's coefficient c_cpm (matched damping) is the largest c ≤ 0 with P(c) ≤ −β‖q̇‖²; FPM's
    law is c_fpm = −α_h (the geometry's energization). Where c_fpm > c_cpm (CPM would brake FPM's
    motion: going round an obstacle that climbs ψ), the deficit ``D = P(c_fpm) + β‖q̇‖² > 0`` is
    drawn from the tank level T ≥ 0 (``Ṫ = −D``), and c moves towards c_cpm only as far as T
    cannot pay. Where CPM's own law dissipates more than β‖q̇‖² a fraction σ (``refill``) of
    the surplus refills T, up to ``capacity``.

    What holds. W = H + T obeys ``Ẇ ≤ −β‖q̇‖²`` in every case (the tank only moves energy
    the law has or had), and T is bounded by its capacity, so ``∫β‖q̇‖²dt ≤ H(0) + T(0)``: the
    convergence argument of CPM (Theorem III.5 of Ratliff et al. 2023: q̇ → 0, the limit set in
    the zero set of f_θ^C) is unchanged; what changes is which basin CPM ends in: the arm may
    climb ψ by at most T (to go round an obstacle), where plain CPM stalls at a local minimum of
    ψ on the free space. capacity [rad²/s², H's units] (0: off); refill σ ∈ [0, 1]."""

    capacity: float = 0.0
    refill: float = TANK_REFILL
    clearance: float = TANK_CLEARANCE_M

    def engaged(self, obstacle_clearance: float) -> bool:
        """Whether the tank may pay: a body sphere within ``clearance`` [m] of an obstacle."""
        return obstacle_clearance < self.clearance

    def __post_init__(self):
        if not (self.capacity >= 0.0 and 0.0 <= self.refill <= 1.0):
            raise ConfigError(f"method.tank must be ≥ 0 and the tank's refill in [0, 1], got "
                              f"{self.capacity}, {self.refill}")

    def coefficient(self, c_cpm: float, c_fpm: float, power_zero: float, qn: float,
                    beta: float, level: float, size: float, dt: float) -> tuple[float, float]:
        """(c, next tank level): c_cpm, c_fpm [1/s]; power_zero P(0) = q̇ᵀa + k_ψ∂ψ·q̇
        [rad²/s³]; qn ‖q̇‖² [rad²/s²]; beta β [1/s]; level T and size (the most it holds)
        [rad²/s²]; dt Δt [s]."""
        if qn <= 0.0:
            return c_cpm, level
        if c_fpm <= c_cpm:  # CPM's own law: refill with a share of its surplus dissipation
            surplus = -(power_zero + c_cpm * qn) - beta * qn
            if surplus > 0.0 and self.refill > 0.0:
                level = min(size, level + self.refill * surplus * dt)
            return c_cpm, level
        deficit = power_zero + c_fpm * qn + beta * qn  # [rad²/s³]
        if deficit <= 0.0:
            return c_fpm, level
        if level >= deficit * dt:
            return c_fpm, level - deficit * dt
        return max(c_cpm, c_fpm - (deficit - level / dt) / qn), 0.0


@dataclass
class CpmEpisode(TamedEpisode):
    """CPM's episode state: FPM's and the energy tank's level and size [J], NaN until the first
    step fills it (``EnergyTank``)."""

    tank_level: float = float("nan")
    tank_size: float = float("nan")


class CpmController(TamedController):
    """CPM on one robot. beta: damping β [1/s] (> 0 for the convergence guarantee);
    eps: ε [(rad/s)²] of the energization and regulator denominators (None: the fabric's
    ``energization_eps``, as FPM's energization uses it); variant: 'paper' or 'original';
    potential_scale: k_ψ on ψ; damping: ``constant`` β or ``matched`` β(q, q̇) = max(β, r − α);
    regulator_scale: factor on the ψ term (1 in the paper, 0.05 in the original code). While
    the configuration pull acts the regulator watches that pull's own potential (the potential
    compatible with what then forces the arm)."""

    creep_fraction = CREEP_FRACTION
    Episode = CpmEpisode

    def __init__(self, puma: PumaController, fabric: Fabric, *, beta: float, variant: str,
                 damping: str, eps: float | None = None,
                 potential_scale: float = POTENTIAL_SCALE,
                 regulator_scale: float = 1.0, alpha_min: float | None = None,
                 rate: ControlRate | None = None, energy: str = "fabric",
                 forcing: Forcing | None = None, tank: EnergyTank | None = None):
        if variant not in VARIANTS:
            raise ConfigError(f"cpm variant must be one of {VARIANTS}, got {variant!r}")
        if variant == "paper" and not beta > 0:
            raise ConfigError(f"cpm needs beta > 0 for convergence, got {beta}")
        super().__init__(puma, fabric, alpha_min, rate, energy, forcing)
        self.beta, self.variant = beta, variant
        self.eps = fabric.gains.energization_eps if eps is None else eps
        self.regulator_scale = regulator_scale
        if not potential_scale > 0:
            raise ConfigError(f"cpm potential_scale must be positive, got {potential_scale}")
        self.potential_scale = potential_scale
        if damping not in DAMPINGS:
            raise ConfigError(f"cpm damping must be one of {DAMPINGS}, got {damping!r}")
        self.matched = damping == "matched"
        self.tank = tank or EnergyTank()
        if self.tank.capacity > 0.0 and energy != "execution":
            raise ConfigError("cpm's energy tank needs method.energy: execution")

    def step(self, obs: Observation) -> Command:
        qd = obs.qd
        state, av, h, qdd_c, xdd, ground = self.forced(obs)
        configuration = self.episode.configuration
        attractor = configuration is not None and configuration.engaged
        if attractor:  # the configuration pull's own potential while it acts (see the module)
            psi, dpsi = configuration.potential(obs.q)
        else:
            psi, dpsi = self.puma.episode.task.potential(state, obs.goal_position,
                                                         obs.goal_quaternion)
            psi, dpsi = self.potential_scale * psi, self.potential_scale * dpsi
        h_plus_f = h + qdd_c
        Mqd = energy_times_velocity(av, self.energy, qd)  # M of the energy energized and of γ
        denom = qd @ Mqd + self.eps
        r_coef = -self.regulator_scale * (qd @ dpsi) / denom  # regulator: r q̇
        beta = self.beta
        if self.variant == "paper":
            alpha_raw = energization_alpha(av, self.energy, qd, h_plus_f, self.eps)
            alpha = bounded_alpha(alpha_raw, self.alpha_min)
            if self.matched:  # β = max(β_min, r − α): exactly h + f_C whenever that dissipates
                beta = max(self.beta, r_coef - alpha)
            c = float(r_coef - alpha - beta)  # q̈ = (h + f_θ^C) + c q̇
            if self.tank.capacity > 0.0:  # FPM's law where the tank pays for it
                c, alpha_raw, alpha = self._tank_law(obs, av, h, h_plus_f, Mqd, psi, dpsi,
                                                     c, alpha_raw, alpha)
            a, c_split = braking_split(h_plus_f, c, qd, alpha_raw, alpha)
            if self.rate.semi_implicit and c_split < 0.0:
                # the velocity-proportional part (with the geometry's own braking along q̇
                # where the α bound acts: braking_split) taken implicitly over the control
                # period: q̇⁺ = (q̇ + Δt a) / (1 − Δt c): it damps, never reverses q̇
                qd_next = self.rate.velocity_step(qd, a, c_split, self.dt, av,
                                                  self.fabric.gains)
                qdd = (qd_next - qd) / self.dt
            else:
                qdd = h_plus_f + c * qd
        else:  # the authors' code: no energization, no damping
            alpha = 0.0
            qdd = h_plus_f + r_coef * qd
        qd_next, extra = self.rate.next_velocity(qd + self.dt * qdd, av, self.dt, self.qd_max,
                                                 ground, qd)
        qdd = (qd_next - qd) / self.dt
        return Command(qdd=qdd, scalars={
            **extra, **fabric_scalars(av), **self.stall_scalars(), "psi": psi,
            "psi_rate": float(dpsi @ qd),
            "dissipation": float(beta * (qd @ Mqd)),
            "energy_total": float(self._kinetic(av, qd, Mqd) + psi), "alpha": float(alpha),
            "beta": float(beta), "tank": float(self.episode.tank_level),
            "potential_attractor": float(attractor),
            "task_acc_norm": float(np.linalg.norm(xdd))})

    def _tank_law(self, obs: Observation, av, h, h_plus_f, Mqd, psi: float, dpsi,
                  c: float, alpha_raw: float, alpha: float) -> tuple[float, float, float]:
        """The energy tank's choice of ``(c, α_raw, α)`` in q̈ = (h + f) + c q̇ (``EnergyTank``).

        Where the tank is engaged (near an obstacle or a joint limit) and holds energy, FPM's
        coefficient c = −α_h replaces CPM's; the tank is drained by what that adds to dH/dt.
        """
        qd, ep = obs.qd, self.episode
        if not ep.tank_level >= 0.0:  # first step: κ times the potential energy
            ep.tank_level = ep.tank_size = self.tank.capacity * psi
        engaged = self.tank.engaged(av.min_clearance)
        # FPM's α only where the tank may pay (elsewhere c_fpm = −∞: CPM's law, the tank refills)
        alpha_raw_h = alpha_h = np.nan
        c_fpm = -np.inf
        if engaged:
            alpha_raw_h = energization_alpha(av, self.energy, qd, h, self.eps)
            alpha_h = bounded_alpha(alpha_raw_h, self.alpha_min)
            c_fpm = -alpha_h
        c_tank, ep.tank_level = self.tank.coefficient(
            c, c_fpm, float(qd @ h_plus_f + dpsi @ qd), float(qd @ Mqd), self.beta,
            ep.tank_level, ep.tank_size, self.dt)
        if c_tank != c:
            return c_tank, alpha_raw_h, alpha_h
        return c, alpha_raw, alpha

    def _kinetic(self, av, qd: np.ndarray, Mqd: np.ndarray) -> float:
        """The energy the law conserves up to β: H_{L_e} (``energy: fabric``) or ½‖q̇‖²."""
        return float(av.energy) if self.energy == "fabric" else 0.5 * float(qd @ Mqd)


def cpm_fabric() -> FabricGains:
    """CPM's avoidance fabric: FPM's (:func:`~tamedpuma.methods._settings.tamed_fabric`) with
    the energization and regulator denominators' ε = 1e-3 [(rad/s)²], above the joint
    controller's velocity noise squared (the module docstring says why)."""
    return replace(tamed_fabric(), energization_eps=1.0e-3)


def cpm_forcing() -> Forcing:
    """How CPM's forcing meets the fabric: FPM's (:func:`~tamedpuma.methods._settings.
    fpm_forcing`) with PUMA's task metric one more leaf of the geometry (``task_metric``) and
    the configuration pull at every arming (``always``)."""
    return replace(fpm_forcing(), mode="task_metric", configuration_pull="always")


@dataclass(frozen=True)
class CpmSettings(FpmSettings):
    """method=cpm: FPM's settings (:class:`~tamedpuma.methods._settings.FpmSettings`) and the
    regulator's. The defaults are ``method=cpm``'s: FPM's, except those redeclared here;
    ``conf/method/cpm_literal.yaml`` (paper eq. 10 as written) and ``cpm_original.yaml`` (the
    authors' code) override them."""

    orientation: str = "feedback"     # feedback (CPM's, as PUMA's): the primitive sees the
    #                                   hand's orientation | reference: a reference it moves
    #                                   itself, which the hand tracks (PumaSettings.orientation)
    orientation_clearance: float = 0.0  # [m] the reference's (orientation: reference only)
    fabric: FabricGains = field(default_factory=cpm_fabric)  # the barriers' energies ×30 (as
    #                                   FPM's) and ε = 1e-3 (cpm_fabric)
    forcing: Forcing = field(default_factory=cpm_forcing)  # how PUMA's forcing meets the fabric:
    #                                   FPM's with task_metric and configuration_pull always
    variant: str = "paper"           # paper | original (the authors' code)
    beta: float = 0.5                # β [1/s] > 0: the damping (its floor with damping: matched)
    damping: str = "matched"         # matched: β(q, q̇) = max(β, r − α) | constant: the paper's β
    tank: float = 1.0                # energy tank capacity [1] × k_ψ ψ(q₀) (0: off;
    #                                  EnergyTank): FPM's law where it pays

    def __post_init__(self):
        super().__post_init__()
        check(self.variant in VARIANTS, "method.variant", " or ".join(VARIANTS), self.variant)
        check(self.damping in DAMPINGS, "method.damping", " or ".join(DAMPINGS), self.damping)
        nonneg("method.beta", self.beta)
        nonneg("method.tank", self.tank)


#: the settings ``make`` takes; their defaults are what ``method=cpm`` composes (tested)
SETTINGS = CpmSettings


def make(settings: CpmSettings, kinematics) -> CpmController:
    puma, fabric = puma_and_fabric(settings, kinematics)
    rate = settings.control_rate
    if settings.variant == "original":  # the authors' code: no energization, β = 0, ψ × 0.05
        return CpmController(puma, fabric, beta=0.0, variant="original", regulator_scale=0.05,
                             potential_scale=1.0, damping="constant", rate=rate)
    return CpmController(puma, fabric, beta=float(settings.beta), variant=settings.variant,
                         damping=settings.damping, alpha_min=alpha_floor(settings), rate=rate,
                         energy=settings.energy, forcing=settings.forcing,
                         tank=EnergyTank(float(settings.tank)))
