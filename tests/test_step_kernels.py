"""FPM's and CPM's fused step kernels (tamedpuma/methods/_kernels.py): compiled (numba) and plain
give the same numbers, the plain ones are the numpy functions they fuse, and the barrier step's
fast path keeps exactly the velocities the whole step keeps."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tamedpuma.fabrics.discrete import barrier_step
from tamedpuma.fabrics.spec import FabricError
from tamedpuma.methods import _kernels
from tamedpuma.methods._ground_rows import HullTable
from tamedpuma.methods._ground_rows import hull_ground_rows as fused_ground_rows
from tamedpuma.methods._policy import TaskAcceleration, pull_to_joints
from tamedpuma.methods._tamed import (
    BARRIER_KAPPA,
    BARRIER_STANDOFF,
    Forcing,
    barrier_system,
    forced_reference,
    forced_through_metric,
    free_pull,
    keeps_velocity,
    pulled_through_metric,
)
from tamedpuma.robot import ground
from tamedpuma.robot.ground import GroundRows, link_hulls

N, M_ROWS = 7, 6


def _spd(rng, n=N):
    A = rng.standard_normal((n, n))
    return A @ A.T + 0.2 * np.eye(n)


def _fabric(rng, rows: int):
    """An avoidance fabric's parts (M = m_b I + Σ m_r a_r a_rᵀ, f, barrier rows and metric)."""
    a = rng.standard_normal((rows, N))
    m = np.where(rng.random(rows) < 0.3, 0.0, rng.exponential(5.0, rows))
    M = 0.2 * np.eye(N) + (a.T * m) @ a
    f = rng.standard_normal(N)
    return SimpleNamespace(M=M, f=f, barrier_rows=a, barrier_metric=m,
                           acceleration=lambda: -np.linalg.solve(M, f))


def _case(seed: int):
    rng = np.random.default_rng(seed)
    av = _fabric(rng, int(rng.integers(0, 12)))
    task = TaskAcceleration(rng.standard_normal(M_ROWS), rng.standard_normal((M_ROWS, N)),
                            rng.standard_normal(M_ROWS))
    null = rng.standard_normal(N) if seed % 3 else None
    forcing = Forcing(mode=("metric", "task_metric")[seed % 2], directional=seed % 5 != 0)
    return rng, av, task, null, forcing


def _close(a, b, rel=1e-12):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if b.size == 0:
        return a.shape == b.shape
    return np.all(np.abs(a - b) <= rel * np.maximum(np.abs(b).max(), 1e-300))


@pytest.mark.parametrize("seed", range(40))
def test_the_fused_forcing_is_the_numpy_forcing(seed):
    rng, av, task, null, forcing = _case(seed)
    target = task.xdd - task.jdqd
    qdd_free = free_pull(task, target, 0.01, null)
    assert _close(qdd_free, pull_to_joints(task, 0.01, null))
    got = forced_through_metric(av, task, target, forcing, null, qdd_free)
    want = forced_reference(av, task, forcing, null, qdd_free)
    for g, w in zip(got, want):
        assert _close(g, w)


def _plain_and_compiled(name, *args):
    pytest.importorskip("numba")
    assert _kernels.warm_up()
    kernel = _kernels.STEP[name]
    return kernel.plain(*args), kernel.fast(*args)


@pytest.mark.parametrize("seed", range(40))
def test_compiled_and_plain_kernels_agree_to_rounding(seed):
    rng, av, task, null, forcing = _case(seed)
    target = task.xdd - task.jdqd
    has_null = null is not None
    null = null if has_null else target[:0]
    plain, fast = _plain_and_compiled("damped_pull", task.J, target, 1e-4, null, has_null)
    assert _close(fast, plain)
    args = (av.M, av.f, av.barrier_rows, av.barrier_metric, task.J, 100.0, target, 0.05, null,
            has_null, plain, forcing.directional, forcing.mode == "task_metric")
    plain, fast = _plain_and_compiled("metric_forcing", *args)
    for p, f in zip(plain, fast):
        assert _close(f, p)


