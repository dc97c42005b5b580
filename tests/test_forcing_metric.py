"""PUMA's forcing resolved through the avoidance metric (``method.forcing.mode: metric``) and the
execution energy (``method.energy: execution``): properties of the maths, on the iiwa's real
kinematics and avoidance fabric, and the behaviour they are for on the point robot."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.episode import run_episode
from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._policy import (
    LinearTaskPrimitive,
    PlanarTask,
    TaskAcceleration,
    pull_through_metric,
    pull_to_joints,
)
from tamedpuma.methods._tamed import (
    ControlRate,
    Forcing,
    PumaController,
    geometry_with_task_metric,
)
from tamedpuma.methods.cpm import CpmController
from tamedpuma.methods.fpm import FpmController
from tamedpuma.worlds.pointmass import PointKinematics, PointMassWorld, point_scenario, point_spec

OBSTACLES = (np.array([[0.5, -0.3, 0.5], [0.3, 0.35, 0.3]]), np.array([0.05, 0.08]),
             np.zeros((2, 3)))
Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])


def _task(kinematics, q, qd, rng):
    state = kinematics.evaluate(q, qd)
    return state, TaskAcceleration(rng.normal(size=6), state.ee_jacobian, state.ee_jdqd)


def test_in_free_space_the_metric_forcing_realises_puma_as_the_damped_inverse_does(kinematics):
    """M_a = m_b I: q̈_C = (m_b I + wJᵀJ)⁻¹ wJᵀ(ẍ_d − J̇q̇) is the damped least-squares inverse
    with λ² = m_b/w, and J q̈_C → ẍ_d − J̇q̇ as w grows."""
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = Q0 + rng.normal(scale=0.3, size=7)
        _, task = _task(kinematics, q, rng.normal(size=7), rng)
        M_a = 0.2 * np.eye(7)
        for w in (20.0, 2.0e4):
            qdd = pull_through_metric(task, M_a, w, 0.0)
            assert np.allclose(qdd, pull_to_joints(task, np.sqrt(0.2 / w)), atol=1e-10)
        residual = task.J @ qdd - (task.xdd - task.jdqd)
        assert np.linalg.norm(residual) < 1e-3 * np.linalg.norm(task.xdd - task.jdqd)


def test_a_large_barrier_metric_suppresses_pumas_push_along_its_normal(kinematics):
    """A barrier metric μ n nᵀ along a joint-space direction n: the component of q̈_C along n
    falls like 1/μ while the additive pullback keeps pushing along n."""
    rng = np.random.default_rng(1)
    q = Q0 + rng.normal(scale=0.2, size=7)
    _, task = _task(kinematics, q, np.zeros(7), rng)
    free = pull_to_joints(task, 0.01)
    n = free / np.linalg.norm(free)  # the direction PUMA pushes in
    along = []
    for mu in (1e1, 1e3, 1e5):
        M_a = 0.2 * np.eye(7) + mu * np.outer(n, n)
        qdd = pull_through_metric(task, M_a, 20.0, 0.0)
        along.append(abs(n @ qdd))
    assert along[0] > 10 * along[1] > 100 * along[2] > 0
    assert abs(n @ free) > 1e3 * along[2]


def test_fabric_energization_keeps_h_le(kinematics):
    """FPM's and CPM's energization: α conserves H_{L_e}, q̇ᵀ(M(a − αq̇) + f_L) = 0 (ε = 0)."""
    fab = Fabric(FabricGains(), kinematics.spec.q_min, kinematics.spec.q_max)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, qd = Q0 + rng.normal(scale=0.1, size=7), rng.normal(size=7)
        av = fab.avoidance(kinematics.evaluate(q, qd), q, qd, *OBSTACLES)
        a = rng.normal(size=7)
        alpha = av.alpha(qd, a, 0.0)
        assert abs(qd @ (av.M @ (a - alpha * qd)) + qd @ av.f_energy) < 1e-9 * abs(
            qd @ av.M @ qd) * np.linalg.norm(a)


def test_the_geometry_with_the_task_metric_is_the_spec_sum_and_leaves_the_hand_to_puma(
        kinematics):
    """``forcing.mode: task_metric``: h = −(M + JᵀwJ)⁻¹f is the avoidance spec (M, f) summed
    with the task leaf (JᵀwJ, 0) (ẍ = 0, metric w); w → 0 gives the fabric's h = −M⁻¹f, and as w
    grows the geometry's hand acceleration J h falls like 1/w while h tends to the fabric
    restricted to the joints the hand leaves free (the null space of J)."""
    fab = Fabric(FabricGains(), kinematics.spec.q_min, kinematics.spec.q_max)
    rng = np.random.default_rng(7)
    for _ in range(4):
        q, qd = Q0 + rng.normal(scale=0.2, size=7), rng.normal(size=7)
        state = kinematics.evaluate(q, qd)
        av = fab.avoidance(state, q, qd, *OBSTACLES)
        J = state.ee_jacobian
        h0 = av.acceleration()
        assert np.allclose(geometry_with_task_metric(av, J, 1e-12), h0, rtol=0,
                           atol=1e-9 * np.linalg.norm(h0))
        h = geometry_with_task_metric(av, J, 30.0)
        assert np.allclose((av.M + 30.0 * J.T @ J) @ h, -av.f, atol=1e-9)  # the spec sum
        hand = [np.linalg.norm(J @ geometry_with_task_metric(av, J, w)) for w in (1e2, 1e4)]
        assert hand[1] < 2e-2 * hand[0]
        Z = np.linalg.svd(J)[2][J.shape[0]:].T  # a basis of the joints the hand leaves free
        limit = Z @ np.linalg.solve(Z.T @ av.M @ Z, -Z.T @ av.f)  # the fabric there (w → ∞)
        err = [np.linalg.norm(geometry_with_task_metric(av, J, w) - limit) for w in (1e6, 1e8)]
        assert err[1] < 0.05 * err[0] + 1e-5 * np.linalg.norm(limit)  # falls like 1/w
        w_rows = np.array([50.0, 50.0, 50.0, 5.0, 5.0, 5.0])  # per-row weights
        hw = geometry_with_task_metric(av, J, w_rows)
        assert np.allclose((av.M + J.T @ (w_rows[:, None] * J)) @ hw, -av.f, atol=1e-9)


@pytest.mark.parametrize("bad", [{"mode": "sum"}, {"weight": 100.0}, {"stall_pull": -1.0},
                                 {"wieght": 3.0}, {"priority": "position"},
                                 {"configuration_pull": "sometimes"}])
def test_bad_forcing_settings_are_refused(bad):
    with pytest.raises(ConfigError, match="method.forcing"):
        Forcing.from_mapping(bad)


SPEC = point_spec(speed_limit=50.0)


@pytest.mark.parametrize("name", ["fpm", "cpm"])
def test_point_robot_reaches_the_goal_around_the_obstacle_with_metric_forcing(
        name, point_scale_forcing):
    """The behaviour the option is for, on the point robot (obstacle between start and goal):
    no collision, goal reached, for both methods."""
    kin = PointKinematics(SPEC)
    puma = PumaController(PlanarTask(LinearTaskPrimitive(1.0, 2.0)), kin)
    fabric = Fabric(FabricGains.from_mapping(None), SPEC.q_min, SPEC.q_max)
    forcing = Forcing(mode="metric")
    if name == "fpm":
        ctrl = FpmController(puma, fabric, forcing=forcing)
    else:
        ctrl = CpmController(puma, fabric, beta=8.0, eps=1e-6, variant="paper",
                             regulator_scale=1.0, potential_scale=1.0, damping="matched",
                             rate=ControlRate(semi_implicit=True), forcing=forcing)
    sc = point_scenario(obstacles=True, max_steps=1500, dt=0.02)
    run = run_episode(sc, ctrl, PointMassWorld(SPEC))
    m = run.metrics
    assert m.success_paper and m.success_whole_body, (m.failure_paper, m.final_position_error_m)
    assert m.min_clearance_m > 0


def test_directional_forcing_lets_a_joint_at_its_limit_leave_it_and_still_holds_a_push_in(
        kinematics):
    """Joint 2 resting at its lower limit barrier (sagging towards it: the limit's metric is on,
    2k/x² ~ 10⁵): the full metric holds PUMA's pull away from the limit as firmly as a push into
    it; the directional one leaves the receding row out, so the joint leaves, and still holds
    the push into the limit. Without any receding row both metrics are M."""
    from tamedpuma.methods._tamed import approached_metric

    fab = Fabric(FabricGains(), kinematics.spec.q_min, kinematics.spec.q_max)
    q, qd = Q0.copy(), np.zeros(7)
    q[2] = kinematics.spec.q_min[2] + 1e-4
    qd[2] = -1e-3
    state = kinematics.evaluate(q, qd)
    av = fab.avoidance(state, q, qd, *OBSTACLES)
    J = state.ee_jacobian
    for sign in (1.0, -1.0):
        a = np.zeros(7)
        a[2] = sign  # PUMA's free acceleration: joint 2 away from (+) or into (−) its limit
        task = TaskAcceleration(J @ a + state.ee_jdqd, J, state.ee_jdqd)
        free = pull_to_joints(task, 0.01)
        assert np.sign(free[2]) == sign
        full = pull_through_metric(task, av.M.copy(), 100.0, 0.0)
        directional = pull_through_metric(task, approached_metric(av, free), 100.0, 0.0)
        assert abs(full[2]) < 1e-3 * abs(free[2])
        if sign > 0:
            assert directional[2] > 0.3 * free[2]
        else:
            assert abs(directional[2]) < 1e-3 * abs(free[2])
    away = np.zeros(7)
    assert np.array_equal(approached_metric(av, away), av.M)


@pytest.mark.parametrize("ground", [False, True])
def test_the_barrier_rows_metrics_and_rates_rebuild_the_fabric(kinematics, ground):
    """``M = m_b I + Σ_r m_r a_r a_rᵀ`` over the barrier rows the fabric reports, and each row's
    rate splits into ``a_r·q̇`` plus the drift of a moving obstacle (0 for static rows)."""
    gains = FabricGains(ground_enabled=ground)
    fab = Fabric(gains, kinematics.spec.q_min, kinematics.spec.q_max)
    rng = np.random.default_rng(4)
    centers, radii, _ = OBSTACLES
    velocities = np.array([[0.0, 0.3, 0.0], [0.0, 0.0, 0.0]])
    for _ in range(3):
        q, qd = Q0 + rng.normal(scale=0.2, size=7), rng.normal(size=7)
        av = fab.avoidance(kinematics.evaluate(q, qd), q, qd, centers, radii, velocities)
        rows, m = av.barrier_rows, av.barrier_metric
        M = gains.base_metric * np.eye(7) + (rows.T * m) @ rows
        assert np.allclose(M, av.M, rtol=1e-12, atol=1e-12 * np.abs(av.M).max())
        drift = av.barrier_xd - rows @ qd
        k, n_obs = kinematics.spec.sphere_radii.shape[0], len(radii)
        pairs = drift[:k * n_obs].reshape(k, n_obs)
        assert np.allclose(drift[k * n_obs:], 0.0, atol=1e-12)  # joint limits (and ground)
        assert np.allclose(pairs[:, 1], 0.0, atol=1e-12)  # the static obstacle
        assert np.all(np.abs(pairs[:, 0]) > 0)  # the moving one


def _rows(rho: float) -> np.ndarray:
    """The per-row task metric diag(w, w, w, ρw, ρw, ρw) with w = 100."""
    return np.array([1.0, 1.0, 1.0, rho, rho, rho]) * 100.0


def test_per_row_task_weights_give_the_position_rows_priority_where_barriers_hold_joints(
        kinematics):
    """:func:`pull_through_metric` with a per-row task metric diag(w, w, w, ρw, ρw, ρw). In free
    space (7 joints for 6 rows) q̈_C realises ẍ_d for any ρ; with two joints held by large
    barrier metrics (5 joints left for 6 rows) the position residual shrinks as ρ falls, and it
    is the weighted least-squares solution (the normal equations hold)."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = Q0 + rng.normal(scale=0.3, size=7)
        _, task = _task(kinematics, q, rng.normal(size=7), rng)
        target = task.xdd - task.jdqd
        free = [pull_through_metric(task, 1e-6 * np.eye(7), _rows(rho), 0.0)
                for rho in (1.0, 0.01)]
        for qdd in free:
            assert np.linalg.norm(task.J @ qdd - target) < 1e-5 * np.linalg.norm(target)
        held = 1e-6 * np.eye(7)
        held[[1, 4], [1, 4]] = 1e8  # joints 2 and 5 at their limit barriers
        residual = []
        for rho in (1.0, 0.1, 0.01):
            w = _rows(rho)
            qdd = pull_through_metric(task, held, w, 0.0)
            gradient = held @ qdd - task.J.T @ (w * (target - task.J @ qdd))
            assert np.linalg.norm(gradient) < 1e-6 * np.linalg.norm(task.J.T @ (w * target))
            residual.append(np.linalg.norm((task.J @ qdd - target)[:3]))
        assert residual[0] > residual[1] > residual[2]



