"""tamedpuma.robot.rotations against known rotations and against each other (x, y, z, w)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tamedpuma.robot import rotations as r

RNG = np.random.default_rng(7)
S = math.sqrt(0.5)
Z90 = np.array([0.0, 0.0, S, S])  # 90° about z
X90 = np.array([S, 0.0, 0.0, S])  # 90° about x
RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def _unit(n):
    q = RNG.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_hamilton_product_of_the_basis_and_of_known_rotations():
    i, j, k, one = np.eye(4)
    np.testing.assert_array_equal(r.quat_mul(i, j), k)  # ij = k
    np.testing.assert_array_equal(r.quat_mul(j, i), -k)  # ji = −k
    np.testing.assert_array_equal(r.quat_mul(i, i), -one)  # i² = −1
    np.testing.assert_array_equal(r.quat_mul(one, [1.0, 2.0, 3.0, 4.0]), [1.0, 2.0, 3.0, 4.0])
    # two quarter turns about z are a half turn; R(a ⊗ b) = R(a) R(b) (then b applied first)
    np.testing.assert_allclose(r.quat_mul(Z90, Z90), [0.0, 0.0, 1.0, 0.0], atol=1e-15)
    a, b = _unit(50), _unit(50)
    np.testing.assert_allclose(r.quats_to_matrices(r.quat_mul(a, b)),
                               r.quats_to_matrices(a) @ r.quats_to_matrices(b), atol=1e-12)


def test_conjugate_inverts_and_relative_quat_is_the_rotation_from_the_goal():
    q, g = _unit(30), _unit(30)
    np.testing.assert_array_equal(r.quat_conj([1.0, 2.0, 3.0, 4.0]), [-1.0, -2.0, -3.0, 4.0])
    prod = r.quat_mul(q, r.quat_conj(q))
    np.testing.assert_allclose(prod, np.tile([0.0, 0.0, 0.0, 1.0], (30, 1)), atol=1e-15)
    rel = r.relative_quat(q, g)  # ζ ⊗ ζ_g⁻¹: R_rel R_g = R
    np.testing.assert_allclose(r.quats_to_matrices(rel) @ r.quats_to_matrices(g),
                               r.quats_to_matrices(q), atol=1e-12)
    np.testing.assert_allclose(r.relative_quat(3.0 * Z90, 0.5 * np.array([0, 0, 0, 1.0])), Z90)


def test_angles_of_known_rotations():
    assert r.quat_angle(Z90) == pytest.approx(math.pi / 2, rel=1e-15)
    assert r.quat_angle(-Z90) == pytest.approx(math.pi / 2, rel=1e-15)  # q ≡ −q
    assert r.quat_angle([0.0, 0.0, 0.0, 1.0]) == 0.0
    assert r.orientation_error(Z90, [0.0, 0.0, 0.0, 1.0]) == pytest.approx(math.pi / 2)
    assert r.orientation_error(Z90, -Z90) == pytest.approx(0.0, abs=1e-7)
    # 90° about x then 90° about z: a 120° rotation (axis (1, 1, 1)/√3 up to sign)
    assert r.orientation_error(r.quat_mul(Z90, X90), [0, 0, 0, 1.0]) == pytest.approx(
        2 * math.pi / 3)
    a, b = _unit(6), _unit(9)
    pair = r.orientation_errors_between(a, b)
    assert pair.shape == (6, 9)
    np.testing.assert_allclose(pair, r.orientation_error(a[:, None], b[None]), atol=1e-7)
    np.testing.assert_allclose(pair, r.quat_angle(r.relative_quat(a[:, None], b[None])),
                               atol=1e-7)


def test_matrices_of_known_quaternions_in_every_form():
    np.testing.assert_allclose(r.quat_to_matrix(Z90), RZ90, atol=1e-15)
    np.testing.assert_allclose(r.quat_to_matrix(2.0 * Z90), RZ90, atol=1e-15)  # normalised
    np.testing.assert_allclose(r.unit_quats_to_matrices(Z90), RZ90, atol=1e-15)
    np.testing.assert_allclose(np.reshape(r.rotation_entries(*Z90), (3, 3)), RZ90, atol=1e-15)
    q = _unit(20)
    mats = r.quats_to_matrices(q)
    np.testing.assert_allclose(r.unit_quats_to_matrices(q), mats, atol=1e-15)
    np.testing.assert_allclose(np.array([r.rotation_entries(*x) for x in q]).reshape(-1, 3, 3),
                               mats, atol=1e-15)
    np.testing.assert_allclose(mats @ mats.transpose(0, 2, 1), np.tile(np.eye(3), (20, 1, 1)),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(mats), 1.0, atol=1e-12)
    # not normalised: s² R + (1 − s²) I (what unit_quats_to_matrices promises)
    np.testing.assert_allclose(r.unit_quats_to_matrices(2.0 * Z90), 4.0 * RZ90 - 3.0 * np.eye(3),
                               atol=1e-14)


def test_relative_rotation_on_floats_is_the_matrix_of_relative_quat():
    q, g = RNG.normal(size=(25, 4)), RNG.normal(size=(25, 4))  # not normalised: both are
    for a, b in zip(q, g):
        entries = r.relative_rotation(a.tolist(), b.tolist())
        assert all(isinstance(e, float) for e in entries)
        np.testing.assert_allclose(np.reshape(entries, (3, 3)),
                                   r.quat_to_matrix(r.relative_quat(a, b)), atol=1e-14)
    assert all(math.isnan(e) for e in r.relative_rotation([0.0] * 4, [0.0, 0.0, 0.0, 1.0]))


def test_error_to_goal_is_the_angle_and_the_log_of_relative_quat_to_the_bit():
    q, g = _unit(400), _unit(400)
    g[:100] = q[:100] + RNG.normal(size=(100, 4)) * 1e-7  # near the goal
    g[100:120] = q[100:120]  # at it (|θ| below the log's threshold)
    g[120:140] = -q[120:140]  # the same orientation, the other sign (w < 0)
    q[140:200] *= RNG.uniform(0.5, 2.0, size=(60, 1))  # not normalised
    cases = [*zip(q, g), (np.full(4, np.nan), g[0]), (np.zeros(4), g[0])]
    with np.errstate(invalid="ignore"):  # the zero quaternion's 0/0
        for a, b in cases:
            angle, rotation = r.error_to_goal(a, b)
            assert isinstance(angle, float)
            np.testing.assert_array_equal(angle, float(r.orientation_error(a, b)))
            assert rotation.tobytes() == r.quat_log(r.relative_quat(a, b)).tobytes()
    np.testing.assert_array_equal(r.error_to_goal(Z90.tolist(), [0.0, 0.0, 0.0, 1.0])[1],
                                  r.quat_log(Z90))


def test_skew_is_the_cross_product_and_its_generators_are_the_basis():
    v, w = RNG.normal(size=(10, 3)), RNG.normal(size=(10, 3))
    np.testing.assert_allclose(np.einsum("kij,kj->ki", r.skew(v), w), np.cross(v, w),
                               atol=1e-15)
    np.testing.assert_array_equal(r.skew([0.0, 0.0, 1.0]), [[0, -1, 0], [1, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(r.skew(v[0]), -r.skew(v[0]).T)
    gens = r.SKEW_GENERATORS.reshape(3, 3, 3)
    for k, e in enumerate(np.eye(3)):
        np.testing.assert_array_equal(gens[k], r.skew(e))
    np.testing.assert_array_equal(r.skew(v).reshape(10, 9), v @ r.SKEW_GENERATORS)


def test_exp_and_log_maps_round_trip_and_rpy_of_a_known_rotation():
    omega = RNG.normal(size=3)
    omega *= 2.5 / np.linalg.norm(omega)
    R = r.exp_so3(omega)
    np.testing.assert_allclose(r.rotation_error(np.eye(3), R), omega, atol=1e-12)
    np.testing.assert_allclose(r.exp_so3([0.0, 0.0, math.pi / 2]), RZ90, atol=1e-15)
    np.testing.assert_allclose(r.rpy_to_matrix([0.0, 0.0, math.pi / 2]), RZ90, atol=1e-15)
    q = _unit(15)
    back = r.matrix_to_quat(r.quats_to_matrices(q))
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=1)), 1.0, atol=1e-12)
    assert np.all(back[:, 3] >= 0)
    # a smooth path of orientations with random signs: made continuous, every step is short
    path = r.quat_mul(np.stack([r.matrix_to_quat(r.exp_so3([0.0, 0.0, 0.05 * t]))
                                for t in range(40)]), _unit(1))
    signs = np.where(RNG.random(40) < 0.5, -1.0, 1.0)[:, None]
    cont = r.continuous_quats(signs * path)
    assert np.all(np.sum(cont[1:] * cont[:-1], axis=1) > 0.99)
    np.testing.assert_array_equal(cont, signs[0] * path)  # the first sign kept
