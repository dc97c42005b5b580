"""Leaves: task maps against finite differences, the vectorised pullback against a per-pair loop,
barrier guards (clamping, counting, never a negative metric), obstacle count as run-time data."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.fabrics import Fabric, FabricError, FabricGains, Spec, quaternion_to_rotation
from tamedpuma.fabrics.energy import barrier_leaf
from tamedpuma.fabrics.leaves import (
    goal_errors,
    ground_plane,
    joint_limits,
    pull_sphere_pairs,
    sphere_obstacle_pairs,
)
from tamedpuma.robot.rotations import skew

Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])
GOAL_P = np.array([0.58, -0.214, 0.115])
GOAL_R = quaternion_to_rotation([-0.5459, 0.5806, -0.4112, 0.4426])


def _obstacles(rng, n, moving=True):
    centers = rng.uniform([-0.8, -0.8, 0.0], [0.8, 0.8, 1.2], size=(n, 3))
    radii = rng.uniform(0.02, 0.1, size=n)
    vel = rng.normal(scale=0.3, size=(n, 3)) if moving else np.zeros((n, 3))
    return centers, radii, vel


def _pairs(kinematics, q, qd, obs, margin=1e-3):
    st = kinematics.evaluate(q, qd)
    return st, sphere_obstacle_pairs(st.sphere_centers, st.sphere_jacobians, st.sphere_jdqd,
                                     st.sphere_radii, qd, *obs, margin)


def test_pair_task_map_matches_finite_differences(kinematics):
    """x(t) along q(t) = q + t q̇ (q̈ = 0) with moving obstacles: x' = ẋ, x'' = J̇q̇, ∂x/∂q = uᵀJ."""
    rng = np.random.default_rng(0)
    q, qd = Q0 + rng.normal(scale=0.3, size=7), rng.normal(size=7)
    obs = _obstacles(rng, 6)
    st, pairs = _pairs(kinematics, q, qd, obs)
    radii = st.sphere_radii

    def x_at(t, dq=0.0):
        c = kinematics.sphere_centers(q + t * qd + dq)
        o = obs[0] + t * obs[2]
        d = np.linalg.norm(c[:, None] - o[None], axis=-1)
        return d / (radii[:, None] + obs[1]) - 1.0

    h = 1e-4
    np.testing.assert_allclose(pairs.x, x_at(0.0), atol=1e-12)
    np.testing.assert_allclose(pairs.xd, (x_at(h) - x_at(-h)) / (2 * h), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(pairs.jdqd, (x_at(h) - 2 * x_at(0) + x_at(-h)) / h**2,
                               rtol=1e-4, atol=1e-5)
    rows = np.einsum("dkn,kdq->knq", pairs.u, st.sphere_jacobians)
    fd = np.stack([(x_at(0, h * e) - x_at(0, -h * e)) / (2 * h) for e in np.eye(7)], -1)
    np.testing.assert_allclose(rows, fd, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(pairs.clearance, (pairs.x) * (radii[:, None] + obs[1]), atol=1e-12)


def test_goal_errors_match_finite_differences(kinematics):
    rng = np.random.default_rng(1)
    q, qd = Q0 + rng.normal(scale=0.3, size=7), rng.normal(size=7)
    offsets = 0.045 * np.eye(3)
    st = kinematics.evaluate(q, qd)
    terms = goal_errors(st.ee_position, st.ee_rotation, st.ee_jacobian, st.ee_jdqd, qd, GOAL_P,
                        GOAL_R, offsets)

    def e_at(qq):
        p, quat = kinematics.ee_pose(qq)
        R = quaternion_to_rotation(quat)
        return np.concatenate(((p - GOAL_P)[None], offsets @ R.T - offsets @ GOAL_R.T))

    h = 1e-4
    np.testing.assert_allclose(terms.e, e_at(q), atol=1e-12)
    J = terms.jacobians[:, :, :7]
    fd = np.stack([(e_at(q + h * d) - e_at(q - h * d)) / (2 * h) for d in np.eye(7)], -1)
    np.testing.assert_allclose(J, fd, atol=1e-8)
    acc = (e_at(q + h * qd) - 2 * e_at(q) + e_at(q - h * qd)) / h**2
    np.testing.assert_allclose(terms.jacobians[:, :, 7], acc, atol=2e-5)
    v = rng.normal(size=3)
    np.testing.assert_allclose(skew(v) @ np.array([1.0, 2.0, 3.0]), np.cross(v, [1.0, 2.0, 3.0]))


def test_vectorised_pair_pullback_equals_a_loop_of_pullbacks(kinematics):
    rng = np.random.default_rng(2)
    q, qd = Q0, rng.normal(size=7)
    st, pairs = _pairs(kinematics, q, qd, _obstacles(rng, 9))
    gains = FabricGains().obstacle
    m, f, fl, _ = barrier_leaf(pairs.x, pairs.xd, gains)
    M, F = pull_sphere_pairs(m, f + m * pairs.jdqd, fl + m * pairs.jdqd, pairs.u,
                             st.sphere_jacobians)
    loop = Spec(np.zeros((7, 7)), np.zeros(7))
    loop_energy = np.zeros(7)
    for i in range(m.shape[0]):
        for j in range(m.shape[1]):
            row = (pairs.u[:, i, j] @ st.sphere_jacobians[i])[None]
            jd = pairs.jdqd[i, j:j + 1]
            loop = loop + Spec(m[i, j][None, None], f[i, j:j + 1]).pull(row, jd)
            loop_energy += Spec(m[i, j][None, None], fl[i, j:j + 1]).pull(row, jd).f
    np.testing.assert_allclose(M, loop.M, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(F[0], loop.f, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(F[1], loop_energy, rtol=1e-10, atol=1e-12)


def _fabric(kinematics, **changes):
    return Fabric(FabricGains(**changes), kinematics.spec.q_min, kinematics.spec.q_max)


def test_obstacle_count_is_run_time_data_and_pairs_add_up(kinematics):
    """One Fabric object serves any count; n obstacles contribute the sum of their single ones."""
    fab = _fabric(kinematics)
    rng = np.random.default_rng(3)
    qd = rng.normal(size=7)
    st = kinematics.evaluate(Q0, qd)
    empty = fab.avoidance(st, Q0, qd, np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    assert empty.min_clearance == np.inf
    for n in (1, 2, 7, 300):
        obs = _obstacles(rng, n)
        keep = np.min(np.linalg.norm(st.sphere_centers[:, None] - obs[0][None], axis=-1), 0) > 0.3
        obs = tuple(a[keep] for a in obs)
        av = fab.avoidance(st, Q0, qd, *obs)
        singles = [fab.avoidance(st, Q0, qd, *(a[j:j + 1] for a in obs))
                   for j in range(len(obs[1]))]
        for name in ("M", "f", "f_energy"):
            expected = getattr(empty, name) + sum(getattr(s, name) - getattr(empty, name)
                                                  for s in singles)
            np.testing.assert_allclose(getattr(av, name), expected, rtol=1e-9, atol=1e-9)
        perm = rng.permutation(len(obs[1]))
        shuffled = fab.avoidance(st, Q0, qd, *(a[perm] for a in obs))
        np.testing.assert_allclose(shuffled.M, av.M, rtol=1e-12, atol=1e-12)
        assert av.min_clearance == pytest.approx(min(s.min_clearance for s in singles))


def test_moving_obstacle_uses_the_relative_velocity(kinematics):
    """A still arm and an obstacle flying at it: the approach (ẋ < 0) switches the geometry on."""
    fab = _fabric(kinematics)
    qd = np.zeros(7)
    st = kinematics.evaluate(Q0, qd)
    c = st.sphere_centers[2]
    center = (c + np.array([0.25, 0.0, 0.0]))[None]
    still = fab.avoidance(st, Q0, qd, center, np.array([0.05]), np.zeros((1, 3)))
    flying = fab.avoidance(st, Q0, qd, center, np.array([0.05]), np.array([[-1.0, 0.0, 0.0]]))
    leaving = fab.avoidance(st, Q0, qd, center, np.array([0.05]), np.array([[1.0, 0.0, 0.0]]))
    assert np.allclose(still.f, 0.0)
    # the geometry pushes sphere 2 away from the approaching obstacle (−x direction)
    qdd = flying.acceleration()
    sphere_acc = st.sphere_jacobians[2] @ qdd
    assert sphere_acc[0] < 0
    assert np.linalg.norm(leaving.f) < 1e-2 * np.linalg.norm(flying.f)
    # pair level: receding (ẋ > 0) switches the directional geometry off
    _, pairs = _pairs(kinematics, Q0, qd, (center, np.array([0.05]), np.array([[1.0, 0, 0]])))
    assert pairs.xd[2, 0] > 0
    assert barrier_leaf(pairs.x, pairs.xd, FabricGains().obstacle)[1][2, 0] == 0


def test_penetration_is_clamped_counted_and_still_pushes_out(kinematics):
    fab = _fabric(kinematics)
    st = kinematics.evaluate(Q0, np.zeros(7))
    c = st.sphere_centers[3]
    qd = -0.3 * np.linalg.pinv(st.sphere_jacobians[3]) @ np.array([1.0, 0.0, 0.0])
    st = kinematics.evaluate(Q0, qd)
    for offset in (0.1, 0.05, 0.0):  # overlapping, deep, centred on the body sphere
        centers = (c + np.array([offset, 0.0, 0.0]))[None]
        av = fab.avoidance(st, Q0, qd, centers, np.array([0.05]), np.zeros((1, 3)))
        assert av.n_clamped >= 1 and av.min_clearance < 0
        assert np.all(np.isfinite(av.M)) and np.all(np.isfinite(av.f))
        assert np.linalg.eigvalsh(av.M).min() > 0
        qdd = av.acceleration()
        assert np.all(np.isfinite(qdd)) and np.linalg.norm(qdd) > 0


def test_ground_plane_leaf(kinematics):
    fab = _fabric(kinematics, ground_enabled=True, ground_height=0.1)
    q = Q0.copy()
    qd = np.zeros(7)
    qd[1] = 0.5  # shoulder forward: the arm moves down
    st = kinematics.evaluate(q, qd)
    terms = ground_plane(st.sphere_centers, st.sphere_jacobians, st.sphere_jdqd, st.sphere_radii,
                         qd, 0.1, 1e-3)
    np.testing.assert_allclose(terms.clearance, st.sphere_centers[:, 2] - st.sphere_radii - 0.1)
    off = _fabric(kinematics).avoidance(st, q, qd, np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    on = fab.avoidance(st, q, qd, np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    assert on.ground_clearance == pytest.approx(terms.clearance.min())
    assert np.linalg.eigvalsh(on.M - off.M).min() > -1e-12
    descending = np.any(terms.xd < 0)
    assert descending
    # the ground geometry decelerates the descent of the lowest approaching sphere
    i = np.argmin(np.where(terms.xd < 0, terms.x, np.inf))
    acc_on = st.sphere_jacobians[i, 2] @ on.acceleration()
    acc_off = st.sphere_jacobians[i, 2] @ off.acceleration()
    assert acc_on > acc_off


def test_start_on_or_past_a_joint_limit_is_clamped_not_a_blow_up(kinematics):
    spec = kinematics.spec
    fab = _fabric(kinematics)
    for q_bad in (spec.q_max[1], spec.q_max[1] + 5e-6, spec.q_min[1] - 1e-3):
        q = Q0.copy()
        q[1] = q_bad
        lim = joint_limits(q, np.zeros(7), spec.q_min, spec.q_max, 1e-3)
        assert lim.n_clamped >= 1 and lim.x.min() >= 1e-3
        qd = np.full(7, 0.2)
        qdd, diag = fab.evaluate(kinematics.evaluate(q, qd), q, qd, np.zeros((0, 3)), np.zeros(0),
                                 np.zeros((0, 3)), GOAL_P, GOAL_R)
        assert diag.n_limit_clamped >= 1
        assert np.all(np.isfinite(qdd)) and np.linalg.norm(qdd) > 0


def test_non_finite_input_raises_instead_of_a_silent_zero(kinematics):
    fab = _fabric(kinematics)
    qd = np.zeros(7)
    st = kinematics.evaluate(Q0, qd)
    with pytest.raises(FabricError):
        fab.evaluate(st, Q0, qd, np.array([[np.nan, 0.0, 0.5]]), np.array([0.05]),
                     np.zeros((1, 3)), GOAL_P, GOAL_R)
    with pytest.raises(FabricError), np.errstate(invalid="ignore"):
        fab.evaluate(st, Q0, qd, np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)),
                     np.array([np.nan, 0.0, 0.0]), GOAL_R)


def test_forcing_is_the_pullback_of_the_attractor_specs(kinematics):
    """(M_ψ, f_ψ) = Σ_k pull (g_k I, g_k ∇ψ_k) through the position and orientation-vector maps."""
    from tamedpuma.fabrics.energy import attractor_metric, attractor_potential

    fab = _fabric(kinematics, orientation_axes=(0, 2), orientation_weight=2.0, goal_weight=1.5)
    rng = np.random.default_rng(4)
    q, qd = Q0 + rng.normal(scale=0.2, size=7), rng.normal(size=7)
    st = kinematics.evaluate(q, qd)
    fo = fab.forcing(st, qd, GOAL_P, GOAL_R)
    terms = goal_errors(st.ee_position, st.ee_rotation, st.ee_jacobian, st.ee_jdqd, qd, GOAL_P,
                        GOAL_R, 0.045 * np.eye(3)[[0, 2]])
    total = Spec(np.zeros((7, 7)), np.zeros(7))
    for e, jac, w in zip(terms.e, terms.jacobians, (1.5, 2.0, 2.0)):
        _, grad, r = attractor_potential(e, fab.gains, w)
        gm = float(attractor_metric(r, fab.gains))
        total = total + Spec(gm * np.eye(3), gm * grad).pull(jac[:, :7], jac[:, 7])
    np.testing.assert_allclose(fo.M, total.M, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(fo.f, total.f, rtol=1e-12, atol=1e-12)
    assert fo.goal_distance == pytest.approx(np.linalg.norm(st.ee_position - GOAL_P))


def test_an_extra_hand_sphere_is_only_config(robot_spec):
    """The real robot's hand sphere (diameter 0.14 m) is one more config entry: k = 6 spheres."""
    import dataclasses

    from tamedpuma.robot.kinematics import BodySphere, Kinematics

    spec = dataclasses.replace(robot_spec, spheres=robot_spec.spheres + (
        BodySphere("lbr_iiwa_link_7", 0.07, (0.0, 0.0, 0.1)),))
    kin = Kinematics(spec)
    fab = Fabric(FabricGains(), spec.q_min, spec.q_max)
    rng = np.random.default_rng(5)
    qd = rng.normal(size=7)
    st = kin.evaluate(Q0, qd)
    hand = st.sphere_centers[5]
    obs = ((hand + [0.2, 0.0, 0.0])[None], np.array([0.05]), np.zeros((1, 3)))
    av = fab.avoidance(st, Q0, qd, *obs)
    assert av.min_clearance == pytest.approx(0.2 - 0.12)
    qdd, diag = fab.evaluate(st, Q0, qd, *obs, GOAL_P, GOAL_R)
    assert np.all(np.isfinite(qdd)) and diag.min_clearance == av.min_clearance
