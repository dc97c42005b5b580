"""Spec algebra: pullback (with the +J̇q̇ curvature term), sum, acceleration by a solve."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.fabrics import FabricError, Spec, pull_rows, pullback, solve_acceleration

RNG = np.random.default_rng(1234)


def _polar(q, qd):
    """x = (r cos θ, r sin θ): J and J̇q̇ (the acceleration of x at q̈ = 0)."""
    r, th = q
    rd, thd = qd
    c, s = np.cos(th), np.sin(th)
    J = np.array([[c, -r * s], [s, r * c]])
    jdqd = np.array([-2 * rd * thd * s - r * thd**2 * c, 2 * rd * thd * c - r * thd**2 * s])
    return J, jdqd


@pytest.mark.parametrize("seed", range(5))
def test_free_particle_pulled_to_polar_coordinates(seed):
    rng = np.random.default_rng(seed)
    q = np.array([rng.uniform(0.2, 3.0), rng.uniform(-np.pi, np.pi)])
    qd = rng.normal(size=2)
    J, jdqd = _polar(q, qd)
    mass = rng.uniform(0.1, 5.0)
    free = Spec(mass * np.eye(2), np.zeros(2))  # ẍ = 0
    qdd = pullback(free, J, jdqd).acceleration()
    r, (rd, thd) = q[0], qd
    np.testing.assert_allclose(qdd, [r * thd**2, -2 * rd * thd / r], rtol=1e-10, atol=1e-12)


def test_pulled_metrics_are_symmetric_positive_semidefinite():
    for _ in range(50):
        d, n = RNG.integers(1, 6), RNG.integers(1, 9)
        rank = RNG.integers(0, d + 1)
        A = RNG.normal(size=(d, rank))
        spec = Spec(A @ A.T, RNG.normal(size=d))
        pulled = pullback(spec, RNG.normal(size=(d, n)) * 10 ** RNG.uniform(-3, 3),
                          RNG.normal(size=d))
        np.testing.assert_array_equal(pulled.M, pulled.M.T)
        scale = max(1.0, np.abs(pulled.M).max())
        assert np.linalg.eigvalsh(pulled.M).min() >= -1e-12 * scale


def _phi2(x, xd):
    """y = (x0², x0 x1, sin x1): value, J and J̇ẋ (= Σ_jk ∂²y/∂x_j∂x_k ẋ_j ẋ_k)."""
    y = np.array([x[0] ** 2, x[0] * x[1], np.sin(x[1])])
    J = np.array([[2 * x[0], 0.0], [x[1], x[0]], [0.0, np.cos(x[1])]])
    jdxd = np.array([2 * xd[0] ** 2, 2 * xd[0] * xd[1], -np.sin(x[1]) * xd[1] ** 2])
    return y, J, jdxd


def _composite(q):
    r, th = q
    return _phi2(np.array([r * np.cos(th), r * np.sin(th)]), np.zeros(2))[0]


@pytest.mark.parametrize("seed", range(5))
def test_pullback_through_a_composition_equals_two_pullbacks(seed):
    rng = np.random.default_rng(seed)
    q = np.array([rng.uniform(0.3, 2.0), rng.uniform(-3, 3)])
    qd = rng.normal(size=2)
    J1, j1 = _polar(q, qd)
    x = np.array([q[0] * np.cos(q[1]), q[0] * np.sin(q[1])])
    xd = J1 @ qd
    _, J2, j2 = _phi2(x, xd)
    A = rng.normal(size=(3, 3))
    spec = Spec(A @ A.T + 0.1 * np.eye(3), rng.normal(size=3))
    # The composite's J̇q̇ from finite differences of y(q + t q̇) (q̈ = 0), not from the chain rule.
    h = 1e-4
    yddot = (_composite(q + h * qd) - 2 * _composite(q) + _composite(q - h * qd)) / h**2
    direct = pullback(spec, J2 @ J1, yddot)
    twice = pullback(pullback(spec, J2, j2), J1, j1)
    np.testing.assert_allclose(twice.M, direct.M, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(twice.f, direct.f, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(twice.f, pullback(spec, J2 @ J1, J2 @ j1 + j2).f, rtol=1e-12,
                               atol=1e-12)


def test_sum_and_pull_rows_agree_with_individual_pullbacks():
    n, P = 7, 6
    A = RNG.normal(size=(P, n))
    m = RNG.uniform(0, 3, size=P)
    f = RNG.normal(size=P)
    jd = RNG.normal(size=P)
    total = Spec(np.zeros((n, n)), np.zeros(n))
    for p in range(P):
        total = total + Spec(np.array([[m[p]]]), f[p:p + 1]).pull(A[p:p + 1], jd[p:p + 1])
    M, F = pull_rows(m, f + m * jd, A)
    np.testing.assert_allclose(M, total.M, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(F, total.f, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError):
        total + Spec(np.eye(2), np.zeros(2))


def test_acceleration_is_a_solve_and_never_a_silent_zero():
    A = RNG.normal(size=(7, 7))
    M = A @ A.T + 0.2 * np.eye(7)
    f = RNG.normal(size=7)
    qdd = Spec(M, f).acceleration()
    np.testing.assert_allclose(M @ qdd, -f, atol=1e-10)
    batch = solve_acceleration(np.stack((M, 2 * M)), np.stack((f, f)))
    np.testing.assert_allclose(batch[1], qdd / 2, atol=1e-12)
    with pytest.raises(FabricError):
        solve_acceleration(np.zeros((3, 3)), np.ones(3))
    with pytest.raises(FabricError):
        solve_acceleration(np.eye(3), np.array([1.0, np.nan, 0.0]))
    # huge but finite accelerations are returned as they are (the reference zeroed them)
    big = solve_acceleration(np.eye(2), np.array([1e9, 0.0]))
    assert big[0] == -1e9


def test_the_fabrics_package_imports_numpy_only():
    import ast
    import sys
    from pathlib import Path

    import tamedpuma.fabrics as pkg

    base = {"numpy", "tamedpuma"} | set(sys.stdlib_module_names)
    for path in Path(pkg.__file__).parent.glob("*.py"):
        # compiled.py: the optional numba kernels (imported only if installed)
        allowed = base | ({"numba"} if path.name == "compiled.py" else set())
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module]
            for name in names:
                assert name.split(".")[0] in allowed, f"{path.name} imports {name}"
                if name.startswith("tamedpuma."):
                    allowed_own = ("tamedpuma.errors", "tamedpuma.robot.rotations")
                    assert name in allowed_own or name.startswith("tamedpuma.fabrics")


def test_linear_solve_is_numpys_solve_bit_for_bit_and_refuses_a_singular_matrix():
    """``linear_solve`` (the gesv gufunc without np.linalg.solve's wrapper) returns exactly
    np.linalg.solve's numbers for vector and matrix right-hand sides, and a singular or
    non-float system still goes to np.linalg.solve (LinAlgError)."""
    import warnings

    from tamedpuma.fabrics.spec import linear_solve

    rng = np.random.default_rng(0)
    for n in (2, 6, 7):
        X = rng.normal(size=(n, n))
        A = X @ X.T + 0.1 * np.eye(n)
        for b in (rng.normal(size=n), rng.normal(size=(n, 3))):
            np.testing.assert_array_equal(linear_solve(A, b), np.linalg.solve(A, b))
    np.testing.assert_array_equal(linear_solve(np.eye(2, dtype=int), np.ones(2)), np.ones(2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with pytest.raises(np.linalg.LinAlgError):
            linear_solve(np.zeros((3, 3)), np.ones(3))
