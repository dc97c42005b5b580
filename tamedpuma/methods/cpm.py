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

``forcing`` as FPM's (:mod:`tamedpuma.methods.fpm`).
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
attractor that replaces PUMA's rows after such a stall (at every arming farther than 0.15 m from the
goal) is part of f_θ^C too. Were the regulator to watch ψ meanwhile, the pull would only steer CPM
where ψ's energy lets it (the way out climbs ψ: CPM crawls); so the regulator watches the
attractor's own potential φ(q) = g ρ_ℓ(‖q − q_g‖) while it acts (−∂φ is its pull: compatible), so
dH/dt ≤ −β q̇ᵀq̇ holds with H = ½‖q̇‖² + φ then and with ψ elsewhere; the argument holds on every
interval on one potential and, after the last engagement, ψ's (scalar ``potential_attractor``: 1
while φ is used).

ε [(rad/s)²] (the fabric's ``energization_eps``, 1e-6, as FPM's energization): the regulariser
of the energization and regulator denominators ``q̇ᵀMq̇ + ε``; above √ε the law is eq. 10
exactly. A larger ε = 1e-3 (above the velocity motors' sag under gravity squared) was measured
and does not pay (docs/method.md, "Measured and not kept").

Discretisation (``control_rate.semi_implicit``, default): over one control period Δt the law is
q̈ = a + c q̇ with a = h + f_θ^C and c = r − α − β ≤ 0 (the regulator, energization and damping
all act along q̇); the velocity-proportional part is taken implicitly along q̇
(:func:`~tamedpuma.fabrics.discrete.energized_velocity_step`), a first-order step like the
explicit one, which instead flips q̇ whenever |c| Δt > 1 and amplifies it beyond 2
(α ~ ‖a‖/‖q̇‖ is large at low speed; matched β reaches 100 /s): the arm chatters and moves by
numerical noise rather than by the law. Across q̇ the step is the law's, undivided.

``variant: original`` reproduces the authors' public code instead, for comparison: no
energization, β = 0, and the regulator scaled by 0.05: ``q̈ = h + f_θ^C − 0.05 (q̇q̇ᵀ/(q̇ᵀMq̇)) ∂ψ``
(ψ squared, at the current state, with the correct quaternion Jacobian: the authors' code
departs from these by defects this project does not reproduce).
Scalars: ``psi`` (ψ), ``psi_rate`` (∂ψ/∂q · q̇ [1/s]), ``dissipation`` (β q̇ᵀMq̇, the predicted
−dH/dt), ``energy_fabric`` (H_{L_e}), ``energy_total`` (H_{L_e} + ψ), ``alpha``, ``beta``,
``min_clearance_m`` [m], ``n_clamped``, ``n_limit_clamped``, ``task_acc_norm``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._kernels import STEP
from tamedpuma.methods._settings import FpmSettings, check, fpm_forcing, nonneg
from tamedpuma.methods._tamed import (
    ControlRate,
    Forcing,
    PumaController,
    TamedController,
    fabric_scalars,
    puma_and_fabric,
    vector_norm,
)
from tamedpuma.types import Command, Observation

VARIANTS = ("paper", "original")
DAMPINGS = ("constant", "matched")
#: k_ψ [1]: the regulator watches k_ψ ψ (still a compatible potential); with β it sets the speed
#: along the path, about k_ψ|∂ψ/∂q·u|/(β uᵀMu)
POTENTIAL_SCALE = 0.3
#: the creep criterion of CPM's stall pull (:mod:`tamedpuma.methods._stall`): the hand's
#: distance counts as progress only when it falls by this fraction of what is left
CREEP_FRACTION = 0.05


class CpmController(TamedController):
    """CPM on one robot. beta: damping β [1/s] (> 0 for the convergence guarantee);
    eps: ε [(rad/s)²] of the energization and regulator denominators (None: the fabric's
    ``energization_eps``, as FPM's energization uses it); variant: 'paper' or 'original';
    potential_scale: k_ψ on ψ; damping: ``constant`` β or ``matched`` β(q, q̇) = max(β, r − α);
    regulator_scale: factor on the ψ term (1 in the paper, 0.05 in the original code). While
    the configuration pull acts the regulator watches that pull's own potential (the potential
    compatible with what then forces the arm)."""

    creep_fraction = CREEP_FRACTION

    def __init__(self, puma: PumaController, fabric: Fabric, *, beta: float, variant: str,
                 damping: str, eps: float | None = None,
                 potential_scale: float = POTENTIAL_SCALE,
                 regulator_scale: float = 1.0, rate: ControlRate | None = None,
                 forcing: Forcing | None = None):
        if variant not in VARIANTS:
            raise ConfigError(f"cpm variant must be one of {VARIANTS}, got {variant!r}")
        if variant == "paper" and not beta > 0:
            raise ConfigError(f"cpm needs beta > 0 for convergence, got {beta}")
        super().__init__(puma, fabric, rate, forcing)
        self.beta, self.variant = beta, variant
        self.eps = fabric.gains.energization_eps if eps is None else eps
        self.regulator_scale = regulator_scale
        if not potential_scale > 0:
            raise ConfigError(f"cpm potential_scale must be positive, got {potential_scale}")
        self.potential_scale = potential_scale
        if damping not in DAMPINGS:
            raise ConfigError(f"cpm damping must be one of {DAMPINGS}, got {damping!r}")
        self.matched = damping == "matched"

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
        if self.variant == "paper":
            # energize_{L_e}[h + f_θ^C], the regulator r q̇ and the damping (matched:
            # β = max(β_min, r − α), exactly h + f_C whenever that dissipates): q̈ = (h + f_θ^C)
            # + c q̇, c = r − α − β, the c q̇ part implicit along q̇ where semi-implicit (it
            # damps, never reverses q̇, and leaves the push across q̇ whole)
            alpha, beta, qd_pre, dissipation, psi_rate = STEP["cpm_velocity"](
                av.M, av.f_energy, qd, h, qdd_c, dpsi, self.eps, float(self.regulator_scale),
                float(self.beta), self.matched, self.rate.semi_implicit, self.dt)
        else:
            alpha, beta, qd_pre, dissipation, psi_rate = self.original_law(qd, h, qdd_c, dpsi,
                                                                           av.M)
        qd_next, extra = self.rate.next_velocity(qd_pre, av, self.dt, self.qd_max, ground, qd)
        qdd = (qd_next - qd) / self.dt
        return Command(qdd=qdd, scalars={
            **extra, **fabric_scalars(av), **self.stall_scalars(), "psi": psi,
            "psi_rate": float(psi_rate),
            "dissipation": float(dissipation),
            "energy_total": float(av.energy + psi), "alpha": float(alpha),
            "beta": float(beta),
            "potential_attractor": float(attractor),
            "task_acc_norm": vector_norm(xdd)})

    def original_law(self, qd, h, qdd_c, dpsi, M):
        """The authors' code (no energization, no damping): ``q̈ = h + f_θ^C + r q̇``; returns
        (α = 0, β, q̇ + Δt q̈ [rad/s], β q̇ᵀMq̇, ∂ψ·q̇) as the paper variant's kernel does."""
        Mqd = M @ qd
        r_coef = -self.regulator_scale * (qd @ dpsi) / (qd @ Mqd + self.eps)
        qdd = (h + qdd_c) + r_coef * qd
        return 0.0, self.beta, qd + self.dt * qdd, self.beta * (qd @ Mqd), dpsi @ qd


def cpm_forcing() -> Forcing:
    """How CPM's forcing meets the fabric: FPM's (:func:`~tamedpuma.methods._settings.
    fpm_forcing`) with PUMA's task metric one more leaf of the geometry (``task_metric``)."""
    return replace(fpm_forcing(), mode="task_metric")


@dataclass(frozen=True)
class CpmSettings(FpmSettings):
    """method=cpm: FPM's settings (:class:`~tamedpuma.methods._settings.FpmSettings`) and the
    regulator's. The defaults are ``method=cpm``'s: FPM's, except those redeclared here;
    ``conf/method/cpm_literal.yaml`` (paper eq. 10 as written) and ``cpm_original.yaml`` (the
    authors' code) override them."""

    fabric: FabricGains = field(default_factory=FabricGains)  # the Fabrics method's gains (not
    #                                   FPM's ×30: the fabric's energy is the regulator's metric)
    forcing: Forcing = field(default_factory=cpm_forcing)  # how PUMA's forcing meets the fabric:
    #                                   FPM's with task_metric
    variant: str = "paper"           # paper | original (the authors' code)
    beta: float = 0.5                # β [1/s] > 0: the damping (its floor with damping: matched)
    damping: str = "matched"         # matched: β(q, q̇) = max(β, r − α) | constant: the paper's β

    def __post_init__(self):
        super().__post_init__()
        check(self.variant in VARIANTS, "method.variant", " or ".join(VARIANTS), self.variant)
        check(self.damping in DAMPINGS, "method.damping", " or ".join(DAMPINGS), self.damping)
        nonneg("method.beta", self.beta)


#: the settings ``make`` takes; their defaults are what ``method=cpm`` composes (tested)
SETTINGS = CpmSettings


def make(settings: CpmSettings, kinematics) -> CpmController:
    puma, fabric = puma_and_fabric(settings, kinematics)
    rate = settings.control_rate
    if settings.variant == "original":  # the authors' code: no energization, β = 0, ψ × 0.05
        return CpmController(puma, fabric, beta=0.0, variant="original", regulator_scale=0.05,
                             potential_scale=1.0, damping="constant", rate=rate)
    return CpmController(puma, fabric, beta=float(settings.beta), variant=settings.variant,
                         damping=settings.damping, rate=rate, forcing=settings.forcing)