@pytest.mark.parametrize("seed", range(40))
@pytest.mark.parametrize("compiled", [False, True])
def test_the_one_call_forcing_is_the_free_pull_then_the_fused_forcing(seed, compiled):
    """pulled_through_metric (q̈_P and the forcing in one kernel call) gives the numbers of
    free_pull then forced_through_metric, bit for bit, plain and compiled (and the compiled
    kernel the plain one's to rounding)."""
    rng, av, task, null, forcing = _case(seed)
    if compiled:
        pytest.importorskip("numba")
        assert _kernels.warm_up()
    kernels = {k: _kernels.Kernel(getattr(_kernels, k)) for k in
               ("pulled_forcing", "damped_pull", "metric_forcing")}
    for name, kernel in kernels.items():
        kernel.fast = _kernels.STEP[name].fast if compiled else None
    with pytest.MonkeyPatch.context() as m:
        for name, kernel in kernels.items():
            m.setitem(_kernels.STEP, name, kernel)
        got = pulled_through_metric(av, task, forcing, null, 0.01)
        target = task.xdd - task.jdqd
        qdd_free = free_pull(task, target, 0.01, null) if forcing.directional else None
        want = forced_through_metric(av, task, target, forcing, null, qdd_free)
    for g, w in zip(got, want):
        assert np.array_equal(g, w)
    for name, kernel in kernels.items():
        assert kernel.demoted is None and (kernel.fast is not None) == compiled, name
    if compiled:
        ref = forced_reference(av, task, forcing, null, qdd_free)
        for g, w in zip(got, ref):
            assert _close(g, w)


def _rows_case(seed: int):
    """A barrier step's inputs: rows near their bound (some past the standoff), a drift on
    some, ground rows on some seeds."""
    rng = np.random.default_rng(1000 + seed)
    rows, x = rng.standard_normal((9, N)), rng.uniform(-0.01, 0.3, 9)
    v = rng.standard_normal(N) * rng.choice([0.01, 0.1, 1.0])
    av = SimpleNamespace(barrier_rows=rows, barrier_x=x, barrier_jdqd=rng.standard_normal(9),
                         barrier_xd=rng.standard_normal(9) if seed % 2 else None,
                         M=_spd(rng), far_rows=None)
    ground = None
    if seed % 3:
        k = int(rng.integers(0, 4))
        ground = GroundRows(rng.uniform(0.0, 0.2, k), rng.standard_normal((k, N)),
                            rng.standard_normal(k))
    return av, ground, v, rng.standard_normal(N) * 0.1


@pytest.mark.parametrize("seed", range(200))
def test_the_fast_path_keeps_exactly_what_the_barrier_step_keeps(seed):
    av, ground, v, qd = _rows_case(seed)
    rows, x, jd, drift = barrier_system(av, ground, qd)
    w, active = barrier_step(v, rows, x, 0.02, BARRIER_KAPPA, av.M, jd, drift, None,
                             BARRIER_STANDOFF)
    assert keeps_velocity(av, ground, v, qd, 0.02) == (w is v and active == 0)


def test_the_cases_cover_both_answers():
    kept = [keeps_velocity(*_rows_case(s)[:3], _rows_case(s)[3], 0.02) for s in range(200)]
    assert 20 < sum(kept) < 180


def test_after_the_warm_up_nothing_compiles_and_new_types_run_plain():
    pytest.importorskip("numba")
    assert _kernels.warm_up()
    kernel = _kernels.Kernel(_kernels.damped_pull)
    kernel.fast = _kernels.STEP["damped_pull"].fast
    before = len(kernel.fast.signatures)
    rng = np.random.default_rng(0)
    J = np.asfortranarray(rng.standard_normal((M_ROWS, N)))  # a layout the warm-up never saw
    t = rng.standard_normal(M_ROWS).astype(np.float32)
    out = kernel(J, t, 1e-4, t[:0], False)
    assert len(_kernels.STEP["damped_pull"].fast.signatures) == before
    assert np.array_equal(out, kernel.plain(J, t, 1e-4, t[:0], False))
    assert kernel.fast is None and "No matching definition" in kernel.demoted  # plain for good


