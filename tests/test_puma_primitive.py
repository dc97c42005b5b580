"""Inference API: ψ gradients against finite differences, numpy fast path against torch."""

import numpy as np
import pytest
import torch

from tamedpuma.errors import CheckpointError
from tamedpuma.puma import checkpoint, manifold, network
from tamedpuma.puma.network import NetConfig, PumaNet, StateSpec
from tamedpuma.puma.primitive import PosePrimitive, VectorPrimitive, wrap
from tamedpuma.puma.training import Workspace
from tamedpuma.robot import rotations

RNG = np.random.default_rng(1)
GP = np.array([0.58, -0.214, 0.115])
GQ = np.array([-0.5459, 0.5806, -0.4112, 0.4426]) / np.linalg.norm([-0.5459, 0.5806, -0.4112,
                                                                      0.4426])


def _meta(n):
    return checkpoint.Meta(0.03, "final_pose", {}, "m",
                           Workspace((-0.3,) * n, (0.3,) * n, 1.0), {}, "", "", {})


@pytest.fixture(scope="module")
def pose():
    torch.manual_seed(0)
    net = PumaNet(StateSpec(3, True, 2), NetConfig(32, 16), [0.5, 0.7, 0.6],
                  [0.2] * 3 + [1.0] * 3, [1.0] * 3 + [5.0] * 3)
    return wrap(net, _meta(3))


def _random_pose():
    q = rotations.quat_mul(manifold.np_quat_exp(RNG.normal(size=3) * 0.6), GQ)
    return GP + RNG.normal(size=3) * 0.2, q


def test_goal_is_an_equilibrium(pose):
    a, alpha = pose.acceleration(GP, GQ, np.zeros(3), np.zeros(3), GP, GQ)
    np.testing.assert_allclose(a, 0, atol=1e-12)
    np.testing.assert_allclose(alpha, 0, atol=1e-12)
    psi, gp, gt = pose.potential(GP, -GQ, GP, GQ)  # -q is the same rotation
    assert psi < 1e-20 and np.abs(gp).max() < 1e-9


def test_potential_gradient_matches_finite_differences(pose):
    h = 1e-6
    for _ in range(5):
        p, q = _random_pose()
        psi, gp, gt = pose.potential(p, q, GP, GQ)
        for k in range(3):
            d = np.zeros(3)
            d[k] = h
            fd_p = (pose.potential(p + d, q, GP, GQ)[0] - pose.potential(p - d, q, GP, GQ)[0]) / (
                2 * h)
            qp = rotations.quat_mul(manifold.np_quat_exp(d), q)  # world-frame rotation
            qm = rotations.quat_mul(manifold.np_quat_exp(-d), q)
            fd_t = (pose.potential(p, qp, GP, GQ)[0] - pose.potential(p, qm, GP, GQ)[0]) / (2 * h)
            assert fd_p == pytest.approx(gp[k], rel=1e-5, abs=1e-7)
            assert fd_t == pytest.approx(gt[k], rel=1e-5, abs=1e-7)


def test_numpy_fast_path_matches_torch(pose):
    net = pose.net
    p, q = _random_pose()
    v, w = RNG.normal(size=3) * 0.1, RNG.normal(size=3) * 0.3
    a, alpha = pose.acceleration(p, q, v, w, GP, GQ)
    qrel = rotations.quat_mul(q, rotations.quat_conj(GQ))
    t = lambda x: torch.tensor(np.atleast_2d(x), dtype=torch.float32)  # noqa: E731
    with torch.no_grad():
        ref = net(t(p - GP), t(qrel), t(np.concatenate((v, w)))).numpy()[0]
    np.testing.assert_allclose(np.concatenate((a, alpha)), ref, rtol=1e-4, atol=1e-5)
    psi, gp, gt = network.potential(net, t(p - GP), t(qrel))
    psi2, gp2, gt2 = pose.potential(p, q, GP, GQ)
    np.testing.assert_allclose(psi2, psi.item(), rtol=1e-4)
    np.testing.assert_allclose(gp2, gp[0].numpy(), rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(gt2, gt[0].numpy(), rtol=1e-3, atol=1e-5)


def test_batched_equals_single(pose):
    ps, qs = zip(*[_random_pose() for _ in range(4)])
    v = RNG.normal(size=(4, 3)) * 0.1
    w = RNG.normal(size=(4, 3)) * 0.1
    a, alpha = pose.acceleration_batch(np.array(ps), np.array(qs), v, w, GP, GQ)
    for i in range(4):
        ai, al = pose.acceleration(ps[i], qs[i], v[i], w[i], GP, GQ)
        np.testing.assert_allclose(a[i], ai, atol=1e-12)
        np.testing.assert_allclose(alpha[i], al, atol=1e-12)


@pytest.mark.parametrize("order", [1, 2])
def test_vector_primitive(order):
    torch.manual_seed(0)
    net = PumaNet(StateSpec(2, False, order), NetConfig(16, 8), [1.0, 1.0], [1.0, 1.0], [1.0, 1.0])
    prim = wrap(net, _meta(2))
    assert isinstance(prim, VectorPrimitive)
    x, goal = np.array([0.3, -0.2]), np.array([0.1, 0.1])
    if order == 1:
        assert prim.velocity(goal, goal) == pytest.approx([0, 0], abs=1e-12)
        assert prim.velocity(np.stack([x, x]), goal).shape == (2, 2)
        with pytest.raises(CheckpointError):
            prim.acceleration(x, x)
    else:
        assert prim.acceleration(goal, np.zeros(2), goal) == pytest.approx([0, 0], abs=1e-12)
        with pytest.raises(CheckpointError):
            prim.velocity(x)
    psi, g = prim.potential(x, goal)
    h = 1e-6
    fd = [(prim.potential(x + h * e, goal)[0] - prim.potential(x - h * e, goal)[0]) / (2 * h)
          for e in np.eye(2)]
    np.testing.assert_allclose(fd, g, rtol=1e-5, atol=1e-8)


def test_pose_primitive_rests_at_its_goal(pose):
    """Pinned goal: at rest on the goal the acceleration and the potential vanish."""
    assert isinstance(pose, PosePrimitive)
    a, alpha = pose.acceleration(GP, GQ, np.zeros(3), np.zeros(3), GP, GQ)
    np.testing.assert_allclose(a, 0.0, atol=1e-9)
    np.testing.assert_allclose(alpha, 0.0, atol=1e-9)
    assert pose.potential(GP, GQ, GP, GQ)[0] == pytest.approx(0.0, abs=1e-12)
