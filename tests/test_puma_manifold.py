"""Properties of the S³ helpers: exp/log round trips, equivalence of the two steps, no NaN at 0."""

import numpy as np
import pytest
import torch

from tamedpuma.puma import manifold as m
from tamedpuma.robot import rotations

RNG = np.random.default_rng(0)


def _t(a):
    return torch.tensor(a, dtype=torch.float64)


def random_quats(n):
    q = RNG.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@pytest.mark.parametrize("scale", [1e-9, 1e-4, 0.3, 2.0, 3.1])
def test_exp_log_round_trip(scale):
    axis = RNG.normal(size=(50, 3))
    theta = axis / np.linalg.norm(axis, axis=1, keepdims=True) * scale
    back = m.quat_log(m.quat_exp(_t(theta))).numpy()
    np.testing.assert_allclose(back, theta, atol=1e-10, rtol=1e-8)
    q = random_quats(50)
    q2 = m.quat_exp(m.quat_log(_t(q))).numpy()
    np.testing.assert_allclose(np.abs(np.sum(q2 * q, axis=1)), 1.0, atol=1e-12)


def test_zero_velocity_is_finite_with_gradients():
    theta = torch.zeros(4, 3, dtype=torch.float64, requires_grad=True)
    q = m.quat_exp(theta)
    q.sum().backward()
    assert torch.all(torch.isfinite(theta.grad))
    np.testing.assert_allclose(q.detach().numpy(), [[0, 0, 0, 1]] * 4)
    omega = torch.zeros(3, 3, dtype=torch.float64, requires_grad=True)
    q0 = _t(random_quats(3))
    out = m.step_orientation(q0, omega, 0.02)
    log = m.quat_log(_t(np.tile([0.0, 0, 0, 1], (3, 1))).requires_grad_(True))
    (out.sum() + log.sum()).backward()
    assert torch.all(torch.isfinite(omega.grad)) and torch.all(torch.isfinite(log))
    np.testing.assert_allclose(out.detach().numpy(), q0.numpy(), atol=1e-15)
    u = torch.zeros(3, 4, dtype=torch.float64)
    assert torch.all(torch.isfinite(m.sphere_exp(q0, u)))


def test_sphere_exponential_equals_lie_step():
    q = _t(random_quats(20))
    omega = _t(RNG.normal(size=(20, 3)) * 2.0)
    dt = 0.03
    lie = m.step_orientation(q, omega, dt)
    riem = m.sphere_exp(q, m.omega_to_qdot(q, omega) * dt)
    np.testing.assert_allclose(lie.numpy(), riem.numpy(), atol=1e-12)


def test_tangent_projection_and_omega_round_trip():
    q = _t(random_quats(20))
    omega = _t(RNG.normal(size=(20, 3)))
    qdot = m.omega_to_qdot(q, omega)
    np.testing.assert_allclose((qdot * q).sum(-1).numpy(), 0.0, atol=1e-12)  # tangent
    noisy = qdot + 0.3 * q  # a normal component is removed by the projection
    np.testing.assert_allclose(m.qdot_to_omega(q, noisy).numpy(), omega.numpy(), atol=1e-12)


def test_matrix_quaternion_round_trip_and_angle():
    q = random_quats(200)
    q = np.where(q[:, 3:] < 0, -q, q)
    back = rotations.matrix_to_quat(rotations.quats_to_matrices(q))
    np.testing.assert_allclose(back, q, atol=1e-12)
    rot = m.np_random_rotations(RNG, 100, 1.0)
    assert np.all(rotations.quat_angle(rot) <= 1.0 + 1e-12)


def test_quat_mul_matches_rotation_composition():
    a, b = random_quats(10), random_quats(10)
    ab = rotations.quats_to_matrices(rotations.quat_mul(a, b))
    np.testing.assert_allclose(ab, rotations.quats_to_matrices(a) @ rotations.quats_to_matrices(b),
                               atol=1e-12)


def test_fused_products_differentiable_after_first_use_in_inference_mode():
    """The fused products' constant matrices are cached on first use; a first use inside
    ``torch.inference_mode`` (an evaluation before a training in one process) must not leave an
    inference tensor that a later training cannot save for backward."""
    m._CONST.clear()  # the first use is the one below
    q = torch.tensor(random_quats(3), dtype=torch.float32)
    with torch.inference_mode():
        m.quat_to_matrix_flat(q)
        m.quat_mul_fused(q, q)
    q = q.clone().requires_grad_(True)
    (m.quat_to_matrix_flat(q).sum() + m.quat_mul_fused(q, q).sum()).backward()
    assert q.grad is not None and torch.isfinite(q.grad.float()).all()