@pytest.mark.parametrize("method", ["fpm", "cpm"])
def test_the_step_passes_the_types_the_warm_up_compiled(method, monkeypatch):
    """FPM's and CPM's steps among obstacles, the obstacles' radii read-only (as the kinematic
    state's and the simulator's are), call every kernel with types the warm-up compiled: none
    is demoted to plain."""
    pytest.importorskip("numba")
    from omegaconf import OmegaConf

    from tamedpuma.app.bench_timing import observation
    from tamedpuma.app.compose import compose_dict
    from tamedpuma.app.sweep import build

    assert _kernels.warm_up()
    for name, fast in _kernels._COMPILED[0].items():  # fresh wrappers: no earlier test's state
        fresh = _kernels.Kernel(getattr(_kernels, name))
        fresh.fast = fast
        monkeypatch.setitem(_kernels.STEP, name, fresh)
    built = build(OmegaConf.create(compose_dict("sweep", [
        "task=tomato", "scenario=random", "scenario.random_seed=2002",
        "scenario.start_kind=anywhere", "recorder=none", f"method={method}"])))
    controller, scenario = built.controller, built.scenario
    controller.reset(scenario)
    q, qd = scenario.q0.copy(), np.zeros_like(scenario.q0)
    for k in range(150):
        obs = observation(scenario, q.copy(), qd.copy(), scenario.obstacles, t=k * scenario.dt,
                          step=k)
        obs.obstacle_radii.flags.writeable = False
        qd = np.clip(qd + controller.step(obs).qdd * scenario.dt, -1.0, 1.0)
        q = q + qd * scenario.dt
    assert not any(k.demoted for k in _kernels.STEP.values()), {
        name: k.demoted for name, k in _kernels.STEP.items() if k.demoted}
    assert all(k.fast is not None for k in _kernels.STEP.values())


def test_without_numba_every_kernel_is_the_plain_function(monkeypatch):
    kernel = _kernels.Kernel(_kernels.damped_pull)  # as STEP's are before any warm-up
    assert kernel.fast is None
    rng = np.random.default_rng(1)
    J, t = rng.standard_normal((M_ROWS, N)), rng.standard_normal(M_ROWS)
    assert np.array_equal(kernel(J, t, 1e-4, t[:0], False),
                          _kernels.damped_pull(J, t, 1e-4, t[:0], False))
    monkeypatch.setattr(_kernels, "AVAILABLE", False)
    monkeypatch.setattr(_kernels, "_COMPILED", [])
    assert _kernels.warm_up() is False


def _evaluated_at_random(kinematics, seed: int, n: int = 100):
    """Yield q̇ after ``kinematics.evaluate`` at each of n random (q, q̇), q within the joint
    limits."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(kinematics.spec.q_min), np.asarray(kinematics.spec.q_max)
    for _ in range(n):
        qd = rng.standard_normal(N)
        kinematics.evaluate(rng.uniform(lo, hi), qd)
        yield qd


@pytest.fixture(scope="module")
def hulls(kinematics):
    return link_hulls(kinematics)


def _per_hull(hulls, below):
    """``below`` as given, or ("per hull") the heights the step uses at a 40 ms period: each
    hull's vertical speed bound × Δt / κ (0 for the first link, which never needs a row)."""
    if below != "per hull":
        return below
    return np.array(hulls.speed_bounds) * 0.04 / 0.5


@pytest.mark.parametrize("below", [np.inf, 0.4, 0.1, "per hull"])
def test_the_fused_ground_rows_are_the_robot_modules(kinematics, hulls, below):
    table = HullTable.of(hulls)
    below = _per_hull(hulls, below)
    found = 0
    for qd in _evaluated_at_random(kinematics, seed=7):
        want = ground.hull_ground_rows(kinematics, hulls, qd, below)
        got = fused_ground_rows(kinematics, table, qd, below)
        found += len(want.heights)
        for g, w in ((got.heights, want.heights), (got.rows, want.rows),
                     (got.jdqd, want.jdqd)):
            assert g.shape == w.shape and _close(g, w)
    assert found > 0


