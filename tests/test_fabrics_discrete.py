"""The fabric at the control rate (tamedpuma/fabrics/discrete.py): the barrier step is the
M-projection onto the half-spaces and removes energy, barriers are never crossed at Δt on the arm,
the speed limit keeps the direction and every joint under its limit."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.fabrics.discrete import (
    barrier_step,
    energized_velocity_step,
    limit_speed,
)

Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])


def _spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T + 0.2 * np.eye(n)


def test_barrier_step_is_the_metric_projection_onto_the_half_spaces():
    rng = np.random.default_rng(0)
    dt, kappa = 0.02, 0.5
    for _ in range(200):
        n, R = 7, int(rng.integers(1, 8))
        M, A = _spd(rng, n), rng.normal(size=(R, n))
        x, v = rng.uniform(1e-3, 0.5, size=R), rng.normal(scale=3.0, size=n)
        w, active = barrier_step(v, A, x, dt, kappa, M)
        b = -kappa * x / dt
        assert np.all(A @ w >= b - 1e-9)
        assert w @ M @ w <= v @ M @ v + 1e-9  # energy never grows (0 is admissible)
        if np.all(A @ v >= b):
            assert active == 0 and np.array_equal(w, v)
            continue
        # optimality: no admissible point on the segment to random admissible points is closer
        dist = (w - v) @ M @ (w - v)
        for _ in range(20):
            z = w + rng.normal(scale=0.5, size=n)
            if np.all(A @ z >= b):
                for t in (0.01, 0.1, 0.5, 1.0):
                    y = w + t * (z - w)
                    assert (y - v) @ M @ (y - v) >= dist - 1e-9


def test_limit_speed_keeps_the_direction_and_every_joint_under_its_limit():
    rng = np.random.default_rng(1)
    qd_max = np.array([1.4835, 1.4835, 1.7453, 1.3090, 2.2689, 2.3562, 2.3562])
    for _ in range(100):
        v = rng.normal(scale=3.0, size=7)
        w, s = limit_speed(v, qd_max)
        assert np.all(np.abs(w) <= qd_max * (1 + 1e-12))
        assert 0 < s <= 1 and np.allclose(w, s * v)
        if np.all(np.abs(v) <= qd_max):
            assert s == 1.0


def test_implicit_step_never_reverses_the_velocity():
    qd, a, M = np.array([1.0, -2.0]), np.zeros(2), np.eye(2)
    for c in (-1.0, -50.0, -1e6):
        out = energized_velocity_step(qd, a, -c, 0.02, M @ qd, 1e-6)
        assert np.all(np.sign(out) == np.sign(qd)) and np.all(np.abs(out) <= np.abs(qd))
        explicit = qd + 0.02 * c * qd
        if c * 0.02 < -1:
            assert np.all(np.sign(explicit) != np.sign(qd))  # what the implicit step avoids


def test_no_barrier_is_crossed_at_the_control_rate_on_the_arm(kinematics):
    """Drive the arm at its speed limits straight at an obstacle (and at joint limits and the
    ground): with the barrier step no body sphere enters the obstacle, no joint leaves its range
    and no sphere goes below the ground; without it the same commands cross."""
    spec = kinematics.spec
    fabric = Fabric(FabricGains(ground_enabled=True), spec.q_min, spec.q_max)
    dt = 0.02
    zeros = np.zeros(7)
    q_start = Q0.copy()
    centers = kinematics.sphere_centers(q_start)
    target = centers[4]
    rng = np.random.default_rng(2)
    for trial in range(5):
        direction = rng.normal(size=7)
        # the obstacle sits where the commanded motion takes the wrist sphere after ~0.5 s
        q_ahead = q_start + 0.5 * direction / np.max(np.abs(direction) / spec.qd_max)
        obstacle = kinematics.sphere_centers(q_ahead)[4][None] + 0.0 * target
        radii = np.array([0.06])
        crossed = {}
        for use_step in (False, True):
            q, qd = q_start.copy(), zeros.copy()
            worst, worst_limit, worst_ground = np.inf, np.inf, np.inf
            for _ in range(100):
                command, _ = limit_speed(direction * 10.0, spec.qd_max)
                state = kinematics.evaluate(q, qd)
                av = fabric.avoidance(state, q, qd, obstacle, radii, np.zeros((1, 3)))
                if use_step:
                    command, _ = barrier_step(command, av.barrier_rows, av.barrier_x, dt, 0.5,
                                              av.M, av.barrier_jdqd)
                qd = command
                q = q + dt * qd
                c = kinematics.sphere_centers(q)
                gap = np.linalg.norm(c - obstacle, axis=1) - spec.sphere_radii - radii
                worst = min(worst, gap.min())
                worst_limit = min(worst_limit, np.min(q - spec.q_min), np.min(spec.q_max - q))
                worst_ground = min(worst_ground, np.min(c[:, 2] - spec.sphere_radii))
            crossed[use_step] = (worst, worst_limit, worst_ground)
        assert crossed[False][0] < 0, f"trial {trial}: the test command never reached the obstacle"
        worst, worst_limit, worst_ground = crossed[True]
        assert worst > 0 and worst_limit > -1e-9 and worst_ground > 0, crossed[True]


def test_the_barrier_step_moves_away_from_an_obstacle_that_closes_in():
    """A row whose distance an obstacle closes by itself (drift −5 /s, x = 0.1, Δt = 0.02,
    κ = 0.5): the arm at rest must move away, ``a·w ≥ −κx/Δt − drift = 2.5``; the projection is
    the M-closest such w. When two rows ask for opposite motions (squeezed), no w meets both:
    the static projection (w = 0 admissible) is returned."""
    from tamedpuma.fabrics.discrete import barrier_step

    M = np.diag([2.0, 1.0])
    rows = np.array([[1.0, 0.0]])
    w, active = barrier_step(np.zeros(2), rows, np.array([0.1]), 0.02, 0.5, M,
                             drift=np.array([-5.0]))
    assert active == 1 and w == pytest.approx([2.5, 0.0])
    w, _ = barrier_step(np.array([0.0, 1.0]), rows, np.array([0.1]), 0.02, 0.5, M,
                        drift=np.array([-1.0]))  # closing slowly: nothing to do
    assert w == pytest.approx([0.0, 1.0])
    squeezed = np.array([[1.0, 0.0], [-1.0, 0.0]])
    w, _ = barrier_step(np.array([-1.0, 1.0]), squeezed, np.array([0.1, 0.1]), 0.02, 0.5, M,
                        drift=np.array([-5.0, -5.0]))
    assert np.all(np.isfinite(w)) and np.all(squeezed @ w >= -2.5 - 1e-9)


@pytest.mark.parametrize("moving,standoff", [(False, 0.0), (True, 0.0), (True, 1e-3)])
def test_far_pairs_left_out_of_the_barrier_step_give_the_same_step(kinematics, moving,
                                                                    standoff):
    """Many obstacles: the pairs beyond the activation distance have no row (FarRows). The
    step over the kept rows equals the step over every row, whether the far rows' bound holds
    (the common case) or not (then the step is taken again over all rows); every far pair's
    constraint holds at the answer."""
    spec = kinematics.spec
    fab = Fabric(FabricGains(), spec.q_min, spec.q_max)
    rng = np.random.default_rng(21)
    seen = {"bound": 0, "again": 0}
    for trial in range(40):
        q, qd = Q0 + rng.normal(scale=0.2, size=7), rng.normal(scale=0.5, size=7)
        st = kinematics.evaluate(q, qd)
        centers = rng.uniform([-0.9, -0.9, 0.0], [0.9, 0.9, 1.3], size=(300, 3))
        centers[0] = st.sphere_centers[3] + [0.0, 0.0, 0.14]  # one pair close
        vel = rng.normal(scale=0.3, size=(300, 3)) if moving else np.zeros((300, 3))
        av = fab.avoidance(st, q, qd, centers, np.full(300, 0.05), vel)
        assert av.far_rows is not None
        f_rows, f_x, f_jd, f_drift = av.far_rows.rows()
        rows = np.concatenate((av.barrier_rows, f_rows))
        x, jd = np.concatenate((av.barrier_x, f_x)), np.concatenate((av.barrier_jdqd, f_jd))
        drift = av.barrier_xd - av.barrier_rows @ qd
        all_drift = np.concatenate((drift, f_drift)) if moving else None
        dt = 0.02 if trial % 2 else 0.4  # 0.4 s: the far bound fails, the step is redone
        v = rng.normal(scale=1.5, size=7)
        full = barrier_step(v, rows, x, dt, 0.5, av.M, jd, all_drift, standoff=standoff)
        w, active = barrier_step(v, av.barrier_rows, av.barrier_x, dt, 0.5, av.M,
                                 av.barrier_jdqd, drift if moving else None, av.far_rows,
                                 standoff)
        holds = (av.far_rows.holds(v, dt, 0.5, standoff)
                 and av.far_rows.holds(w, dt, 0.5, standoff))
        seen["bound" if holds else "again"] += 1
        np.testing.assert_allclose(w, full[0], rtol=1e-9, atol=1e-9)
        assert active == full[1]
        b = -0.5 * (f_x - standoff) / dt - 0.5 * dt * np.minimum(f_jd, 0.0)
        if holds:  # the bound is sound: every far row holds at w, with and without drift
            assert np.all(f_rows @ w >= b) and np.all(f_rows @ w + f_drift >= b)
    assert seen["bound"] and seen["again"]


def test_with_a_standoff_an_obstacle_that_keeps_closing_in_never_gets_the_distance_to_zero():
    """A 1-d barrier x whose obstacle closes in at a constant rate (drift −0.2 /s), the arm's
    own rate the projected w, x⁺ = x + Δt (w + drift) + a small second-order error that the
    linearised constraint does not see (−1e-7 per step, the curvature of a real arm's rows):
    with x_s = 0 the distance halves towards 0 every period and the error takes it past 0;
    with a standoff x_s = 1e-3 it settles at ~x_s and never crosses."""
    M, rows = np.eye(1), np.ones((1, 1))
    lowest = {}
    for standoff in (0.0, 1e-3):
        x, w = 0.05, np.zeros(1)
        low = x
        for _ in range(400):
            w, _ = barrier_step(w, rows, np.array([x]), 0.02, 0.5, M, drift=np.array([-0.2]),
                                standoff=standoff)
            x = x + 0.02 * (float(w[0]) - 0.2) - 1e-7
            low = min(low, x)
        lowest[standoff] = low
    assert lowest[0.0] < 0.0
    assert 0.5e-3 < lowest[1e-3] < 1.5e-3


def test_control_rate_options_parse_and_bad_values_are_one_line_errors():
    from tamedpuma.errors import ConfigError
    from tamedpuma.methods._tamed import ControlRate

    rate = ControlRate.from_mapping({"barrier_step": True, "semi_implicit": True})
    assert rate.barrier_step and rate.semi_implicit and not rate.speed_limit
    for bad, match in (({"brake": True}, "unknown"), ({"kappa": 0.5}, "unknown")):
        with pytest.raises(ConfigError, match=match):
            ControlRate.from_mapping(bad)


def test_the_speed_limit_keeps_the_headroom_and_the_direction():
    """With the speed limit the next velocity is scaled uniformly onto (1 − h) q̇_max (h: the
    headroom): the fastest joint lands on it, the direction is kept, and a velocity already
    within it passes."""
    from tamedpuma.methods._tamed import SPEED_HEADROOM as h
    from tamedpuma.methods._tamed import ControlRate

    qd_max = np.array([1.48, 1.48, 1.74, 1.31, 2.27, 2.36, 2.36])
    rng = np.random.default_rng(11)
    assert 0.0 < h < 0.1
    rate = ControlRate(speed_limit=True)
    for _ in range(60):
        v = rng.normal(scale=3.0, size=7)
        w, log = rate.next_velocity(v, None, 0.02, qd_max)
        ratio = np.abs(v) / ((1 - h) * qd_max)
        if ratio.max() > 1:
            assert np.max(np.abs(w) / qd_max) == pytest.approx(1 - h)
            assert log["speed_scale"] == pytest.approx(1 / ratio.max())
            assert np.allclose(w * np.linalg.norm(v), v * np.linalg.norm(w))  # w = s v
        else:
            assert np.array_equal(w, v)


def test_the_energized_step_solves_the_rank_one_implicit_system():
    """(I + αΔt P) q̇⁺ = q̇ + Δt a with P x = q̇ (q̇ᵀM x)/(q̇ᵀMq̇ + ε): the step's residual is at
    rounding, and it agrees with a dense solve as far as the system's condition number lets the
    dense solve itself be right (at α = 10⁹ about 10⁷: ~10⁻⁹ of the largest component, and the
    last digits then differ between CPUs' LAPACK builds); α ≤ 0 is the explicit step."""
    rng = np.random.default_rng(5)
    dt, eps = 0.02, 1e-6
    for scale in (1e-4, 1e-2, 1.0):
        M = _spd(rng, 7)
        qd, a = scale * rng.normal(size=7), rng.normal(size=7)
        Mqd = M @ qd
        for alpha in (1e-3, 3.0, 1e4, 1e9):
            P = np.outer(qd, Mqd) / (qd @ Mqd + eps)
            A, b = np.eye(7) + alpha * dt * P, qd + dt * a
            got = energized_velocity_step(qd, a, alpha, dt, Mqd, eps)
            scale_ab = np.abs(A).max() * np.abs(got).max() + np.abs(b).max()
            assert np.abs(A @ got - b).max() <= 1e-13 * scale_ab  # backward error: rounding
            want = np.linalg.solve(A, b)
            tol = max(1e-9, 10 * np.linalg.cond(A) * np.finfo(float).eps)
            np.testing.assert_allclose(got, want, rtol=max(1e-7, tol),
                                       atol=tol * np.abs(want).max())
        for alpha in (0.0, -4.0):
            np.testing.assert_allclose(energized_velocity_step(qd, a, alpha, dt, Mqd, eps),
                                       qd + dt * (a - alpha * qd), atol=1e-15)


def test_the_energized_step_keeps_the_push_across_the_velocity():
    """Energization acts along q̇ only: along q̇ the step is the implicit one (never reverses
    q̇, whatever α), and the M-orthogonal part of Δt a is applied in full, however large α is
    (the isotropic (q̇ + Δt a)/(1 + αΔt) would divide it by 1 + αΔt and hold the arm still)."""
    rng = np.random.default_rng(6)
    dt, eps = 0.02, 1e-12
    for _ in range(50):
        M = _spd(rng, 7)
        qd = 1e-3 * rng.normal(size=7)
        Mqd = M @ qd
        u = qd / np.sqrt(qd @ Mqd)
        across = rng.normal(size=7)
        across -= u * (u @ M @ across)  # M-orthogonal to q̇
        along = rng.normal() * 10.0
        a = along * u + across
        alpha = float(Mqd @ a) / (qd @ Mqd + eps)  # α of the law (f_L = 0)
        nxt = energized_velocity_step(qd, a, alpha, dt, Mqd, eps)
        dq = nxt - qd
        np.testing.assert_allclose(dq - u * (u @ M @ dq), dt * across, rtol=1e-6, atol=1e-12)
        speed_along = u @ M @ nxt
        assert speed_along * (u @ M @ qd) >= 0  # never reversed along q̇
        if alpha > 0:
            iso = (qd + dt * a) / (1.0 + alpha * dt)  # the isotropic implicit step
            assert np.linalg.norm(iso - u * (u @ M @ iso)) < np.linalg.norm(dt * across)
