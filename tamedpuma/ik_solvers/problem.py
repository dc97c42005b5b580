"""The collision-aware IK problem, its result, and the shared maths every backend is checked by.

Problem (all in the robot base = world frame; q [rad], positions [m])::

    min_q   w_p ‖p(q) − p*‖² + w_R (1 − cos θ(R(q), R*)) + w_q ‖q − q_ref‖²
    s.t.    q_lower ≤ q ≤ q_upper                        (joint limits ∩ trust region)
            d_ij(q) = ‖c_i(q) − o_j‖ − r_i − r_j ≥ d_min  (every body sphere i, obstacle j)

with p(q), R(q) the end-effector position and rotation, θ the angle of ``R*ᵀ R`` (so
``1 − cos θ = (3 − tr(R*ᵀ R))/2``), c_i(q) the body-sphere centres. The objective's gradient is
exact: ``∇ = 2 w_p J_vᵀ (p − p*) − (w_R/2) J_ωᵀ g + 2 w_q (q − q_ref)`` with g from
``B = R R*ᵀ`` (see :func:`objective`), and the constraint Jacobian rows are
``∂d_ij/∂q = n_ijᵀ J_i`` with ``n_ij = (c_i − o_j)/‖c_i − o_j‖``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tamedpuma.robot.kinematics import Kinematics
from tamedpuma.types import frozen_array


def _frozen(value, shape, name) -> np.ndarray:
    """``value`` reshaped to ``shape`` (-1: any length) as a read-only finite float array of the
    problem's own (:func:`~tamedpuma.types.frozen_array` copies it: the caller may change its
    array later)."""
    arr = np.reshape(np.asarray(value, dtype=float), shape)
    return frozen_array(arr, tuple(None if n == -1 else n for n in shape), f"IKProblem.{name}")


@dataclass(frozen=True)
class SolverOptions:
    """The backends' own settings (each read by one backend; see its module docstring).

    scale: s [m], both backends' objective is scaled by 1/s² (same minimiser; the solvers'
    tolerances then resolve sub-millimetre steps); ftol: SLSQP's absolute tolerance on the
    scaled objective; drake_margin [m]: added to d_min in the bound passed to Drake (SNOPT's
    feasibility tolerance cannot then leave a pair below d_min); drake_influence [m]: Drake's
    influence distance beyond that bound (pairs further apart are not evaluated)."""

    scale: float = 0.01
    ftol: float = 1e-6
    drake_margin: float = 1e-4
    drake_influence: float = 0.05


@dataclass(frozen=True, eq=False)
class IKProblem:
    """One collision-aware IK solve (see the module docstring for the equations).

    kinematics: the robot; q_start: (dof,) initial guess, also the configuration returned on failure
    if it is safe [rad]; q_ref: (dof,) regularisation reference [rad] (default q_start);
    target_position: (3,) p* [m]; target_rotation: (3, 3) R* or None (no orientation term);
    obstacle_centers (n, 3) [m], obstacle_radii (n,) [m]; d_min: clearance bound [m];
    q_lower, q_upper: (dof,) bounds [rad] (default the robot's joint limits);
    position_weight w_p [1/m²], orientation_weight w_R [-], regularization_weight w_q [1/rad²];
    tolerance: allowed constraint violation of a successful result [m or rad];
    max_iterations: solver iteration limit; options: the backends' own settings.
    """

    kinematics: Kinematics
    q_start: np.ndarray
    target_position: np.ndarray
    obstacle_centers: np.ndarray
    obstacle_radii: np.ndarray
    d_min: float = 0.01
    target_rotation: np.ndarray | None = None
    q_ref: np.ndarray | None = None
    q_lower: np.ndarray | None = None
    q_upper: np.ndarray | None = None
    position_weight: float = 1.0
    orientation_weight: float = 0.0
    regularization_weight: float = 1e-4
    tolerance: float = 1e-5
    max_iterations: int = 100
    options: SolverOptions = field(default_factory=SolverOptions)

    def __post_init__(self):
        spec = self.kinematics.spec
        n = spec.dof
        setattr_ = object.__setattr__
        setattr_(self, "q_start", _frozen(self.q_start, (n,), "q_start"))
        setattr_(self, "q_ref", self.q_start if self.q_ref is None
                 else _frozen(self.q_ref, (n,), "q_ref"))
        setattr_(self, "target_position", _frozen(self.target_position, (3,), "target_position"))
        if self.target_rotation is not None:
            setattr_(self, "target_rotation",
                     _frozen(self.target_rotation, (3, 3), "target_rotation"))
        setattr_(self, "obstacle_centers",
                 _frozen(self.obstacle_centers, (-1, 3), "obstacle_centers"))
        setattr_(self, "obstacle_radii", _frozen(self.obstacle_radii, (-1,), "obstacle_radii"))
        if len(self.obstacle_radii) != len(self.obstacle_centers):
            raise ValueError("IKProblem: one radius per obstacle centre")
        lo = spec.q_min if self.q_lower is None else np.maximum(self.q_lower, spec.q_min)
        hi = spec.q_max if self.q_upper is None else np.minimum(self.q_upper, spec.q_max)
        setattr_(self, "q_lower", _frozen(lo, (n,), "q_lower"))
        setattr_(self, "q_upper", _frozen(hi, (n,), "q_upper"))
        if np.any(self.q_lower > self.q_upper):
            raise ValueError("IKProblem: q_lower above q_upper")
        if not (self.d_min >= 0 and self.tolerance > 0 and self.max_iterations >= 1):
            raise ValueError("IKProblem: need d_min >= 0, tolerance > 0, max_iterations >= 1")

    @property
    def n_obstacles(self) -> int:
        return len(self.obstacle_radii)


@dataclass(frozen=True)
class IKResult:
    """q: (dof,) the answer [rad]: the solver's solution on success; on failure the safest known
    configuration (the solver's iterate if it satisfies every constraint, else q_start if it does,
    else the one of the two with the smaller violation);
    success: the solver converged AND the returned q satisfies every constraint within tolerance;
    message: the solver's status text (and why the check failed, if it did);
    iterations: solver iterations (or function evaluations where the solver reports no count);
    max_violation: largest violation of the bounds and distance constraints at q [m or rad];
    min_distance: min_ij d_ij(q) [m] (inf without obstacles); backend: which solver ran;
    solve_time_ms: wall time of the backend call [ms]; ee_position: (3,) the end-effector
    position at q [m] (from the placement pass of :func:`~tamedpuma.ik_solvers.solve_ik`'s
    check; None from a backend alone)."""

    q: np.ndarray
    success: bool
    message: str
    iterations: int
    max_violation: float
    min_distance: float
    backend: str
    solve_time_ms: float = 0.0
    ee_position: np.ndarray | None = None

    @property
    def status(self) -> str:
        return "success" if self.success else "failed"


def distances(problem: IKProblem, q: np.ndarray, with_jacobian: bool = False):
    """``d_ij(q) − d_min`` for every (sphere i, obstacle j), flattened (k·n,) [m];
    with_jacobian: also the (k·n, dof) Jacobian ``n_ijᵀ J_i``."""
    kin = problem.kinematics
    if not with_jacobian:  # the centres alone: the placement pass (the same numbers)
        return _gaps(problem, kin.sphere_centers(q), kin.sphere_radii)[0].ravel()
    zeros = np.zeros(kin.spec.dof)
    state = kin.evaluate(q, zeros)
    return _pair_distances(problem, state, with_jacobian)


def _gaps(problem: IKProblem, centers: np.ndarray, radii: np.ndarray):
    """``‖c_i − o_j‖ − r_i − r_j − d_min`` (k, n) [m] of sphere centres c (k, 3), radii r (k,)."""
    diff = centers[:, None, :] - problem.obstacle_centers[None, :, :]  # (k, n, 3)
    norm = np.linalg.norm(diff, axis=-1)
    return norm - radii[:, None] - problem.obstacle_radii[None, :] - problem.d_min, diff, norm


def _pair_distances(problem: IKProblem, state, with_jacobian: bool):
    gap, diff, norm = _gaps(problem, state.sphere_centers, state.sphere_radii)
    if not with_jacobian:
        return gap.ravel()
    unit = diff / np.maximum(norm, 1e-12)[..., None]
    jac = np.einsum("knc,kcq->knq", unit, state.sphere_jacobians)
    return gap.ravel(), jac.reshape(-1, state.sphere_jacobians.shape[-1])


def objective(problem: IKProblem, state, q: np.ndarray) -> tuple[float, np.ndarray]:
    """Objective value and exact gradient at q (module docstring), from a kinematic state at q.

    Orientation: ``c_R = (w_R/2)(3 − tr(R*ᵀ R))``; for a joint twist ω_k (column k of J_ω),
    ``∂ tr(R*ᵀ R)/∂q_k = ω_kᵀ g`` with ``B = R R*ᵀ``, ``g = (B₂₃ − B₃₂, B₃₁ − B₁₃, B₁₂ − B₂₁)``.
    """
    jac = state.ee_jacobian
    err = state.ee_position - problem.target_position
    dq = q - problem.q_ref
    value = problem.position_weight * err @ err + problem.regularization_weight * dq @ dq
    grad = (2.0 * problem.position_weight * jac[:3].T @ err
            + 2.0 * problem.regularization_weight * dq)
    if problem.target_rotation is not None and problem.orientation_weight > 0:
        b = state.ee_rotation @ problem.target_rotation.T
        value += 0.5 * problem.orientation_weight * (3.0 - np.trace(b))
        g = np.array([b[1, 2] - b[2, 1], b[2, 0] - b[0, 2], b[0, 1] - b[1, 0]])
        grad -= 0.5 * problem.orientation_weight * jac[3:].T @ g
    return float(value), grad


def violation(problem: IKProblem, q: np.ndarray,
              centers: np.ndarray | None = None) -> tuple[float, float]:
    """(max violation of bounds and distance constraints [m or rad], min_ij d_ij [m]) at q;
    centers: the body-sphere centres (k, 3) [m] at q where a placement pass already gave them
    (:func:`placement`: the same numbers), else computed here."""
    q = np.asarray(q, float)
    bound = max(0.0, float((problem.q_lower - q).max()), float((q - problem.q_upper).max()))
    if problem.n_obstacles == 0:
        return bound, float("inf")
    if centers is None:
        gap = distances(problem, q)
    else:
        gap = _gaps(problem, centers, problem.kinematics.sphere_radii)[0].ravel()
    return max(bound, float((-gap).max(initial=0.0))), float(gap.min() + problem.d_min)


def placement(kinematics: Kinematics, q: np.ndarray):
    """(end-effector position (3,) [m], rotation (3, 3), body-sphere centres (k, 3) [m]) at q
    from one placement pass: the numbers of ``ee_frame`` and ``sphere_centers`` (each frame is
    placed from the joints alone, whichever frames a pass places)."""
    rotations, origins = kinematics.placements(q, (kinematics.ee_id, *kinematics.sphere_ids))
    return origins[0], rotations[0], origins[1:]


def robot_key(kinematics: Kinematics) -> tuple:
    """A hashable key of everything a backend may cache about the robot (URDF, joints, links,
    spheres), so caches never outlive or confuse robot models."""
    spec = kinematics.spec
    return (spec.urdf_path, spec.joint_names, spec.link_names, spec.ee_link, spec.spheres)


def reach_bounds(kinematics: Kinematics) -> np.ndarray:
    """(k, dof) upper bounds L_ik on ‖∂c_i/∂q_k‖ [m/rad], valid at every configuration.

    For a serial chain, joint k moves sphere i only if k is an ancestor of the sphere's link, and
    then ``‖∂c_i/∂q_k‖ ≤ ‖c_i − a_k‖ ≤ Σ`` of the (rigid) segment lengths between joint origins
    from a_k to c_i (triangle inequality), so ``‖c_i(q) − c_i(q')‖ ≤ Σ_k L_ik |q_k − q'_k|``.
    """
    model = kinematics.model
    data = model.createData()
    import pinocchio as pin  # kinematics already depends on it

    pin.framesForwardKinematics(model, data, np.zeros(model.nq))
    out = np.zeros((len(kinematics.sphere_ids), model.nv))
    for i, fid in enumerate(kinematics.sphere_ids):
        joint = model.frames[fid].parentJoint
        point = data.oMf[fid].translation
        chain = []
        while joint > 0:
            chain.append(joint)
            joint = model.parents[joint]
        # chain: the sphere's parent joint first, then its ancestors
        length = 0.0
        prev = point
        for j in chain:
            origin = data.oMi[j].translation
            length += float(np.linalg.norm(prev - origin))
            prev = origin
            out[i, model.joints[j].idx_v] = length
    return out
