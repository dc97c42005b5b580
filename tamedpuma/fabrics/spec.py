"""Specs and their algebra (method.md section 2).

A *spec* ``(M, f)_x`` on a task space x is the second-order system ``M ẍ + f = 0``: M [kg-like
metric, any consistent unit] symmetric positive semi-definite, f in the units of ``M ẍ``.

- sum: ``(M₁, f₁) + (M₂, f₂) = (M₁ + M₂, f₁ + f₂)``;
- pullback through ``x = φ(q)`` with ``J = ∂φ/∂q`` and the curvature term ``J̇q̇`` (``ẍ = J q̈ + J̇q̇``):
  ``pull_φ (M, f)_x = (Jᵀ M J, Jᵀ (f + M J̇q̇))_q``, M and f evaluated at ``x = φ(q), ẋ = J q̇``;
- acceleration: ``q̈ = −M⁻¹ f`` by a linear solve (never an explicit inverse).

:func:`pull_rows` is the batched form used by the fabric: many one-dimensional task variables
(rows ``a_p = ∂x_p/∂q``) with scalar metrics ``m_p`` are pulled back together as
``M = Σ_p m_p a_p a_pᵀ = Aᵀ diag(m) A`` and ``f = Aᵀ (f_p + m_p (J̇q̇)_p)``.
numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tamedpuma.errors import TamedPumaError

try:  # numpy's LAPACK gesv gufuncs without the Python wrapper of np.linalg.solve (~3 µs less)
    from numpy.linalg._umath_linalg import solve as _gesv_matrix
    from numpy.linalg._umath_linalg import solve1 as _gesv
except ImportError:  # pragma: no cover - other numpy layouts
    _gesv = _gesv_matrix = None
_sum = np.add.reduce
_F8 = np.dtype(float)


class FabricError(TamedPumaError):
    """A fabric evaluation that cannot produce a finite acceleration (non-finite input)."""


@dataclass(frozen=True)
class Spec:
    """The system ``M ẍ + f = 0``: M (d, d) symmetric PSD metric, f (d,) force."""

    M: np.ndarray
    f: np.ndarray

    def __post_init__(self):
        M = np.asarray(self.M, dtype=float)
        f = np.asarray(self.f, dtype=float)
        if M.ndim != 2 or M.shape[0] != M.shape[1] or f.shape != (M.shape[0],):
            raise ValueError(f"spec needs M (d, d) and f (d,), got {M.shape} and {f.shape}")
        object.__setattr__(self, "M", M)
        object.__setattr__(self, "f", f)

    @property
    def dim(self) -> int:
        return self.f.shape[0]

    def __add__(self, other: Spec) -> Spec:
        """Sum of specs on the same space: ``(M₁ + M₂, f₁ + f₂)``."""
        if not isinstance(other, Spec):
            return NotImplemented
        if other.dim != self.dim:
            raise ValueError(f"cannot add specs of dimension {self.dim} and {other.dim}")
        return Spec(self.M + other.M, self.f + other.f)

    def pull(self, J: np.ndarray, Jdqd: np.ndarray) -> Spec:
        """Pullback through a map with Jacobian J (d, n) and J̇q̇ (d,); see :func:`pullback`."""
        return pullback(self, J, Jdqd)

    def acceleration(self) -> np.ndarray:
        """``ẍ = −M⁻¹ f`` (linear solve); see :func:`solve_acceleration`."""
        return solve_acceleration(self.M, self.f)


def pullback(spec: Spec, J: np.ndarray, Jdqd: np.ndarray) -> Spec:
    """``pull (M, f)_x = (Jᵀ M J, Jᵀ (f + M J̇q̇))_q``.

    J: (d, n) Jacobian ``∂x/∂q``; Jdqd: (d,) ``J̇q̇`` so that ``ẍ = J q̈ + J̇q̇`` [x-units/s²].
    The returned metric is symmetrised (exactly symmetric in floating point).
    """
    J = np.asarray(J, dtype=float)
    Jdqd = np.asarray(Jdqd, dtype=float)
    if J.ndim != 2 or J.shape[0] != spec.dim or Jdqd.shape != (spec.dim,):
        raise ValueError(f"pullback of a {spec.dim}-d spec needs J ({spec.dim}, n) and J̇q̇ "
                         f"({spec.dim},), got {J.shape} and {Jdqd.shape}")
    MJ = spec.M @ J
    M = J.T @ MJ
    return Spec(0.5 * (M + M.T), J.T @ (spec.f + spec.M @ Jdqd))


def pull_rows(m: np.ndarray, b: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pull back P one-dimensional specs at once: ``(Σ_p m_p a_p a_pᵀ, Σ_p a_p b_p)``.

    m: (P,) task metrics m_p ≥ 0; b: (P,) pulled task forces ``b_p = f_p + m_p (J̇q̇)_p``;
    A: (P, n) rows ``a_p = ∂x_p/∂q``. Returns M (n, n) and f (n,).
    """
    return A.T @ (m[:, None] * A), A.T @ b


def linear_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A⁻¹ b`` for one square float array A (n, n) and b (n,) or (n, k): the LAPACK gesv
    gufunc ``np.linalg.solve`` calls, without its Python wrapper (the same result bit for bit,
    ~2 µs less per call at n = 7: the control loop solves a few 7×7 systems per step).
    Anything else (other shapes or dtypes, a singular A, a non-finite result) goes to
    ``np.linalg.solve`` itself, which raises ``LinAlgError`` as before (a singular A also
    warns once from the first attempt)."""
    if (_gesv is not None and A.dtype is _F8 and b.dtype is _F8 and A.ndim == 2
            and b.ndim <= 2 and A.shape[0] == b.shape[0]):
        out = (_gesv if b.ndim == 1 else _gesv_matrix)(A, b)
        if math.isfinite(_sum(out, axis=None)):
            return out
    return np.linalg.solve(A, b)


def solve_acceleration(M: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``ẍ = −M⁻¹ f`` for M (..., d, d) SPD and f (..., d), by a (batched) linear solve.

    Raises :class:`FabricError` if the solve fails or the result is not finite: a fabric never
    returns a silent zero acceleration.
    """
    M = np.asarray(M, dtype=float)
    f = np.asarray(f, dtype=float)
    if _gesv is not None and M.shape[-1] == f.shape[-1]:
        with np.errstate(invalid="ignore"):  # singular → NaN, reported below
            out = _gesv(M, f, signature="dd->d")
        if np.isfinite(out).all():
            np.negative(out, out=out)
            return out
    try:
        out = -np.linalg.solve(M, f[..., None])[..., 0]
    except np.linalg.LinAlgError as exc:
        raise FabricError(f"fabric metric is singular: {exc}") from exc
    if not np.isfinite(out).all():
        raise FabricError("fabric acceleration is not finite")
    return out
