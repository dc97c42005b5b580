"""The one-state network path (puma/single.py) against its references: the batched numpy copy
(puma/fastnet.py) and the torch network in float64 (forward pass and autograd ∂ψ), to 1e-10."""

import copy
from pathlib import Path

import numpy as np
import pytest
import torch

from tamedpuma.puma import checkpoint, manifold
from tamedpuma.puma.network import NetConfig, PumaNet, StateSpec
from tamedpuma.puma.primitive import load_primitive, wrap
from tamedpuma.puma.training import Workspace
from tamedpuma.robot import rotations

SHIPPED = Path(__file__).resolve().parents[1] / "tamedpuma" / "puma" / "shipped"
TOL = 1e-10


def _meta(n):
    return checkpoint.Meta(0.03, "final_pose", {}, "m",
                           Workspace((-0.3,) * n, (0.3,) * n, 1.0), {}, "", "", {})


def _random_net(spec, seed=0, skip=1.0, pin_goal=True):
    torch.manual_seed(seed)
    t = spec.tangent_dim
    net = PumaNet(spec, NetConfig(32, 16, pin_goal=pin_goal, skip=skip),
                  np.linspace(0.3, 0.7, spec.n_pos), np.linspace(0.2, 1.0, t),
                  np.linspace(1.0, 5.0, t))
    with torch.no_grad():  # LayerNorm gains/biases away from their (1, 0) initialisation
        for m in net.modules():
            if isinstance(m, torch.nn.LayerNorm):
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.3, 0.3)
    return wrap(net, _meta(spec.n_pos))


@pytest.fixture(scope="module", params=["random", "shipped"])
def pose(request):
    if request.param == "shipped":
        return load_primitive(SHIPPED / "tomato" / "puma.pt")
    return _random_net(StateSpec(3, True, 2))


def _random_state(rng):
    gp = rng.normal(size=3) * 0.3
    gq = rng.normal(size=4)
    gq /= np.linalg.norm(gq)
    p = gp + rng.normal(size=3) * 0.3
    q = rotations.quat_mul(manifold.np_quat_exp(rng.normal(size=3)), gq)
    return p, q * rng.uniform(0.5, 2.0), rng.normal(size=3) * 0.3, rng.normal(size=3), gp, gq


def _both(prim, *calls):
    """The last of ``calls`` ((method name, args), run in order) with the one-state path, then
    with the reference (batched numpy) path."""
    one = prim.single
    try:
        fast = [getattr(prim, name)(*args) for name, args in calls][-1]
        prim.single = None
        ref = [getattr(prim, name)(*args) for name, args in calls][-1]
    finally:
        prim.single = one
    return fast, ref


def _close(a, b, scale=1.0):
    a, b = np.atleast_1d(np.asarray(a, float)), np.atleast_1d(np.asarray(b, float))
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, rtol=TOL, atol=TOL * scale)


def test_pose_single_state_matches_the_batched_reference(pose):
    rng = np.random.default_rng(3)
    for _ in range(30):
        p, q, v, w, gp, gq = _random_state(rng)
        (a1, al1), (a0, al0) = _both(pose, ("acceleration", (p, q, v, w, gp, gq)))
        _close(a1, a0)
        _close(al1, al0)
        # ψ right after the acceleration at the same pose reuses the rest row of that pass
        pot1, pot0 = _both(pose, ("acceleration", (p, q, v, w, gp, gq)),
                           ("potential", (p, q, gp, gq)))
        assert pose.single.want_rest
        for x, y in zip(pot1, pot0):
            _close(x, y, scale=max(1.0, abs(pot0[0])))
        # ψ at another pose than the last acceleration's: a pass of its own
        p2 = p + rng.normal(size=3) * 0.05
        pot1, pot0 = _both(pose, ("acceleration", (p, q, v, w, gp, gq)),
                           ("potential", (p2, q, gp, gq)))
        for x, y in zip(pot1, pot0):
            _close(x, y, scale=max(1.0, abs(pot0[0])))


def _torch64(prim):
    net = copy.deepcopy(prim.net).double()
    goal = [None if x is None else x.double() for x in net.goal_state((1,))]
    return net, goal


