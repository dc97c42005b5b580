"""Geometric fabrics engine (numpy only): specs, energies, leaves, speed control, assembly.

See method.md section 2. Obstacles are arrays whose count is run-time data; no build step.

Modules: :mod:`~tamedpuma.fabrics.spec` (``Spec(M, f)``, sum, pullback with +J̇q̇, solve),
:mod:`~tamedpuma.fabrics.energy` (barrier and attractor energies, Euler-Lagrange terms,
energization), :mod:`~tamedpuma.fabrics.leaves` (vectorised task maps: sphere × obstacle pairs,
joint limits, ground, goal errors), :mod:`~tamedpuma.fabrics.speed` (speed control),
:mod:`~tamedpuma.fabrics.gains` (every gain), :mod:`~tamedpuma.fabrics.fabric` (assembly).

Reuse by the TamedPUMA methods (FPM, CPM), per control step::

    fabric = Fabric(FabricGains.from_mapping(cfg.get("fabric")), spec.q_min, spec.q_max)
    state = kinematics.evaluate(q, qd)
    av = fabric.avoidance(state, q, qd, obs_centers, obs_radii, obs_velocities)
    # av.M (dof×dof SPD metric = pulled energy metric), av.f (geometry force), av.f_energy,
    # av.energy (H of the fabric energy L_e), av.min_clearance, av.n_clamped, ...
    qdd_h = av.acceleration()                      # q̈_h = −M⁻¹ f (linear solve)
    # FPM (eq. 9): energize the avoidance geometry w.r.t. L_e, add the pulled PUMA forcing f_C
    qdd = energize(qd, av.M, av.f_energy, qdd_h)[0] + f_C
    # CPM (eq. 10): energize h + f_C, then γ = −(q̇q̇ᵀ/(q̇ᵀMq̇ + ε)) ∂ψ/∂q − β q̇ with M = av.M
    qdd = energize(qd, av.M, av.f_energy, qdd_h + f_C)[0] + gamma

``energize(qd, M_L, f_L, a)`` returns ``(a − α q̇, α)`` with ``α = q̇ᵀ(M_L a + f_L)/(q̇ᵀM_Lq̇ + ε)``,
which keeps ``H_L`` constant; pass any other energy's (M_L, f_L) to energize w.r.t. it, e.g. the
execution energy ``‖q̇‖²`` is ``(2I, 0)`` (:func:`~tamedpuma.fabrics.energy.execution_alpha`).
"""

from tamedpuma.fabrics.energy import energization_coefficient, energize, execution_alpha
from tamedpuma.fabrics.fabric import (
    AvoidanceFabric,
    Fabric,
    FabricBuffers,
    FabricDiagnostics,
    Forcing,
    quaternion_to_rotation,
)
from tamedpuma.fabrics.gains import BarrierGains, FabricGains
from tamedpuma.fabrics.spec import FabricError, Spec, pull_rows, pullback, solve_acceleration

__all__ = [
    "AvoidanceFabric", "BarrierGains", "Fabric", "FabricBuffers", "FabricDiagnostics",
    "FabricError", "FabricGains", "Forcing", "Spec", "energization_coefficient", "energize",
    "execution_alpha", "pull_rows", "pullback", "quaternion_to_rotation", "solve_acceleration",
]
