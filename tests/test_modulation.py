"""Dynamic modulation (Khansari-Zadeh and Billard 2012) around sphere obstacles, as properties."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.methods._modulation import gamma, modulate, modulation, orthonormal_basis, weights

RNG_SEEDS = range(200)


def _scene(rng, n):
    centers = rng.uniform(-1.0, 1.0, (n, 3))
    radii = rng.uniform(0.02, 0.2, n)
    return centers, radii


def _outside_point(rng, center, radius, safety, lo=1.05, hi=4.0):
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    return center + rng.uniform(lo, hi) * (radius + safety) * direction


@pytest.mark.parametrize("power", [0.5, 1.0, 2.0])
def test_single_obstacle_eigenvalues_and_eigenvectors(power):
    rng = np.random.default_rng(1)
    for _ in RNG_SEEDS:
        (center,), (radius,) = _scene(rng, 1)
        safety = rng.uniform(0.0, 0.1)
        x = _outside_point(rng, center, radius, safety)
        mod = modulation(x, center[None], [radius], safety=safety, power=power)
        g = (np.linalg.norm(x - center) / (radius + safety)) ** (2 * power)
        assert mod.gamma[0] == pytest.approx(g, rel=1e-12)
        n = (x - center) / np.linalg.norm(x - center)
        basis = orthonormal_basis(n)
        m = mod.matrix
        np.testing.assert_allclose(m @ n, (1 - 1 / g) * n, atol=1e-12)
        for t in basis[:, 1:].T:
            assert abs(t @ n) < 1e-12
            np.testing.assert_allclose(m @ t, (1 + 1 / g) * t, atol=1e-12)
        # M = E D E^-1 with the documented E and D
        e = basis
        d = np.diag([1 - 1 / g, 1 + 1 / g, 1 + 1 / g])
        np.testing.assert_allclose(m, e @ d @ np.linalg.inv(e), atol=1e-12)
        np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(m)),
                                   np.sort(np.diag(d)), atol=1e-12)


def test_identity_far_from_every_obstacle():
    rng = np.random.default_rng(2)
    for n in (1, 2, 5):
        centers, radii = _scene(rng, n)
        vel = rng.normal(size=(n, 3))
        for scale in (1e2, 1e4, 1e6):
            x = rng.normal(size=3)
            x = scale * x / np.linalg.norm(x)
            mod = modulation(x, centers, radii, vel, safety=0.05)
            # ‖M − I‖ ≤ Σ_j 3 ω_j/Γ_j → 0 as Γ → ∞
            assert np.abs(mod.matrix - np.eye(3)).max() <= 3 * n / mod.gamma.min() + 1e-12
            v = rng.normal(size=3)
            v_mod, _ = modulate(v, x, centers, radii, vel, safety=0.05)
            # v_mod − v = (M − I)(v − ȯ)
            rel = np.abs(v - mod.obstacle_velocity).sum()
            bound = 3 * np.abs(mod.matrix - np.eye(3)).max() * rel
            assert np.abs(v_mod - v).max() <= bound + 1e-15
    empty = modulation(np.zeros(3), np.zeros((0, 3)), np.zeros(0))
    np.testing.assert_array_equal(empty.matrix, np.eye(3))
    assert empty.gamma_min == np.inf


@pytest.mark.parametrize("moving", [False, True])
def test_no_velocity_into_an_obstacle_at_its_boundary(moving):
    """At Γ_j = 1 the velocity relative to obstacle j has no inward normal component, for any
    nominal velocity and any other (non-overlapping) obstacles."""
    rng = np.random.default_rng(3)
    safety = 0.05
    checked = 0
    for _ in RNG_SEEDS:
        n = int(rng.integers(1, 5))
        centers, radii = _scene(rng, n)
        vel = rng.normal(scale=0.3, size=(n, 3)) if moving else np.zeros((n, 3))
        j = int(rng.integers(n))
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        x = centers[j] + (radii[j] + safety) * normal
        others = np.delete(np.arange(n), j)
        if np.any(gamma(x, centers[others], radii[others], safety) <= 1.0):
            continue  # x inside another obstacle's inflated sphere: not a boundary point
        for _ in range(5):
            v = rng.normal(size=3)
            v_mod, mod = modulate(v, x, centers, radii, vel, safety=safety)
            assert mod.gamma[j] == pytest.approx(1.0, abs=1e-12)
            assert mod.weights[j] == pytest.approx(1.0)
            np.testing.assert_allclose(mod.obstacle_velocity, vel[j], atol=1e-12)
            assert normal @ (v_mod - vel[j]) >= -1e-9
            assert normal @ (v_mod - vel[j]) == pytest.approx(0.0, abs=1e-9)
            checked += 1
    assert checked > 300


def test_tangential_flow_is_amplified_at_the_boundary():
    center, radius = np.zeros(3), 0.1
    x = np.array([0.1, 0.0, 0.0])
    v_mod, _ = modulate(np.array([-1.0, 1.0, 0.0]), x, center[None], [radius])
    np.testing.assert_allclose(v_mod, [0.0, 2.0, 0.0], atol=1e-12)


def test_weights():
    np.testing.assert_array_equal(weights(np.array([7.0])), [1.0])
    w = weights(np.array([1.0, 3.0, 10.0]))
    np.testing.assert_allclose(w, [1.0, 0.0, 0.0])
    w = weights(np.array([2.0, 2.0]))
    np.testing.assert_allclose(w, [0.5, 0.5])
    w = weights(np.array([1.0, 1.0, 5.0]))  # two touching boundaries: 0/0 counts as 1/2
    assert np.all(np.isfinite(w)) and w[2] == 0.0
    rng = np.random.default_rng(4)
    for _ in RNG_SEEDS:
        g = 1.0 + rng.exponential(2.0, size=int(rng.integers(2, 6)))
        w = weights(g)
        assert np.all((w >= 0) & (w <= 1))
        assert np.argmax(w) == np.argmin(g)


def test_modulation_is_continuous():
    """Along random segments through a cluster of obstacles (outside the inflated spheres),
    M(x) changes by at most a bounded multiple of the step."""
    rng = np.random.default_rng(5)
    centers = np.array([[0.0, 0.0, 0.0], [0.5, 0.1, 0.0], [0.2, 0.5, 0.2]])
    radii = np.array([0.1, 0.15, 0.1])
    vel = rng.normal(scale=0.2, size=(3, 3))
    safety = 0.05
    h = 1e-3
    for _ in range(10):
        a, b = rng.uniform(-0.6, 1.1, 3), rng.uniform(-0.6, 1.1, 3)
        ts = np.linspace(0.0, 1.0, int(np.linalg.norm(b - a) / h) + 2)
        prev = None
        worst = 0.0
        for t in ts:
            x = a + t * (b - a)
            g = gamma(x, centers, radii, safety)
            if g.min() < 1.02:
                prev = None
                continue
            mod = modulation(x, centers, radii, vel, safety=safety)
            cur = np.concatenate([mod.matrix.ravel(), mod.obstacle_velocity])
            if prev is not None:
                worst = max(worst, np.abs(cur - prev).max())
            prev = cur
        step = np.linalg.norm(b - a) / (len(ts) - 1)
        assert worst < 200 * step  # Lipschitz-like: no jump anywhere


def test_inside_an_obstacle_pushes_out_and_stays_finite():
    center, radius, safety = np.zeros(3), 0.1, 0.05
    for x in (np.array([0.05, 0.0, 0.0]), np.zeros(3)):
        v_mod, mod = modulate(np.array([-1.0, 0.0, 0.0]), x, center[None], [radius],
                              safety=safety)
        assert np.all(np.isfinite(v_mod)) and np.all(np.isfinite(mod.matrix))
    v_mod, _ = modulate(np.array([-1.0, 0.0, 0.0]), np.array([0.1, 0.0, 0.0]), center[None],
                        [radius], safety=safety)
    assert v_mod[0] > 0  # the inward velocity is reversed


def _reference_matrix(x, centers, radii, safety, power, gamma_floor=0.5):
    """M(x) one obstacle at a time, ``M = I M_1 M_2 …`` with
    ``M_j = (1 + ω_j/Γ_j) I − (2 ω_j/Γ_j) n_j n_jᵀ`` (the module docstring, written plainly)."""
    gam = gamma(x, centers, radii, safety, power)
    w = weights(gam)
    diff = x[None, :] - centers
    dist = np.linalg.norm(diff, axis=1, keepdims=True)
    normals = np.where(dist > 1e-12, diff / np.where(dist > 1e-12, dist, 1.0), [0.0, 0.0, 1.0])
    inv = w / np.maximum(gam, gamma_floor)
    matrix = np.eye(3)
    for j in range(len(centers)):
        m_j = (1.0 + inv[j]) * np.eye(3) - 2.0 * inv[j] * np.outer(normals[j], normals[j])
        matrix = matrix @ m_j
    return matrix


def test_the_batched_matrix_is_the_product_one_obstacle_at_a_time():
    """modulation() builds every M_j at once: the plain per-obstacle product's numbers to the bit
    (the same operations on each element), inside, outside and at an obstacle's centre."""
    rng = np.random.default_rng(5)
    for k in range(300):
        n = int(rng.integers(1, 6))
        centers, radii = _scene(rng, n)
        x = centers[0] if k % 50 == 0 else rng.uniform(-1.0, 1.0, 3)
        safety, power = rng.uniform(0.0, 0.2), rng.choice([0.5, 1.0, 2.0])
        np.testing.assert_array_equal(modulation(x, centers, radii, None, safety, power).matrix,
                                      _reference_matrix(x, centers, radii, safety, power))