def _pull_through_metric_as_written(task, W, weight, m_null, qdd_null):
    """pull_through_metric as first written (np.linalg.solve, broadcast weights): the
    reference the streamlined path must match bit for bit."""
    J = task.J
    wJ = np.multiply(np.reshape(weight, (-1, 1)), J)
    A = W + J.T @ wJ
    rhs = wJ.T @ (task.xdd - task.jdqd)
    if qdd_null is not None and m_null > 0.0:
        A.flat[::A.shape[0] + 1] += m_null
        rhs = rhs + m_null * qdd_null
    return np.linalg.solve(A, rhs)


def test_the_pullback_through_the_metric_is_bit_for_bit_the_written_one(kinematics):
    """The control loop's pullback (LAPACK's gesv without numpy's wrapper, no per-call weight
    array) gives the same numbers, bit for bit, as the formulas written out with
    np.linalg.solve, on arm states with barrier-sized metrics, scalar and per-row weights."""
    rng = np.random.default_rng(11)
    for i in range(200):
        q = Q0 + rng.normal(scale=0.4, size=7)
        _, task = _task(kinematics, q, rng.normal(scale=0.5, size=7), rng)
        rows = rng.normal(size=(4, 7))
        W = 0.02 * np.eye(7) + (rows.T * 10.0 ** rng.uniform(-2, 5, size=4)) @ rows
        weight = 100.0 if i % 2 else np.array([100.0] * 3 + [30.0] * 3)
        null = rng.normal(size=7) if i % 3 else None
        fast = pull_through_metric(task, W, weight, 0.05, null)
        ref = _pull_through_metric_as_written(task, W.copy(), weight, 0.05, null)
        np.testing.assert_array_equal(fast, ref)


