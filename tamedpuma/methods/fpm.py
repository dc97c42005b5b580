"""TamedPUMA, Forcing Policy Method (paper eq. 9): the energized avoidance fabric forced by the
pulled PUMA policy,

    q̈ = energize_{L}[h](q, q̇) + f_θ^C(q, q̇)                                      [rad/s²]

h = −M⁻¹ f is the summed, pulled-back avoidance geometry (body spheres × obstacles, joint limits);
energization ``h̃ = h − α q̇`` with ``α = q̇ᵀ(M_L h + f_L)/(q̇ᵀ M_L q̇ + ε)`` keeps the energy H_L
constant; f_θ^C is PUMA's task acceleration pulled to the joints.

Energization is eq. 9's, w.r.t. the fabric's own energy L_e with α exact: h̃ has the paths of h
(any Finsler energy; method.md §2) and conserves H_{L_e}, so the paper's statement (PUMA's zero
set, once reached, is kept: Prop. II.17 of Ratliff et al. 2023) holds.

Options (``conf/method/fpm.yaml``; each addition's law, setting and ablation row: docs/method.md,
"The additions the defaults make"), and which of the paper's statements still holds with it:

- ``forcing.mode``: ``additive`` is eq. 9 as written, f_θ^C = J⁺(ẍ_d − J̇q̇) + N q̈_null, blind to
  the obstacles: at low speed h (∝ ‖q̇‖²) vanishes and PUMA pushes the arm straight into a
  barrier, where it hovers until the time limit. ``metric`` pulls PUMA through the avoidance
  fabric's metric (a weighted pseudo-inverse, :class:`~tamedpuma.methods._tamed.Forcing`): near
  an obstacle PUMA's push along the barrier's normal is suppressed and the arm slides along it,
  as a forced fabric does. h is the paper's, and the zero set of f_θ^C is unchanged (q̇ = 0,
  ẍ_d = 0 gives q̈ = 0 up to the damped elbow objective), so the same statement holds.
- ``forcing.directional``: the metric resists PUMA only along the barriers the forcing q̈_C
  itself approaches (:func:`~tamedpuma.methods._tamed.restore_approached`). Decided on PUMA's
  free pull q̈_P alone, the weighted solution can drive a joint into a limit whose row q̈_P
  recedes from, with nothing weighing that joint against PUMA. The forcing is still a weighted
  pseudo-inverse of PUMA's spec through a PSD metric, so its zero set and the statement below
  are unchanged.
- ``forcing.mode: task_metric`` is ``metric`` and computes the geometry with PUMA's task
  metric as one more leaf, ``h = −(M + JᵀwJ)⁻¹f``
  (:func:`~tamedpuma.methods._tamed.geometry_with_task_metric`), instead of ``h = −M⁻¹f``. The
  leaf is ``ẍ = 0`` in PUMA's task space with the constant metric
  w, a Finsler energy with a zero geometry, so the sum is still a fabric and its energized
  form has the same statement. Why: the barriers' metric exceeds the base's wherever a
  barrier is near, and there h = −M⁻¹f carries their curvature terms (m_r J̇q̇ along each
  barrier row) and the joint-limit braking to the hand at full strength, unweighed against
  PUMA's forcing added after it, so near a barrier they can move the hand away from the goal
  faster than PUMA pulls it in. CPM's default; FPM keeps ``metric``, on which the leaf gains
  no more than the neutral change (docs/method.md, "What the ablation has measured so far").
- ``forcing.stall_pull`` (FPM's and CPM's default 1.5 m/s²; :mod:`tamedpuma.methods._stall`):
  once for 2 s neither the hand's distance to the goal (by 5 mm) nor PUMA's potential ψ (by
  10 %) has improved, a goal attractor is added to PUMA's position rows until ψ has fallen 5 %
  below its value at the stall. Where the hand keeps approaching, in distance or in ψ, the
  forcing is PUMA's to the bit, so the statement above holds there;
  while armed the rest set is that of PUMA's forcing plus a convex attractor to the same goal,
  which no longer contains the stall point unless the barriers hold the attractor too.
- ``forcing.configuration_pull`` (:mod:`tamedpuma.methods._configuration_pull`): when the
  stall pull arms, a joint-space attractor to the nearest IK solution of the goal pose (inside the
  limits, clear, reached along a clear straight segment) replaces PUMA's rows until the hand is
  within ``near_release`` (3 cm) of the goal or the attractor stops making progress. The limit box
  is convex, so it has no rest point made by the limits; its own rest point is the goal pose, in
  PUMA's zero set, and elsewhere the forcing is as above, so the statement holds; the path is not
  PUMA's while it acts.
- ``control_rate`` filters only remove energy (:mod:`tamedpuma.fabrics.discrete`);
  ``limit_margin`` moves the joint-limit
  barriers inside the real limits.

Scalars: ``energy_fabric`` (H_{L_e}), ``alpha`` (α [1/s]), ``min_clearance_m`` [m] (body
spheres vs obstacles, 1e3 without obstacles), ``n_clamped``, ``n_limit_clamped``, ``task_acc_norm``.
"""

from __future__ import annotations

from tamedpuma.methods._kernels import STEP
from tamedpuma.methods._settings import FpmSettings
from tamedpuma.methods._tamed import (
    TamedController,
    fabric_scalars,
    puma_and_fabric,
    vector_norm,
)
from tamedpuma.types import Command, Observation


class FpmController(TamedController):
    """FPM on one robot: ``fabric`` (a :class:`Fabric`) for avoidance, ``puma`` for forcing
    (constructor: :class:`~tamedpuma.methods._tamed.TamedController`)."""

    def step(self, obs: Observation) -> Command:
        qd = obs.qd
        state, av, h, qdd_c, xdd, ground = self.forced(obs)
        # energize_{L_e}[h], then the step (−α q̇ implicit along q̇ alone where semi-implicit)
        alpha, qd_next = STEP["fpm_velocity"](av.M, av.f_energy, qd, h, qdd_c,
                                              self.fabric.gains.energization_eps, self.dt,
                                              self.rate.semi_implicit)
        alpha = float(alpha)
        qd_next, extra = self.rate.next_velocity(qd_next, av, self.dt, self.qd_max, ground, qd)
        qdd = (qd_next - qd) / self.dt
        scalars = {**fabric_scalars(av), "alpha": alpha, **extra,
                   **self.stall_scalars(), "task_acc_norm": vector_norm(xdd)}
        # ψ: the stall monitor's sample where it runs, else computed for the log only
        return Command(qdd=qdd, scalars=scalars, logged_later=None if "psi" in scalars
                       else self.puma.psi_later(state, obs))


#: the settings ``make`` takes; their defaults are what ``method=fpm`` composes (tested)
SETTINGS = FpmSettings


def make(settings: FpmSettings, kinematics) -> FpmController:
    return FpmController(*puma_and_fabric(settings, kinematics), settings.control_rate,
                         settings.forcing)
