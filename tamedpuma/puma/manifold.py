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
    """One exponential-map step ``q ← exp(ω Δt) ⊗ q`` (ω [rad/s] world frame, Δt [s])."""
    out = quat_mul(quat_exp(omega * dt), q)
    return out / out.norm(dim=-1, keepdim=True)


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
