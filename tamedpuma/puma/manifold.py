"""Unit quaternions and the sphere S³: products, exponential and logarithm maps, tangent spaces.

Quaternions are stored (x, y, z, w) everywhere. Angular velocities ω [rad/s] are world-frame
(spatial): ``ζ̇ = ½ ω ⊗ ζ``. The tangent space of S³ at ζ is ``T_ζ S³ = {u : u·ζ = 0} = {½ ω ⊗ ζ}``.

Two equivalent steps on S³ are provided and tested against each other:

- the Riemannian exponential of the sphere, ``Exp_ζ(u) = cos‖u‖ ζ + sin‖u‖ u/‖u‖`` for a tangent
  vector u (use :func:`project_tangent` first for an arbitrary 4-vector);
- the Lie-group form ``ζ ← exp(ω Δt) ⊗ ζ`` with ``exp(θ) = (sin(‖θ‖/2) θ/‖θ‖, cos(‖θ‖/2))``.

With ``u = ½ ω ⊗ ζ Δt`` both give the same point. Every map is finite (no NaN, finite gradients)
at zero velocity: ``sin(a)/a`` and ``a/sin(a)`` use their Taylor series for small a.

Functions prefixed ``np_`` act on numpy arrays (the exp and log maps run through the torch ones, so
that data preparation and training share one implementation); the others on torch tensors
(..., 4) / (..., 3). Every other numpy rotation (product, conjugate, angle, matrices) is in
:mod:`tamedpuma.robot.rotations`.
"""

from __future__ import annotations

import math

import numpy as np
import torch

_SMALL = 1e-6  # below this squared half-angle, Taylor series replace sin(a)/a


# ----------------------------------------------------------------------------- torch


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a ⊗ b`` of (..., 4) quaternions (x, y, z, w)."""
    ax, ay, az, aw = a.unbind(-1)
    bx, by, bz, bw = b.unbind(-1)
    return torch.stack((
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ), dim=-1)


def quat_conj(q: torch.Tensor) -> torch.Tensor:
    """Conjugate (= inverse for unit quaternions) ``(-x, -y, -z, w)``."""
    return torch.cat((-q[..., :3], q[..., 3:]), dim=-1)


def _sinc_and_cos(a2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``sin(a)/a`` and ``cos(a)`` from ``a² ≥ 0`` with finite values and gradients at a = 0."""
    small = a2 < _SMALL
    a = torch.sqrt(torch.where(small, torch.ones_like(a2), a2))
    sinc = torch.where(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, torch.sin(a) / a)
    cos = torch.where(small, 1.0 - a2 / 2.0 + a2 * a2 / 24.0, torch.cos(a))
    return sinc, cos


def quat_exp(theta: torch.Tensor) -> torch.Tensor:
    """Rotation vector θ (..., 3) [rad] → unit quaternion ``(sin(‖θ‖/2) θ/‖θ‖, cos(‖θ‖/2))``."""
    half = 0.5 * theta
    sinc, cos = _sinc_and_cos((half * half).sum(-1, keepdim=True))
    return torch.cat((sinc * half, cos), dim=-1)


def quat_log(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternion (..., 4) → rotation vector θ (..., 3) [rad], ‖θ‖ ≤ π (shortest arc)."""
    q = torch.where(q[..., 3:] < 0, -q, q)
    v, w = q[..., :3], q[..., 3:].clamp(-1.0, 1.0)
    s2 = (v * v).sum(-1, keepdim=True)
    small = s2 < _SMALL
    s = torch.sqrt(torch.where(small, torch.ones_like(s2), s2))
    half = torch.atan2(s, w)
    scale = torch.where(small, 1.0 + s2 / 6.0, half / s)  # half / sin(half)
    return 2.0 * scale * v


def quat_angle(q: torch.Tensor) -> torch.Tensor:
    """Rotation angle of a unit quaternion, in [0, π] [rad]."""
    return 2.0 * torch.atan2(q[..., :3].norm(dim=-1), q[..., 3].abs())


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternion (..., 4) (x, y, z, w) → rotation matrix (..., 3, 3); smooth, q ≡ −q."""
    x, y, z, w = q.unbind(-1)
    return torch.stack((
        torch.stack((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)), -1),
        torch.stack((2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)), -1),
        torch.stack((2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)), -1),
    ), -2)


def hemisphere(q: torch.Tensor) -> torch.Tensor:
    """Canonical sign ``w ≥ 0`` (q and −q are the same rotation)."""
    return torch.where(q[..., 3:] < 0, -q, q)