def test_pose_single_state_matches_torch_float64_and_autograd(pose):
    net, (g_pos, g_quat, g_vel) = _torch64(pose)
    rng = np.random.default_rng(4)
    t = lambda x: torch.tensor(np.atleast_2d(x), dtype=torch.float64)  # noqa: E731
    with torch.no_grad():
        goal_out = net.decoder(net.encode(g_pos, g_quat, g_vel))
        y_goal = net.encode(g_pos, g_quat)
    for _ in range(20):
        p, q, v, w, gp, gq = _random_state(rng)
        a, alpha = pose.acceleration(p, q, v, w, gp, gq)
        qn, gn = q / np.linalg.norm(q), gq / np.linalg.norm(gq)
        qrel = t(rotations.quat_mul(qn, rotations.quat_conj(gn)))
        with torch.no_grad():
            out = (net.decoder(net.encode(t(p - gp), qrel, t(np.r_[v, w]))) - goal_out)
            ref = (out * net.out_scale).numpy()[0]
        _close(np.r_[a, alpha], ref, scale=np.abs(ref).max())
        pos = t(p - gp).requires_grad_(True)
        dtheta = torch.zeros((1, 3), dtype=torch.float64, requires_grad=True)
        quat = manifold.quat_mul(manifold.quat_exp(dtheta), qrel)
        psi = ((net.encode(pos, quat) - y_goal) ** 2).sum()
        gp_ref, gt_ref = torch.autograd.grad(psi, (pos, dtheta))
        psi1, gp1, gt1 = pose.potential(p, q, gp, gq)
        scale = max(1.0, psi.item())
        _close(psi1, psi.item(), scale)
        _close(gp1, gp_ref.numpy()[0], scale)
        _close(gt1, gt_ref.numpy()[0], scale)


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("skip,pin_goal", [(1.0, True), (0.0, False)])
def test_vector_single_state_matches_the_batched_reference(order, skip, pin_goal):
    prim = _random_net(StateSpec(2, False, order), seed=order, skip=skip, pin_goal=pin_goal)
    rng = np.random.default_rng(5)
    for _ in range(20):
        x, xd, goal = rng.normal(size=2), rng.normal(size=2), rng.normal(size=2)
        if order == 1:
            out1, out0 = _both(prim, ("velocity", (x, goal)))
        else:
            out1, out0 = _both(prim, ("acceleration", (x, xd, goal)))
        _close(out1, out0, scale=np.abs(out0).max())
        (psi1, g1), (psi0, g0) = _both(prim, ("potential", (x, goal)))
        _close(psi1, psi0, max(1.0, psi0))
        _close(g1, g0, max(1.0, psi0))


def test_goal_is_an_equilibrium_on_the_single_state_path(pose):
    gp, gq = np.array([0.5, -0.2, 0.1]), np.array([0.0, 0.0, 0.0, 1.0])
    a, alpha = pose.acceleration(gp, gq, np.zeros(3), np.zeros(3), gp, gq)
    assert np.abs(a).max() < 1e-12 and np.abs(alpha).max() < 1e-12
    psi, dp, dt = pose.potential(gp, -gq, gp, gq)
    assert psi < 1e-20 and np.abs(dp).max() < 1e-9 and np.abs(dt).max() < 1e-9


def test_non_finite_and_degenerate_inputs_propagate_as_nan(pose):
    """No exception where the reference gives NaN (a zero quaternion, a NaN position)."""
    gp, gq = np.array([0.5, -0.2, 0.1]), np.array([0.0, 0.0, 0.0, 1.0])
    for p, q in ((gp, np.zeros(4)), (gp + np.nan, gq)):
        with np.errstate(invalid="ignore", divide="ignore"):
            (a1, _), (a0, _) = _both(pose, ("acceleration", (p, q, np.zeros(3), np.zeros(3),
                                                             gp, gq)))
            (psi1, _, _), (psi0, _, _) = _both(pose, ("potential", (p, q, gp, gq)))
        assert np.isnan(a1).all() and np.isnan(a0).all() and np.isnan(psi1) and np.isnan(psi0)


def test_psi_alone_is_the_potentials_and_leaves_the_step_as_it_was():
    """``psi`` (the log's ψ) equals ``potential``'s ψ on both paths, pose and vector nets,
    after an acceleration at the same pose or another; unlike ``potential`` it does not make
    the next accelerations encode a second row at rest."""
    rng = np.random.default_rng(6)
    pose = _random_net(StateSpec(3, True, 2), seed=7)
    for _ in range(10):
        p, q, v, w, gp, gq = _random_state(rng)
        psi1, psi0 = _both(pose, ("acceleration", (p, q, v, w, gp, gq)), ("psi", (p, q, gp, gq)))
        assert not pose.single.want_rest
        (ref, _, _), _ = _both(pose, ("potential", (p, q, gp, gq)))
        pose.single.want_rest = False
        _close(psi1, ref, max(1.0, ref))
        _close(psi0, ref, max(1.0, ref))
        assert psi1 > 0
    # with the rest row of the last acceleration (a caller that asked for the potential before)
    pose.single.want_rest = True
    p, q, v, w, gp, gq = _random_state(rng)
    psi1, _ = _both(pose, ("acceleration", (p, q, v, w, gp, gq)), ("psi", (p, q, gp, gq)))
    _close(psi1, pose.potential(p, q, gp, gq)[0], max(1.0, psi1))
    for order in (1, 2):
        prim = _random_net(StateSpec(2, False, order), seed=order)
        x, goal = rng.normal(size=2), rng.normal(size=2)
        psi1, psi0 = _both(prim, ("psi", (x, goal)))
        assert not prim.single.want_rest
        ref = prim.potential(x, goal)[0]
        _close(psi1, ref, max(1.0, ref))
        _close(psi0, ref, max(1.0, ref))