def _approach_cases(kinematics, n=200, seed=3):
    """Random iiwa states with joints near their limits (limit rows on) and random PUMA task
    accelerations: (av, task, q̈_P) per case."""
    fab = Fabric(FabricGains(), kinematics.spec.q_min, kinematics.spec.q_max)
    lo, hi = kinematics.spec.q_min, kinematics.spec.q_max
    rng = np.random.default_rng(seed)
    for _ in range(n):
        q = rng.uniform(lo + 0.02, hi - 0.02)
        near = rng.random(7) < 0.4  # these joints within 0.3 rad of a limit, moving towards it
        side = rng.random(7) < 0.5
        q[near & side] = (lo + rng.uniform(0.02, 0.3, 7))[near & side]
        q[near & ~side] = (hi - rng.uniform(0.02, 0.3, 7))[near & ~side]
        qd = rng.normal(scale=0.3, size=7)
        qd[near & side] = -np.abs(qd[near & side])
        qd[near & ~side] = np.abs(qd[near & ~side])
        state = kinematics.evaluate(q, qd)
        av = fab.avoidance(state, q, qd, *OBSTACLES)
        task = TaskAcceleration(rng.normal(size=6), state.ee_jacobian, state.ee_jdqd)
        yield av, task, pull_to_joints(task, 0.01)