def project_tangent(q: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Orthogonal projection of a 4-vector u onto ``T_q S³``: ``u − (u·q) q``."""
    return u - (u * q).sum(-1, keepdim=True) * q


def sphere_exp(q: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Riemannian exponential of S³: ``cos‖u‖ q + sin‖u‖ u/‖u‖`` for u in ``T_q S³``."""
    sinc, cos = _sinc_and_cos((u * u).sum(-1, keepdim=True))
    out = cos * q + sinc * u
    return out / out.norm(dim=-1, keepdim=True)


def omega_to_qdot(q: torch.Tensor, omega: torch.Tensor) -> torch.Tensor:
    """World-frame angular velocity ω (..., 3) → quaternion derivative ``½ ω ⊗ q`` in T_q S³."""
    w = torch.cat((omega, torch.zeros_like(omega[..., :1])), dim=-1)
    return 0.5 * quat_mul(w, q)


def qdot_to_omega(q: torch.Tensor, qdot: torch.Tensor) -> torch.Tensor:
    """Quaternion derivative → world-frame ω = 2 vec(P_q(q̇) ⊗ q*) (tangent projection first)."""
    return 2.0 * quat_mul(project_tangent(q, qdot), quat_conj(q))[..., :3]


def step_orientation(q: torch.Tensor, omega: torch.Tensor, dt: float) -> torch.Tensor:
    """One exponential-map step ``q ← exp(ω Δt) ⊗ q`` (ω [rad/s] world frame, Δt [s]).

    The same map as ``quat_mul(quat_exp(ω Δt), q)`` normalised, in fewer operations (training
    rolls it out thousands of times per iteration, where the per-operation cost dominates):
    ``sin(a)/a`` as ``torch.sinc``, ``a = sqrt(‖ωΔt/2‖² + 10⁻³⁰)`` (finite gradients at ω = 0;
    the offset changes a only below a ~ 10⁻¹⁵ rad), the product as one matrix product.
    """
    half = omega * (0.5 * dt)
    a = torch.sqrt((half * half).sum(-1, keepdim=True) + _TINY)
    e = torch.cat((torch.sinc(a * (1.0 / math.pi)) * half, torch.cos(a)), dim=-1)
    out = quat_mul_fused(e, q)
    return out / out.norm(dim=-1, keepdim=True)


_TINY = 1e-30
_CONST: dict = {}


def _const(name: str, dtype: torch.dtype) -> torch.Tensor:
    """The constant matrices of the fused products, one copy per dtype (made outside inference
    mode, so that a training after an evaluation in the same process can save them for
    backward)."""
    key = (name, dtype)
    if key not in _CONST:
        with torch.inference_mode(False):
            _CONST[key] = torch.as_tensor(_TABLES[name], dtype=dtype)
    return _CONST[key]


def _tables() -> dict:
    # Hamilton product as a bilinear map: (a ⊗ b)_k = Σ_ij a_i b_j T[i, j, k] (x, y, z, w order)
    t = np.zeros((4, 4, 4))
    e = np.eye(4)
    for i in range(4):
        for j in range(4):
            t[i, j] = quat_mul(torch.as_tensor(e[i]), torch.as_tensor(e[j])).numpy()
    # rotation matrix R(q) = I + Σ q_i q_j M[i, j]: the terms of quat_to_matrix
    m = np.zeros((4, 4, 3, 3))
    x, y, z, w = 0, 1, 2, 3
    for (r, c), terms in {
        (0, 0): ((-2, y, y), (-2, z, z)), (0, 1): ((2, x, y), (-2, z, w)),
        (0, 2): ((2, x, z), (2, y, w)), (1, 0): ((2, x, y), (2, z, w)),
        (1, 1): ((-2, x, x), (-2, z, z)), (1, 2): ((2, y, z), (-2, x, w)),
        (2, 0): ((2, x, z), (-2, y, w)), (2, 1): ((2, y, z), (2, x, w)),
        (2, 2): ((-2, x, x), (-2, y, y)),
    }.items():
        for k, i, j in terms:
            m[i, j, r, c] += k
    return {"qmul": t.reshape(16, 4), "rot": m.reshape(16, 9), "eye": np.eye(3).reshape(9)}


def quat_mul_fused(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a ⊗ b`` as one outer product and one matrix product (= :func:`quat_mul`)."""
    ab = (a.unsqueeze(-1) * b.unsqueeze(-2)).flatten(-2)
    return ab @ _const("qmul", ab.dtype)


def quat_to_matrix_flat(q: torch.Tensor) -> torch.Tensor:
    """``quat_to_matrix(q).flatten(-2)`` (..., 9) as one outer product and one matrix product."""
    qq = (q.unsqueeze(-1) * q.unsqueeze(-2)).flatten(-2)
    return torch.addmm(_const("eye", qq.dtype), qq.reshape(-1, 16),
                       _const("rot", qq.dtype)).reshape(qq.shape[:-1] + (9,))


_TABLES = _tables()


# ----------------------------------------------------------------------------- numpy


def np_quat_exp(theta: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] → unit quaternion (x, y, z, w)."""
    return quat_exp(torch.from_numpy(np.asarray(theta, float))).numpy()


def np_quat_log(q: np.ndarray) -> np.ndarray:
    """Unit quaternion → rotation vector [rad] (shortest arc)."""
    return quat_log(torch.from_numpy(np.asarray(q, float))).numpy()


def np_random_rotations(rng: np.random.Generator, n: int, max_angle: float) -> np.ndarray:
    """n quaternions with a uniformly random axis and angle uniform in [0, max_angle] [rad]."""
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(0.0, max_angle, size=(n, 1))
    return np_quat_exp(axis * angle)