def test_compiled_and_plain_ground_kernels_agree(kinematics, hulls):
    table = HullTable.of(hulls)
    rng = np.random.default_rng(8)
    Rt = np.stack([np.linalg.qr(rng.standard_normal((3, 3)))[0] for _ in table.radii])
    tz = rng.uniform(-0.2, 0.6, len(table.radii))
    below = rng.uniform(0.1, 0.5, len(table.radii))  # one height per hull
    plain, fast = _plain_and_compiled("lowest_points", table.vertices, table.starts, Rt, tz,
                                      table.radii, below)
    assert np.array_equal(plain[0], fast[0]) and plain[0].any()
    for p, f in zip(plain[1:], fast[1:]):
        assert _close(f[plain[0]], p[plain[0]])
    none = np.zeros(len(below), np.bool_)  # no row found: the reach is the least slack
    p, f = _plain_and_compiled("ground_reach", none, plain[1], below, np.linspace(0, 2, len(below)))
    assert p == f and np.isfinite(p) and _kernels.ground_reach(plain[0], plain[1], below,
                                                                np.ones(len(below))) == 0.0
    args = (rng.standard_normal((3, 6, N)), rng.standard_normal((3, 6)),
            rng.standard_normal((3, 3)), rng.standard_normal(N))
    plain, fast = _plain_and_compiled("ground_rows", *args)
    for p, f in zip(plain, fast):
        assert _close(f, p)


def test_a_numba_that_cannot_compile_leaves_the_plain_kernels(monkeypatch):
    def broken():
        raise ImportError("numba built for another numpy")

    fresh = {k.__name__: _kernels.Kernel(k) for k in _kernels.KERNELS}
    monkeypatch.setattr(_kernels, "AVAILABLE", True)
    monkeypatch.setattr(_kernels, "_COMPILED", [])
    monkeypatch.setattr(_kernels, "_compiled", broken)
    monkeypatch.setattr(_kernels, "STEP", fresh)
    with pytest.warns(UserWarning, match="plain numpy"):
        assert _kernels.warm_up() is False
    assert all(k.fast is None for k in fresh.values())
    assert _kernels.warm_up() is False  # once per process: no second attempt, no warning


def test_a_singular_geometry_raises_as_the_numpy_forcing_does():
    """M + JᵀwJ singular while the forcing's system is not (its m_null I): FabricError, as
    before the fusion (not the kernel's LinAlgError)."""
    rng, av, task, null, _ = _case(1)
    J = task.J.copy()
    J[:, -1] = 0.0  # the last joint moves no task row: JᵀwJ (and M = 0 + JᵀwJ) singular
    task = TaskAcceleration(task.xdd, J, task.jdqd)
    av.M = np.zeros((N, N))
    forcing = Forcing(mode="task_metric", directional=False)
    target = task.xdd - task.jdqd
    with pytest.raises(FabricError):
        forced_reference(av, task, forcing, np.ones(N), None)
    with pytest.raises(FabricError):
        forced_through_metric(av, task, target, forcing, np.ones(N), None)


@pytest.mark.parametrize("below", [np.inf, 0.4, 0.1, "per hull"])
def test_the_one_call_ground_rows_are_the_two_kernel_ones(kinematics, hulls, below, monkeypatch):
    """The compiled one-call ground rows (_kernels.hull_ground, from the chain's joint state)
    are the two-kernel path's, bit for bit, and robot/ground.py's link-by-link ones to
    rounding."""
    pytest.importorskip("numba")
    assert _kernels.warm_up()
    table = HullTable.of(hulls)
    below = _per_hull(hulls, below)
    one = _kernels.STEP["hull_ground"]
    two = _kernels.Kernel(_kernels.hull_ground)  # not compiled: the two-kernel path
    found = 0
    for qd in _evaluated_at_random(kinematics, seed=9):
        got = fused_ground_rows(kinematics, table, qd, below)
        with monkeypatch.context() as m:
            m.setitem(_kernels.STEP, "hull_ground", two)
            want = fused_ground_rows(kinematics, table, qd, below)
        ref = ground.hull_ground_rows(kinematics, hulls, qd, below)
        found += len(want.heights)
        for g, w, r in ((got.heights, want.heights, ref.heights), (got.rows, want.rows, ref.rows),
                        (got.jdqd, want.jdqd, ref.jdqd)):
            assert g.shape == w.shape and np.array_equal(g, w) and _close(g, r)
        assert got.reach == want.reach and (got.reach == 0.0) == (len(got.heights) > 0)
    assert one.fast is not None and found > 0