def test_the_directional_metric_leaves_out_no_barrier_the_forcing_approaches(kinematics):
    """Rows left out because PUMA's free pull q̈_P recedes from them are put back wherever the
    weighted solution q̈_C approaches them. Over random states near the joint limits: q̈_C
    approaches no row still left out, the rows left out are a subset of the receding ones, and
    q̈_C is the weighted solve through M without exactly those rows; where the first solve
    approaches none of them it is kept to the bit. And the restore is needed: the first solve
    (decided on q̈_P alone) approaches a left-out row in some of the cases."""
    from tamedpuma.methods._tamed import metric_without, receding_rows, restore_approached

    pulled_into, changed = 0, 0
    for av, task, free in _approach_cases(kinematics):
        def solve(W, task=task):
            return pull_through_metric(task, W, 100.0, 0.05)

        receding = receding_rows(av, free)
        W = metric_without(av, receding)
        by_pull = solve(W)
        got, out = restore_approached(av, receding, W, by_pull, solve)
        rows = av.barrier_rows
        assert not np.any(out & (rows @ got < 0.0))
        assert not np.any(out & ~receding)
        np.testing.assert_allclose(got, solve(metric_without(av, out)), rtol=1e-9, atol=1e-9)
        if np.any(receding & (rows @ by_pull < 0.0)):
            pulled_into += 1
            changed += not np.array_equal(got, by_pull)
        else:
            assert np.array_equal(got, by_pull)
    assert pulled_into >= 5 and changed == pulled_into