@pytest.mark.parametrize("spec", [StateSpec(3, True, 2), StateSpec(2, False, 1),
                                  StateSpec(2, False, 2)], ids=["pose", "vector1", "vector2"])
def test_the_compiled_passes_give_the_numpy_paths_numbers_to_rounding(spec):
    """Where numba is installed the encoder, decoder and backward pass run compiled
    (puma/single_kernels.py); the numpy path is the reference: 1e-12 relative, also for the
    second row at rest (forward after potential) and with the skip part off."""
    from tamedpuma.puma import single_kernels
    from tamedpuma.puma.single import SingleState

    if not single_kernels.AVAILABLE:
        pytest.skip("numba is not installed (the `fast` extra): no compiled path to compare")
    rng = np.random.default_rng(11)
    for skip in (1.0, 0.0):
        prim = _random_net(spec, seed=3, skip=skip)
        fast, plain = prim.single, SingleState(prim.fast, compiled=False)
        assert fast.kernels is not None and plain.kernels is None
        n, t = spec.n_pos, spec.tangent_dim
        for k in range(40):
            e = (rng.normal(size=n) * 0.3).tolist()
            rot = (rotations.exp_so3(rng.normal(size=3)).ravel().tolist()
                   if spec.orientation else None)
            vel = rng.normal(size=t).tolist() if spec.order == 2 else None
            if k % 2:  # the potential first: the forward passes then encode the rest row too
                got, ref = fast.potential(e, rot), plain.potential(e, rot)
                for a, b in zip(got, ref):
                    if b is not None:
                        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
            got, ref = fast.forward(e, rot, vel), plain.forward(e, rot, vel)
            np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
            np.testing.assert_allclose(fast.psi(e, rot), plain.psi(e, rot), rtol=1e-12)



def _packed_and_listed(seed: int, skip: float):
    """Two copies of one random network with their own one-state evaluators (the packed path
    and the listed one to compare it with); skipped without numba (no compiled path)."""
    from tamedpuma.puma import single_kernels

    if not single_kernels.AVAILABLE:
        pytest.skip("numba is not installed (the `fast` extra): no compiled path to compare")
    packed = _random_net(StateSpec(3, True, 2), seed=seed, skip=skip)
    listed = copy.copy(packed)
    listed.single = packed.single.fresh()
    return packed, listed


def test_the_packed_forward_gives_the_listed_paths_numbers():
    """``SingleState.forward_packed`` (one compiled call from the packed state, PoseTask's
    path) gives ``acceleration``'s numbers bit for bit, with and without the rest row, and
    leaves the same rest-row memo for ``potential`` and ``psi``."""
    rng = np.random.default_rng(12)
    for skip in (1.0, 0.0):
        packed, listed = _packed_and_listed(seed=5, skip=skip)
        for k in range(30):
            p, q, v, w, gp, gq = _random_state(rng)
            if k % 3 == 1:  # a potential first: the forward passes encode the rest row too
                packed.potential(p, q, gp, gq)
                listed.potential(p, q, gp, gq)
            got = packed.single.forward_packed(np.concatenate((p, q, gp, gq, v, w)))
            ref = np.concatenate(listed.acceleration(p, q, v, w, gp, gq))
            np.testing.assert_array_equal(got, ref)
            assert packed.single._rest_key == listed.single._rest_key
            if k % 3 == 1:
                for a, b in zip(packed.potential(p, q, gp, gq), listed.potential(p, q, gp, gq)):
                    np.testing.assert_array_equal(a, b)
            assert packed.psi(p, q, gp, gq) == listed.psi(p, q, gp, gq)


def test_the_packed_potential_gives_the_listed_paths_numbers():
    """``SingleState.potential_packed`` (one compiled call, PoseTask's path) gives
    ``potential`` pulled to the joints (``∂ψ/∂p · J_v + ∂ψ/∂θ · J_ω``) bit for bit: at the pose
    of the last forward pass (its rest row reused) and at another pose (encoded afresh)."""
    rng = np.random.default_rng(13)
    for skip in (1.0, 0.0):
        packed, listed = _packed_and_listed(seed=6, skip=skip)
        for k in range(30):
            p, q, v, w, gp, gq = _random_state(rng)
            jac = rng.normal(size=(6, 7))
            for prim in (packed, listed):
                prim.acceleration(p, q, v, w, gp, gq)
            at = (p, q, gp, gq) if k % 2 else _random_state(rng)[:1] + (q, gp, gq)
            psi, grad = packed.single.potential_packed(np.concatenate(at), jac)
            ref, d_p, d_theta = listed.potential(*at)
            assert psi == ref
            np.testing.assert_array_equal(grad, d_p @ jac[:3] + d_theta @ jac[3:])
            assert packed.single.want_rest and packed.single._rest is None
