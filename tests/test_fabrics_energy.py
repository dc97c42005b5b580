"""Energies: metrics and forces are the Euler-Lagrange derivatives of each leaf's energy;
energization conserves the energy (at the integrator's order) and keeps HD2 paths."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.fabrics.energy import (
    attractor,
    attractor_blocks,
    attractor_metric,
    attractor_potential,
    barrier_energy,
    barrier_geometry,
    barrier_leaf,
    energize,
)
from tamedpuma.fabrics.gains import GROUND_DEFAULT, LIMIT_DEFAULT, OBSTACLE_DEFAULT, BarrierGains

LEAVES = {"obstacle": OBSTACLE_DEFAULT, "joint_limit": LIMIT_DEFAULT, "ground": GROUND_DEFAULT,
          "other": BarrierGains(0.3, 2.0, True, 0.7, 3.0, False)}


def _lagrangian(gains, activation=np.inf):
    return lambda x, xd: float(barrier_energy(x, xd, gains, activation)[0])


@pytest.mark.parametrize("activation", [np.inf, 2.5, 0.7])
@pytest.mark.parametrize("name", sorted(LEAVES))
def test_barrier_metric_force_and_energy_are_euler_lagrange_derivatives(name, activation):
    """Also with the activation taper w(x) = (1 − (x/x_a)²)² (x_a = 0.7: some samples beyond it,
    where the leaf vanishes)."""
    gains = LEAVES[name]
    L = _lagrangian(gains, activation)
    rng = np.random.default_rng(0)
    for _ in range(20):
        x = rng.uniform(0.05, 2.0)
        if abs(x - activation) < 1e-3:
            continue
        xd = rng.choice([-1, 1]) * rng.uniform(0.1, 2.0)  # away from the switch of s(ẋ)
        h = 1e-4 * x
        k = 1e-4
        _, M, f, H = barrier_energy(x, xd, gains, activation)
        d2_dxd2 = (L(x, xd + k) - 2 * L(x, xd) + L(x, xd - k)) / k**2
        dL_dxd = (L(x, xd + k) - L(x, xd - k)) / (2 * k)
        dL_dx = (L(x + h, xd) - L(x - h, xd)) / (2 * h)
        d2_dxd_dx = (L(x + h, xd + k) - L(x + h, xd - k) - L(x - h, xd + k)
                     + L(x - h, xd - k)) / (4 * h * k)
        scale = 1.0 + abs(float(M))
        assert float(M) == pytest.approx(d2_dxd2, rel=1e-5, abs=1e-6 * scale)
        assert float(f) == pytest.approx(d2_dxd_dx * xd - dL_dx, rel=1e-5, abs=1e-6 * scale)
        assert float(H) == pytest.approx(xd * dL_dxd - L(x, xd), rel=1e-6, abs=1e-9)


def test_activation_taper_is_c1_vanishes_beyond_x_a_and_is_the_reference_as_x_goes_to_0():
    x_a = 1.5
    x = np.array([x_a - 1e-7, x_a, x_a + 1e-7, 10.0])
    m, f, fl, H = barrier_leaf(x, np.full(4, -0.8), OBSTACLE_DEFAULT, x_a)
    np.testing.assert_array_equal([m[1:], f[1:], fl[1:], H[1:]], 0.0)
    assert 0 < m[0] < 1e-13 and abs(fl[0]) < 1e-6  # w and w' → 0 continuously at x_a
    small = np.array([1e-4])
    ref = barrier_leaf(small, np.array([-0.8]), OBSTACLE_DEFAULT)
    tapered = barrier_leaf(small, np.array([-0.8]), OBSTACLE_DEFAULT, x_a)
    np.testing.assert_allclose(tapered, ref, rtol=1e-8)  # w(x) = 1 − 2(x/x_a)² + …
    with pytest.raises(Exception, match="obstacle_activation must be positive"):
        FabricGains(obstacle_activation=0.0)
    g = FabricGains.from_mapping({"obstacle_activation": None})
    assert g.obstacle_activation == np.inf and g.to_mapping()["obstacle_activation"] is None
    assert FabricGains.from_mapping(FabricGains(obstacle_activation=2.0).to_mapping()) == \
        FabricGains(obstacle_activation=2.0)


def test_barriers_never_have_a_negative_metric_and_push_away_while_approaching():
    x = np.geomspace(1e-3, 1e2, 200)
    for gains, activation in [(g, a) for g in LEAVES.values() for a in (np.inf, 3.0)]:
        for xd in (-3.0, -1e-3, 0.0, 1e-3, 3.0):
            m, f, _, H = barrier_leaf(x, np.full_like(x, xd), gains, activation)
            assert np.all(m >= 0) and np.all(H >= 0) and np.all(np.isfinite(f))
            h = barrier_geometry(x, np.full_like(x, xd), gains)
            assert np.all(h <= 0)  # ẍ = −h ≥ 0: never pulls into the barrier


def test_attractor_gradient_and_metric():
    g = FabricGains()
    rng = np.random.default_rng(1)
    weights = np.array([1.0, 2.5, 0.3])
    e = rng.normal(size=(3, 3)) * [[0.3], [0.02], [1e-3]]
    psi, grad, r = attractor_potential(e, g, weights)
    h = 1e-7
    for k in range(3):
        fd = [(attractor_potential(e[k] + h * d, g, weights[k])[0]
               - attractor_potential(e[k] - h * d, g, weights[k])[0]) / (2 * h) for d in np.eye(3)]
        np.testing.assert_allclose(grad[k], fd, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(np.linalg.norm(grad, axis=1),
                               g.goal_potential_gain * weights * np.tanh(g.goal_sharpness * r))
    # metric of L = ½ g(‖e‖) ‖ẋ‖²: ∂²L/∂ẋ² = g I, between its bounds
    gm = attractor_metric(r, g)
    assert np.all(gm >= g.goal_metric_scale * g.goal_metric_min - 1e-12)
    assert np.all(gm <= g.goal_metric_scale * g.goal_metric_max + 1e-12)
    psi2, grad2, r2, gm2 = attractor(e, g, weights)
    np.testing.assert_allclose(psi2, psi)
    np.testing.assert_allclose(grad2, grad)
    np.testing.assert_allclose(gm2, gm)
    psi3, r3, ratio3, gm3 = attractor_blocks((r * r).tolist(), g, weights.tolist())
    assert psi3 == pytest.approx(psi.sum(), rel=1e-12)
    np.testing.assert_allclose(np.array(ratio3)[:, None] * e, grad, rtol=1e-12)
    np.testing.assert_allclose(r3, r, rtol=1e-12)
    np.testing.assert_allclose(gm3, gm, rtol=1e-12)
    # zero error: zero gradient, finite
    assert np.all(attractor(np.zeros((1, 3)), g, np.ones(1))[1] == 0)


# -- joint space, with the real kinematics ----------------------------------------------------

OBSTACLES = (np.array([[0.5, -0.3, 0.5], [0.3, 0.35, 0.3], [0.55, -0.1, 0.25]]),
             np.array([0.05, 0.08, 0.05]), np.zeros((3, 3)))
Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])


def _fabric(kinematics, **changes):
    return Fabric(FabricGains(**changes), kinematics.spec.q_min, kinematics.spec.q_max)


@pytest.mark.parametrize("activation", [np.inf, 1.0, 3.0])
def test_joint_space_metric_and_force_are_euler_lagrange_derivatives(kinematics, activation):
    """The pulled fabric energy L(q, q̇) = Σ leaves + base: M = ∂²L/∂q̇², f_L = (∂²L/∂q̇∂q) q̇ − ∂L/∂q.

    This checks the pullback, the pair Jacobians and the sign of J̇q̇ against the kinematics,
    with and without the obstacle leaf's activation taper.
    """
    fab = _fabric(kinematics, obstacle_activation=activation)
    spec = kinematics.spec

    def L(q, qd):  # every energy here is quadratic in ẋ, so L = H
        return fab.avoidance(kinematics.evaluate(q, qd), q, qd, *OBSTACLES).energy

    def dL_dqd(q, qd, k=1e-5):
        return np.array([(L(q, qd + k * d) - L(q, qd - k * d)) / (2 * k) for d in np.eye(7)])

    rng = np.random.default_rng(3)
    tested = 0
    while tested < 3:
        q = Q0 + rng.normal(scale=0.2, size=7)
        q = np.clip(q, spec.q_min + 0.05, spec.q_max - 0.05)
        q[6] = spec.q_max[6] - 0.02  # a joint limit in play
        qd = rng.choice([-1, 1], size=7) * rng.uniform(0.2, 1.0, size=7)
        av = fab.avoidance(kinematics.evaluate(q, qd), q, qd, *OBSTACLES)
        if not 0.01 < av.min_clearance < 0.3:  # near, not in, an obstacle
            continue
        tested += 1
        assert av.n_clamped == 0 and av.n_limit_clamped == 0
        k = 1e-4
        M_fd = np.array([(dL_dqd(q, qd + k * d) - dL_dqd(q, qd - k * d)) / (2 * k)
                         for d in np.eye(7)])
        h = 1e-5
        mixed = (dL_dqd(q + h * qd, qd) - dL_dqd(q - h * qd, qd)) / (2 * h)
        grad = np.array([(L(q + h * d, qd) - L(q - h * d, qd)) / (2 * h) for d in np.eye(7)])
        scale = np.abs(av.M).max()
        np.testing.assert_allclose(av.M, M_fd, atol=1e-5 * scale)
        np.testing.assert_allclose(av.f_energy, mixed - grad,
                                   atol=1e-5 * max(1.0, np.abs(av.f_energy).max()))
        assert np.linalg.eigvalsh(av.M).min() >= fab.gains.base_metric - 1e-9


def _rk4(f, y, dt):
    k1 = f(y)
    k2 = f(y + 0.5 * dt * k1)
    k3 = f(y + 0.5 * dt * k2)
    k4 = f(y + dt * k3)
    return y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def _energized_flow(fab, kinematics, energized=True):
    def flow(y):
        q, qd = y[:7], y[7:]
        av = fab.avoidance(kinematics.evaluate(q, qd), q, qd, *OBSTACLES)
        qdd = av.acceleration()
        if energized:
            qdd, _ = energize(qd, av.M, av.f_energy, qdd, eps=0.0)  # exact: q̇ ≠ 0 here
        return np.concatenate((qd, qdd))
    return flow


def _energy(fab, kinematics, y):
    q, qd = y[:7], y[7:]
    return fab.avoidance(kinematics.evaluate(q, qd), q, qd, *OBSTACLES).energy


QD0 = np.array([0.6, -0.5, 0.4, 0.9, -0.6, 0.5, 0.7])


def _drift(fab, kinematics, dt, T=0.8):
    flow = _energized_flow(fab, kinematics)
    y = np.concatenate((Q0, QD0))
    H0 = _energy(fab, kinematics, y)
    drift = 0.0
    for _ in range(round(T / dt)):
        y = _rk4(flow, y, dt)
        drift = max(drift, abs(_energy(fab, kinematics, y) - H0) / H0)
    return drift


def test_energized_fabric_conserves_energy_at_the_integrators_order(kinematics):
    # Smooth variant (no s(ẋ) switches, no activation taper: its (1 − (x/x_a)²)² is only C¹ at
    # x_a, where RK4's order drops): RK4's 4th order must show as Δt halves.
    smooth = dataclasses.replace(
        FabricGains(obstacle_activation=np.inf),
        obstacle=dataclasses.replace(OBSTACLE_DEFAULT, geometry_directional=False),
        joint_limit=dataclasses.replace(LIMIT_DEFAULT, energy_directional=False))
    fab = Fabric(smooth, kinematics.spec.q_min, kinematics.spec.q_max)
    drifts = [_drift(fab, kinematics, dt) for dt in (0.04, 0.02, 0.01)]
    orders = np.log2(np.array(drifts[:-1]) / np.array(drifts[1:]))
    assert drifts[-1] < 1e-6
    assert np.all(orders > 3.5), (drifts, orders)
    # The unenergized geometry does not conserve it (the test is not vacuous).
    flow = _energized_flow(fab, kinematics, energized=False)
    y = np.concatenate((Q0, QD0))
    H0 = _energy(fab, kinematics, y)
    for _ in range(40):
        y = _rk4(flow, y, 0.02)
    assert abs(_energy(fab, kinematics, y) - H0) / H0 > 100 * drifts[1]


def test_energized_default_fabric_conserves_energy(kinematics):
    fab = _fabric(kinematics, obstacle_activation=np.inf)
    drifts = [_drift(fab, kinematics, dt) for dt in (0.04, 0.02, 0.01)]
    orders = np.log2(np.array(drifts[:-1]) / np.array(drifts[1:]))
    assert drifts[-1] < 1e-6 and np.all(orders > 3.0), (drifts, orders)


def test_energized_fabric_with_the_activation_taper_conserves_energy_in_continuous_time(
        kinematics):
    """dH/dt = ∇H · (q̇, q̈) = 0 along the energized flow with the default taper (x_a = 2), at
    states with obstacle pairs inside the taper's band 0 < x < x_a (finite differences of H
    along the flow; the unenergized flow's dH/dt is not 0 there: the check is not vacuous)."""
    fab = _fabric(kinematics)
    assert fab.gains.obstacle_activation == 2.0
    flow, free = _energized_flow(fab, kinematics), _energized_flow(fab, kinematics, False)
    rng = np.random.default_rng(5)
    tested = 0
    for _ in range(200):
        q = np.clip(Q0 + rng.normal(scale=0.3, size=7), kinematics.spec.q_min + 0.05,
                    kinematics.spec.q_max - 0.05)
        y = np.concatenate((q, rng.normal(scale=0.7, size=7)))
        av = fab.avoidance(kinematics.evaluate(y[:7], y[7:]), y[:7], y[7:], *OBSTACLES)
        band = av.barrier_x[:av.barrier_x.size - 14]  # the pair rows
        if not np.any((band > 0.2) & (band < 1.8)) or av.n_clamped:
            continue
        h = 1e-6
        rates = [(_energy(fab, kinematics, y + h * f(y)) - _energy(fab, kinematics, y - h * f(y)))
                 / (2 * h) for f in (flow, free)]
        H = _energy(fab, kinematics, y)
        assert abs(rates[0]) < 1e-6 * H * np.abs(flow(y)).max()
        assert abs(rates[1]) > 1e-3 * H
        tested += 1
        if tested == 5:
            break
    assert tested == 5


def _arc_path(ys):
    q = np.array([y[:7] for y in ys])
    s = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))))
    return s, q


def test_energization_keeps_the_path_of_an_hd2_geometry(kinematics):
    fab = _fabric(kinematics, obstacle_activation=np.inf)  # every obstacle bends this path
    paths = []
    for energized in (False, True):
        flow = _energized_flow(fab, kinematics, energized)
        y = np.concatenate((Q0, QD0))
        ys = [y]
        for _ in range(150):
            y = _rk4(flow, y, 0.005)
            ys.append(y)
        paths.append(_arc_path(ys))
    (s0, q0), (s1, q1) = paths
    speed0 = np.linalg.norm(np.diff(q0, axis=0), axis=1)
    speed1 = np.linalg.norm(np.diff(q1, axis=0), axis=1)
    assert np.abs(speed0 - speed1).max() > 1e-3  # energization did change the speed
    length = min(s0[-1], s1[-1])
    grid = np.linspace(0, length, 50)
    a = np.array([np.interp(grid, s0, q0[:, j]) for j in range(7)])
    b = np.array([np.interp(grid, s1, q1[:, j]) for j in range(7)])
    assert length > 0.3
    assert np.abs(a - b).max() < 2e-3 * length