def test_the_ground_rows_stay_empty_within_their_reach(kinematics, hulls):
    """Where no hull needs a row, none does at any configuration within ``reach`` of it (every
    joint moved by less), by the robot module's link-by-link rows at the same heights; the
    reach is not vacuous."""
    table = HullTable.of(hulls)
    below = _per_hull(hulls, "per hull")
    rng = np.random.default_rng(11)
    lo, hi = np.asarray(kinematics.spec.q_min), np.asarray(kinematics.spec.q_max)
    reaches, checked = [], 0
    for _ in range(60):
        q = rng.uniform(lo, hi)
        kinematics.evaluate(q, np.zeros(N))
        reach = fused_ground_rows(kinematics, table, np.zeros(N), below).reach
        reaches.append(reach)
        if reach == 0.0:
            continue
        for _ in range(20):  # within the reach, out to its edge along a corner
            step = rng.uniform(-1.0, 1.0, N)
            step[rng.integers(N)] = rng.choice([-1.0, 1.0])
            q2 = q + (1.0 - 1e-9) * min(reach, 10.0) * step
            kinematics.evaluate(q2, np.zeros(N))
            assert len(ground.hull_ground_rows(kinematics, hulls, np.zeros(N), below).heights) == 0
            checked += 1
    # random configurations are often low: a reach at half of them, over 0.05 rad (2.5 periods
    # at 1 rad/s) at a quarter (measured: median 0.036 rad, upper quartile 0.088 rad)
    assert checked > 200 and np.percentile(reaches, 75) > 0.05 and min(reaches) == 0.0


