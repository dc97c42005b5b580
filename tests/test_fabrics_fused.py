"""The fused hot path (tamedpuma.fabrics.fused) against the readable leaf-by-leaf reference:
same metric, forces, energy, counts and acceleration; reused buffers never leak between calls."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.fabrics import Fabric, FabricGains, pull_rows, quaternion_to_rotation
from tamedpuma.fabrics.energy import barrier_leaf, energization_coefficient
from tamedpuma.fabrics.fused import integer_powers, kernel_constants
from tamedpuma.fabrics.leaves import (
    ground_plane,
    joint_limits,
    pull_sphere_pairs,
    sphere_obstacle_pairs,
)
from tamedpuma.fabrics.spec import solve_acceleration
from tamedpuma.fabrics.speed import speed_control

Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])
GOAL_P = np.array([0.58, -0.214, 0.115])
GOAL_R = quaternion_to_rotation([-0.5459, 0.5806, -0.4112, 0.4426])


def _obstacles(rng, n, state=None):
    centers = rng.uniform([-0.8, -0.8, 0.0], [0.8, 0.8, 1.2], size=(n, 3))
    if state is not None and n:  # one obstacle inside a body sphere: a clamped pair
        centers[0] = state.sphere_centers[2] + 0.01
    return centers, rng.uniform(0.02, 0.1, size=n), rng.normal(scale=0.3, size=(n, 3))


def _reference_avoidance(fab, st, q, qd, obs):
    """(M, f, f_L, H, min clearance, n_clamped, n_limit_clamped) leaf by leaf."""
    g = fab.gains
    n = q.shape[0]
    pairs = sphere_obstacle_pairs(st.sphere_centers, st.sphere_jacobians, st.sphere_jdqd,
                                  st.sphere_radii, qd, *obs, g.barrier_margin)
    m, f, fl, H = barrier_leaf(pairs.x, pairs.xd, g.obstacle, g.obstacle_activation)
    M, F = pull_sphere_pairs(m, f + m * pairs.jdqd, fl + m * pairs.jdqd, pairs.u,
                             st.sphere_jacobians)
    energy = H.sum() + 0.5 * g.base_metric * qd @ qd
    M = M + g.base_metric * np.eye(n)
    lim = joint_limits(q, qd, fab.q_min, fab.q_max, g.barrier_margin)
    ml, fl_, fll, Hl = barrier_leaf(lim.x, lim.xd, g.joint_limit)
    rows = np.vstack([np.eye(n), -np.eye(n)])
    Ml, f_lim = pull_rows(ml, fl_, rows)
    M, f, f_e = M + Ml, F[0] + f_lim, F[1] + rows.T @ fll
    energy += Hl.sum()
    n_clamped = pairs.n_clamped
    if g.ground_enabled:
        gr = ground_plane(st.sphere_centers, st.sphere_jacobians, st.sphere_jdqd,
                          st.sphere_radii, qd, g.ground_height, g.barrier_margin)
        mg, fg, flg, Hg = barrier_leaf(gr.x, gr.xd, g.ground)
        Mg, f_g = pull_rows(mg, fg + mg * gr.jdqd, gr.rows)
        M, f, f_e = M + Mg, f + f_g, f_e + gr.rows.T @ (flg + mg * gr.jdqd)
        energy += Hg.sum()
        n_clamped += gr.n_clamped
    clearance = pairs.clearance.min() if pairs.clearance.size else np.inf
    return M, f, f_e, energy, clearance, n_clamped, lim.n_clamped


@pytest.mark.parametrize("changes", [
    {}, {"ground_enabled": True, "ground_height": 0.3},
    {"orientation_axes": (0, 2), "orientation_weight": 2.0, "goal_weight": 1.5},
    {"orientation_weight": 0.0},
    {"obstacle_activation": 3.0},
])
def test_fused_avoidance_and_evaluate_match_the_leaf_by_leaf_reference(kinematics, changes):
    gains = FabricGains(**changes)
    spec = kinematics.spec
    fab = Fabric(gains, spec.q_min, spec.q_max)
    rng = np.random.default_rng(11)
    for n_obs, q_shift in ((0, 0.0), (1, 0.0), (3, 0.0), (40, 0.0), (3, 10.0)):
        q = Q0 + rng.normal(scale=0.2, size=7)
        q[1] += q_shift  # far past a limit: clamped limit distances
        qd = rng.normal(size=7)
        st = kinematics.evaluate(q, qd)
        obs = _obstacles(rng, n_obs, st)
        M, f, f_e, energy, clearance, n_clamped, n_limit = _reference_avoidance(
            fab, st, q, qd, obs)
        av = fab.avoidance(st, q, qd, *obs)
        np.testing.assert_allclose(av.M, M, rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose(av.f, f, rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose(av.f_energy, f_e, rtol=1e-11, atol=1e-11)
        assert av.energy == pytest.approx(energy, rel=1e-12)
        assert av.min_clearance == pytest.approx(clearance, rel=1e-12)
        assert (av.n_clamped, av.n_limit_clamped) == (n_clamped, n_limit)
        assert (n_obs == 0 or n_clamped >= 1) and (q_shift == 0 or n_limit >= 1)
        # the full evaluation = avoidance + forcing + energization + speed control
        qdd, diag = fab.evaluate(st, q, qd, *obs, GOAL_P, GOAL_R)
        fo = fab.forcing(st, qd, GOAL_P, GOAL_R)
        qdd_g = solve_acceleration(av.M, av.f)
        qdd_f = solve_acceleration(av.M + fo.M, av.f + fo.f)
        alpha_g = energization_coefficient(qd, av.M, av.f_energy, qdd_g, gains.energization_eps)
        ref, sp = speed_control(qd, qdd_g, qdd_f, alpha_g, fo.goal_distance, gains)
        np.testing.assert_allclose(qdd, ref, rtol=1e-9, atol=1e-9)
        assert diag.alpha_geometry == pytest.approx(alpha_g, rel=1e-9, abs=1e-12)
        assert diag.beta == pytest.approx(sp.beta, rel=1e-9)
        assert diag.potential == pytest.approx(fo.potential, rel=1e-12)
        assert diag.energy_fabric == pytest.approx(energy, rel=1e-12)
        assert diag.goal_distance == pytest.approx(fo.goal_distance, rel=1e-12)
        assert diag.orientation_error == pytest.approx(fo.orientation_error, rel=1e-12)
        assert (diag.n_clamped, diag.n_limit_clamped) == (n_clamped, n_limit)


def test_reused_buffers_do_not_leak_between_calls_or_into_results(kinematics):
    """Alternating layouts and states gives what a fresh Fabric gives; results stay intact."""
    spec = kinematics.spec
    fab = Fabric(FabricGains(), spec.q_min, spec.q_max)
    rng = np.random.default_rng(12)
    cases = []
    for n_obs in (2, 5, 2, 0, 5):
        q, qd = Q0 + rng.normal(scale=0.1, size=7), rng.normal(size=7)
        cases.append((kinematics.evaluate(q, qd), q, qd, _obstacles(rng, n_obs)))
    kept = [(fab.avoidance(st, q, qd, *obs), fab.evaluate(st, q, qd, *obs, GOAL_P, GOAL_R))
            for st, q, qd, obs in cases]
    kept_copies = [(av.M.copy(), av.forces.copy(), qdd.copy()) for av, (qdd, _) in kept]
    for (st, q, qd, obs), (M, _, qdd) in zip(cases, kept_copies):
        fresh = Fabric(FabricGains(), spec.q_min, spec.q_max)
        np.testing.assert_array_equal(fresh.avoidance(st, q, qd, *obs).M, M)
        np.testing.assert_array_equal(fresh.evaluate(st, q, qd, *obs, GOAL_P, GOAL_R)[0], qdd)
    for (av, (qdd, _)), (M, forces, qdd_copy) in zip(kept, kept_copies):
        np.testing.assert_array_equal(av.M, M)
        np.testing.assert_array_equal(av.forces, forces)
        np.testing.assert_array_equal(qdd, qdd_copy)


def test_kinematic_states_own_their_arrays(kinematics):
    """A later evaluate (pinocchio reuses its data) never changes an earlier state."""
    st = kinematics.evaluate(Q0, np.full(7, 0.3))
    before = {name: np.array(getattr(st, name)) for name in st.__dataclass_fields__}
    for i in range(5):
        kinematics.evaluate(Q0 + 0.1 * i, np.full(7, -0.2 * i))
    for name, value in before.items():
        np.testing.assert_array_equal(getattr(st, name), value)


@pytest.mark.parametrize("changes", [{}, {"ground_enabled": True, "ground_height": 0.3},
                                     {"obstacle": {"energy_exponent": 1.5}},
                                     {"obstacle_activation": 3.0}])
def test_many_pairs_path_matches_the_leaf_by_leaf_reference(kinematics, changes):
    """Above 256 rows the products are split by block and the pair powers x^{−p} are products
    of 1/x (integer exponents; np.power otherwise): the same metric, forces and energy."""
    gains = FabricGains.from_mapping(changes)
    spec = kinematics.spec
    fab = Fabric(gains, spec.q_min, spec.q_max)
    rng = np.random.default_rng(13)
    for n_obs in (60, 400):
        q, qd = Q0 + rng.normal(scale=0.2, size=7), rng.normal(size=7)
        st = kinematics.evaluate(q, qd)
        obs = _obstacles(rng, n_obs, st)
        M, f, f_e, energy, clearance, n_clamped, n_limit = _reference_avoidance(
            fab, st, q, qd, obs)
        buffers = fab.buffers()
        av = fab.avoidance(st, q, qd, *obs, buffers)
        assert buffers.layout(st.sphere_centers.shape[0], n_obs).split
        np.testing.assert_allclose(av.M, M, rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose(av.f, f, rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose(av.f_energy, f_e, rtol=1e-11, atol=1e-11)
        assert av.energy == pytest.approx(energy, rel=1e-12)
        assert (av.n_clamped, av.n_limit_clamped) == (n_clamped, n_limit)
        # barrier rows (the pairs below x_a, then limits): Jacobian rows, so rows · q̇ = ẋ of
        # each barrier; the pairs at or beyond x_a (metric 0) are left out and built on demand
        k, P = st.sphere_centers.shape[0], st.sphere_centers.shape[0] * n_obs
        pairs = sphere_obstacle_pairs(st.sphere_centers, st.sphere_jacobians, st.sphere_jdqd,
                                      st.sphere_radii, qd, *obs, gains.barrier_margin)
        far = pairs.x.reshape(-1) >= gains.obstacle_activation
        near = np.flatnonzero(~far)
        Pa = near.size
        assert (Pa < P) == bool(far.any()) == (av.far_rows is not None)
        assert av.barrier_rows.shape == (Pa + 14 + (k if gains.ground_enabled else 0), 7)
        v_obs = np.tile(obs[2], (k, 1))  # pair (i, j) ↦ row i·m + j: obstacle j's velocity
        u = pairs.u.reshape(3, -1).T
        drift = -np.einsum("pd,pd->p", u, v_obs)
        np.testing.assert_allclose(av.barrier_rows[:Pa] @ qd + drift[near],
                                   pairs.xd.reshape(-1)[near], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(av.barrier_jdqd[:Pa], pairs.jdqd.reshape(-1)[near],
                                   rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(av.barrier_rows[Pa:Pa + 14] @ qd, np.r_[qd, -qd], atol=1e-15)
        if av.far_rows is not None:
            rows, x, jd, f_drift = av.far_rows.rows()
            np.testing.assert_allclose(x, pairs.x.reshape(-1)[far], rtol=1e-12)
            np.testing.assert_allclose(rows @ qd + f_drift, pairs.xd.reshape(-1)[far],
                                       rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(f_drift, drift[far], rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(jd, pairs.jdqd.reshape(-1)[far], rtol=1e-10, atol=1e-12)
            # every left-out pair's clearance is at least the bound's
            clear = pairs.clearance.reshape(k, -1)
            floor = np.repeat(av.far_rows.clearance[:, None], n_obs, axis=1)
            assert np.all(clear.reshape(-1)[far] >= floor.reshape(-1)[far] * (1 - 1e-12))


def test_kernel_constants_give_the_barrier_leaf_and_integer_powers_only_for_integers():
    """The per-row constants reproduce energy.barrier_leaf on each row block; the pair rows'
    exponents are integers only when every exponent is a small non-negative integer."""
    gains = FabricGains(ground_enabled=True)
    n_pairs, n, n_ground = 4, 3, 2
    negexp, gain, threshold = kernel_constants(gains, n_pairs, n, n_ground)
    rng = np.random.default_rng(3)
    x = rng.uniform(0.05, 2.0, negexp.shape[1])
    xd = rng.normal(size=x.shape)
    w = gain * (xd < threshold) * x ** negexp  # [m, −k_h s_h x^{−p_h}, −p_L/(2x)]
    limits = slice(n_pairs, n_pairs + 2 * n)
    blocks = ((gains.obstacle, slice(0, n_pairs)), (gains.joint_limit, limits),
              (gains.ground, slice(n_pairs + 3 * n, None)))
    for bg, rows in blocks:
        m, f, fl, H = barrier_leaf(x[rows], xd[rows], bg)
        np.testing.assert_allclose(w[0, rows], m, rtol=1e-14)
        np.testing.assert_allclose(m * w[1, rows] * xd[rows] ** 2, f, rtol=1e-13, atol=1e-300)
        np.testing.assert_allclose(m * w[2, rows] * xd[rows] ** 2, fl, rtol=1e-13, atol=1e-300)
    base = slice(n_pairs + 2 * n, n_pairs + 3 * n)  # base rows: m = m_b, no geometry or force
    np.testing.assert_array_equal(w[0, base], gains.base_metric)
    np.testing.assert_array_equal(w[1:, base], 0.0)
    assert integer_powers(negexp, n_pairs) == (
        int(gains.obstacle.energy_exponent), int(gains.obstacle.geometry_exponent), 1)
    assert integer_powers(negexp, 0) is None
    odd = FabricGains.from_mapping({"obstacle": {"energy_exponent": 1.5}})
    assert integer_powers(kernel_constants(odd, n_pairs, n, 0)[0], n_pairs) is None


@pytest.mark.parametrize("where", ["all inside", "all beyond", "mixed"])
def test_taper_branches_match_the_leaf_by_leaf_reference(kinematics, where):
    """The taper's three cases (every pair below x_a, every pair at or beyond it, some of each)
    give the reference's metric, forces and energy, at a few pairs and (gathered) at many."""
    gains = FabricGains(obstacle_activation=50.0 if where == "all inside" else 2.0)
    spec = kinematics.spec
    fab = Fabric(gains, spec.q_min, spec.q_max)
    rng = np.random.default_rng(17)
    q, qd = Q0 + rng.normal(scale=0.1, size=7), rng.normal(size=7)
    st = kinematics.evaluate(q, qd)
    for n_obs in (2, 80):
        radii = np.full(n_obs, 0.05)
        dirs = rng.normal(size=(n_obs, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        dist = {"all inside": rng.uniform(0.2, 1.0, n_obs), "all beyond": rng.uniform(4, 6, n_obs),
                "mixed": rng.uniform(0.12, 0.8, n_obs)}[where]
        centers = st.sphere_centers[0] + dirs * dist[:, None]
        obs = (centers, radii, rng.normal(scale=0.3, size=(n_obs, 3)))
        x = (np.linalg.norm(st.sphere_centers[:, None] - centers[None], axis=-1)
             / (spec.sphere_radii[:, None] + radii) - 1)
        inside = x < gains.obstacle_activation
        assert {"all inside": inside.all(), "all beyond": not inside.any(),
                "mixed": inside.any() and not inside.all()}[where]
        M, f, f_e, energy, _, n_clamped, n_limit = _reference_avoidance(fab, st, q, qd, obs)
        av = fab.avoidance(st, q, qd, *obs)
        np.testing.assert_allclose(av.M, M, rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose(av.f, f, rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose(av.f_energy, f_e, rtol=1e-11, atol=1e-11)
        assert av.energy == pytest.approx(energy, rel=1e-12)
        assert (av.n_clamped, av.n_limit_clamped) == (n_clamped, n_limit)