def test_the_controller_skips_the_ground_rows_only_where_they_are_empty(kinematics):
    """FPM's ground rows along a random walk that takes the arm down to the ground and back:
    with the skip within reach, every step's rows are those computed afresh (the same arrays),
    most steps skip the computation, and some steps have rows."""
    from omegaconf import OmegaConf

    from tamedpuma.app.compose import compose_dict
    from tamedpuma.app.sweep import build

    built = build(OmegaConf.create(compose_dict("sweep", ["task=tomato", "recorder=none",
                                                          "method=fpm"])))
    ctrl, scenario = built.controller, built.scenario
    ctrl.reset(scenario)
    table, kin = ctrl.hull_table, ctrl.kinematics
    below = table.speeds * (scenario.dt / 0.5)
    rng = np.random.default_rng(12)
    q = np.array([0.0, 0.3, 0.0, -1.0, 0.0, 1.0, 0.0])
    down = np.array([0.0, 1.0, 0.0, 0.6, 0.0, 0.8, 0.0])  # forward and down, then back up
    skipped = with_rows = 0
    for k in range(600):
        qd = (down if (k // 150) % 2 == 0 else -down) + rng.normal(scale=0.3, size=N)
        q = np.clip(q + qd * scenario.dt, kin.spec.q_min, kin.spec.q_max)
        kin.evaluate(q, qd)
        got = ctrl.ground_rows(None, q, qd)
        skipped += got is ctrl.no_ground_rows
        want = fused_ground_rows(kin, table, qd, below)
        with_rows += len(want.heights) > 0
        for g, w in ((got.heights, want.heights), (got.rows, want.rows), (got.jdqd, want.jdqd)):
            assert g.shape == w.shape and np.array_equal(g, w)
    assert skipped > 300 and with_rows > 20  # measured: 379 and 94


def _law_case(seed: int):
    """A fabric's metric and energy force, q̇, h, q̈_C and ∂ψ at random (q̇ small every tenth
    case: α's and the regulator's denominators near ε)."""
    rng = np.random.default_rng(seed)
    qd = rng.standard_normal(N) * (1e-4 if seed % 10 == 0 else 1.0)
    return rng, _spd(rng), rng.standard_normal(N), qd, rng.standard_normal(N), \
        rng.standard_normal(N), rng.standard_normal(N)


@pytest.mark.parametrize("seed", range(40))
def test_compiled_and_plain_law_kernels_agree_and_are_the_laws(seed):
    """``fpm_velocity`` and ``cpm_velocity``: compiled equals plain to rounding, and plain is
    FPM's and CPM's law as written in numpy (α, energized_velocity_step, the matched damping),
    bit for bit."""
    from tamedpuma.fabrics.discrete import energized_velocity_step

    rng, M, f_L, qd, h, qdd_c, dpsi = _law_case(seed)
    eps, dt, semi, matched = 1e-6, 0.02, seed % 2 == 0, seed % 3 != 0
    plain, fast = _plain_and_compiled("fpm_velocity", M, f_L, qd, h, qdd_c, eps, dt, semi)
    Mqd = M @ qd
    alpha = float((Mqd @ h + qd @ f_L) / (qd @ Mqd + eps))
    want = (energized_velocity_step(qd, h + qdd_c, alpha, dt, Mqd, eps) if semi
            else qd + dt * (h - alpha * qd + qdd_c))
    assert plain[0] == alpha and np.array_equal(plain[1], want)
    assert _close(fast[0], plain[0]) and _close(fast[1], plain[1])
    scale, beta_min = float(rng.uniform(0.5, 2.0)), 0.5
    plain, fast = _plain_and_compiled("cpm_velocity", M, f_L, qd, h, qdd_c, dpsi, eps, scale,
                                      beta_min, matched, semi, dt)
    r = -scale * (qd @ dpsi) / (qd @ Mqd + eps)
    hf = h + qdd_c
    alpha = float((Mqd @ hf + qd @ f_L) / (qd @ Mqd + eps))
    beta = max(beta_min, r - alpha) if matched else beta_min
    c = float(r - alpha - beta)
    qdd = ((energized_velocity_step(qd, hf, -c, dt, Mqd, eps) - qd) / dt
           if semi and c < 0.0 else hf + c * qd)
    assert plain[0] == alpha and plain[1] == beta and np.array_equal(plain[2], qd + dt * qdd)
    assert plain[3] == beta * (qd @ Mqd) and plain[4] == dpsi @ qd
    for p, f in zip(plain, fast):
        assert _close(f, p)


def test_the_fused_null_objective_is_the_link_jacobians(kinematics):
    """``null_pull`` (the elbow objective from the chain's state in one call) gives
    ``k J_linkᵀ(p* − p_link) − d q̇`` of link_position_jacobian, compiled and plain."""
    from tamedpuma.methods._policy import NullSpaceObjective

    link = kinematics.spec.link_names[3]
    objective = NullSpaceObjective(link, (0.1, -0.2, 0.9), 4.0, 1.5)
    target = np.array(objective.target)
    for qd in _evaluated_at_random(kinematics, seed=9, n=30):
        p, J = kinematics.link_position_jacobian(link)
        want = objective.stiffness * J.T @ (target - p) - objective.damping * qd
        chain = kinematics.link_chain_state(link)
        plain = _kernels.null_pull.__call__(*chain, target, 4.0, 1.5, qd)
        assert np.array_equal(plain, want)
        if _kernels.warm_up():
            fast = _kernels.STEP["null_pull"].fast(*chain, target, 4.0, 1.5, qd)
            assert _close(fast, want)
            assert np.array_equal(objective.acceleration(kinematics, qd), fast)


@pytest.mark.parametrize("seed", range(20))
def test_the_compiled_speed_limit_is_limit_speed(seed):
    """The compiled :func:`~tamedpuma.fabrics.discrete.limit_speed` gives its plain numbers bit
    for bit, below and above the limit (and NaN where v holds one)."""
    rng = np.random.default_rng(seed)
    v, qd_limit = rng.standard_normal(N) * rng.uniform(0.1, 3.0), rng.uniform(0.5, 2.0, N)
    if seed == 0:
        v[3] = np.nan
    want, got = _plain_and_compiled("limit_speed", v, qd_limit)
    np.testing.assert_array_equal(got[0], want[0])
    assert got[1] == want[1] or (np.isnan(got[1]) and np.isnan(want[1]))
