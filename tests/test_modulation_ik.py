"""Collision-aware IK backends and the Modulation-IK controller, up to a full PyBullet episode."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tamedpuma import ik_solvers
from tamedpuma.app.config import load_group, start_options, typed_scenario
from tamedpuma.app.schema import method_settings, run_config
from tamedpuma.errors import CheckpointError, ConfigError
from tamedpuma.ik_solvers import (
    IKProblem,
    IKResult,
    available_backends,
    distances,
    objective,
    reach_bounds,
    solve_ik,
    violation,
)
from tamedpuma.methods import modulation_ik
from tamedpuma.methods.modulation_ik import LinearVelocityField
from tamedpuma.robot.ik import quat_to_matrix
from tamedpuma.types import Observation

Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])
BACKENDS = available_backends()
TOMATO_GOAL = np.array([0.58, -0.214, 0.115])
TOMATO_QUAT = np.array([-0.5459, 0.5806, -0.4112, 0.4426])


def _problem(kin, q, target, centers, radii=None, step=None, **kw):
    centers = np.reshape(centers, (-1, 3))
    radii = np.full(len(centers), 0.05) if radii is None else radii
    lo = hi = None
    if step is not None:
        lo, hi = q - step, q + step
    return IKProblem(kin, q, target, centers, radii, q_lower=lo, q_upper=hi, **kw)


def _random_scene(kin, rng):
    """A random configuration, a target near its end effector and obstacles near the arm."""
    spec = kin.spec
    q = rng.uniform(spec.q_min * 0.8, spec.q_max * 0.8)
    centers_robot = kin.sphere_centers(q)
    p, _ = kin.ee_pose(q)
    n = int(rng.integers(1, 6))
    picks = centers_robot[rng.integers(len(centers_robot), size=n)]
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    centers = picks + directions * rng.uniform(0.12, 0.35, size=(n, 1))
    target = p + rng.normal(scale=0.05, size=3)
    return q, target, centers


# -- shared maths --------------------------------------------------------------------------

def test_objective_gradient_matches_finite_differences(kinematics):
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(-1.5, 1.5, 7)
        rot = quat_to_matrix(rng.normal(size=4))
        prob = _problem(kinematics, q + 0.1, rng.normal(size=3), np.zeros((0, 3)),
                        target_rotation=rot, orientation_weight=0.7, regularization_weight=0.3)
        value, grad = objective(prob, kinematics.evaluate(q, np.zeros(7)), q)
        fd = np.zeros(7)
        for k in range(7):
            e = np.zeros(7)
            e[k] = 1e-6
            fp = objective(prob, kinematics.evaluate(q + e, np.zeros(7)), q + e)[0]
            fm = objective(prob, kinematics.evaluate(q - e, np.zeros(7)), q - e)[0]
            fd[k] = (fp - fm) / 2e-6
        np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-7)
        # the orientation term is w_R (1 − cos θ)
        rel = rot.T @ kinematics.evaluate(q, np.zeros(7)).ee_rotation
        cos = (np.trace(rel) - 1) / 2
        p = kinematics.ee_pose(q)[0]
        expected = (np.sum((p - prob.target_position) ** 2) + 0.7 * (1 - cos)
                    + 0.3 * np.sum((q - prob.q_ref) ** 2))
        assert value == pytest.approx(expected, rel=1e-12)


def test_distance_jacobian_matches_finite_differences(kinematics):
    rng = np.random.default_rng(1)
    q = rng.uniform(-1.5, 1.5, 7)
    prob = _problem(kinematics, q, np.zeros(3), rng.uniform(-0.8, 0.8, (4, 3)), d_min=0.02)
    gap, jac = distances(prob, q, with_jacobian=True)
    assert gap.shape == (5 * 4,) and jac.shape == (20, 7)
    fd = np.column_stack([(distances(prob, q + e) - distances(prob, q - e)) / 2e-6
                          for e in 1e-6 * np.eye(7)])
    np.testing.assert_allclose(jac, fd, atol=1e-6)
    centers = kinematics.sphere_centers(q)
    manual = (np.linalg.norm(centers[:, None] - prob.obstacle_centers[None], axis=-1)
              - kinematics.spec.sphere_radii[:, None] - 0.05 - 0.02)
    np.testing.assert_allclose(gap, manual.ravel(), atol=1e-12)


def test_reach_bounds_bound_every_sphere_displacement(kinematics):
    reach = reach_bounds(kinematics)
    rng = np.random.default_rng(2)
    for _ in range(200):
        q = rng.uniform(kinematics.spec.q_min, kinematics.spec.q_max)
        dq = rng.normal(scale=rng.choice([0.01, 0.3]), size=7)
        moved = np.linalg.norm(kinematics.sphere_centers(q + dq) - kinematics.sphere_centers(q),
                               axis=1)
        assert np.all(moved <= reach @ np.abs(dq) + 1e-12)


# -- backends ------------------------------------------------------------------------------

def test_unknown_backend_is_a_config_error(kinematics):
    with pytest.raises(ConfigError, match="unknown ik backend"):
        solve_ik(_problem(kinematics, Q0, np.zeros(3), np.zeros((0, 3))), backend="nope")


@pytest.mark.parametrize("backend", BACKENDS)
def test_success_implies_every_distance_constraint_holds(kinematics, backend):
    """Property over random scenes: a reported success satisfies every constraint."""
    rng = np.random.default_rng(10)
    successes = 0
    for _ in range(25):
        q, target, centers = _random_scene(kinematics, rng)
        step = rng.choice([0.03, 0.3, None])
        prob = _problem(kinematics, q, target, centers, d_min=0.02, step=step)
        raw = ik_solvers.BACKENDS[backend](prob)  # the solver's own claim, before our check
        if raw.success:
            assert violation(prob, raw.q)[0] <= prob.tolerance, raw.message
        result = solve_ik(prob, backend)
        assert isinstance(result, IKResult) and result.backend == backend
        assert result.success == raw.success
        assert result.status in ("success", "failed") and result.message
        viol, dmin = violation(prob, result.q)
        assert result.max_violation == pytest.approx(viol, abs=1e-12)
        if result.success:
            successes += 1
            assert viol <= prob.tolerance
            assert np.all(distances(prob, result.q) >= -prob.tolerance)
            assert np.all(result.q >= prob.q_lower - 1e-9) and np.all(result.q <= prob.q_upper
                                                                        + 1e-9)
            assert dmin >= prob.d_min - prob.tolerance
    assert successes >= 15


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_sub_millimetre_step_is_taken(kinematics, backend):
    """Modulation-IK's final approach asks for steps of ~0.2 mm (9 mm/s × 0.02 s). The solver
    must take them: unscaled, such a step's objective gain (~10⁻⁸) was below SNOPT's optimality
    tolerance, SNOPT returned the start and the arm stood 5.6 cm from the goal (Table-1 pouring
    0). With the weights Modulation-IK uses, the answer is ≥ 90 % of the way."""
    rng = np.random.default_rng(4)
    p, _ = kinematics.ee_pose(Q0)
    far = p + np.array([0.0, 0.0, 1.0])  # an obstacle nowhere near
    for _ in range(5):
        d = rng.normal(size=3)
        target = p + 2e-4 * d / np.linalg.norm(d)
        result = solve_ik(_problem(kinematics, Q0, target, far, step=0.03,
                                   regularization_weight=1e-4), backend)
        assert result.success, result.message
        reached, _ = kinematics.ee_pose(result.q)
        assert np.linalg.norm(reached - target) <= 0.1 * 2e-4


@pytest.mark.parametrize("backend", BACKENDS)
def test_target_inside_an_obstacle_stops_at_the_clearance_bound(kinematics, backend):
    p, _ = kinematics.ee_pose(Q0)
    obstacle = p + np.array([0.0, 0.0, -0.2])  # gap 0.2 − 0.07 − 0.05 − 0.02 = 0.06 m
    result = solve_ik(_problem(kinematics, Q0, obstacle, obstacle, d_min=0.02, step=0.15),
                      backend)
    assert result.success, result.message
    assert result.min_distance == pytest.approx(0.02, abs=2e-3)  # the bound is active
    assert result.max_violation <= 1e-5


@pytest.mark.parametrize("backend", BACKENDS)
def test_infeasible_problem_returns_a_safe_answer_flagged_failed(kinematics, backend):
    """An obstacle engulfing the link-3 sphere: no configuration within a small box clears it."""
    c3 = kinematics.sphere_centers(Q0)[0]
    prob = _problem(kinematics, Q0, kinematics.ee_pose(Q0)[0] + 0.01, c3, radii=[0.1],
                    step=0.02, d_min=0.02)
    result = solve_ik(prob, backend)
    assert not result.success and result.status == "failed"
    assert result.max_violation > 0.1  # reported, not hidden
    v_start = violation(prob, Q0)[0]
    assert result.max_violation <= v_start + 1e-12  # never worse than staying put
    assert np.all(np.isfinite(result.q))
    assert np.all(result.q >= prob.q_lower - 1e-9) and np.all(result.q <= prob.q_upper + 1e-9)


def test_a_successful_but_unsafe_answer_is_rejected(kinematics, monkeypatch):
    """solve_ik checks every answer itself: a backend's 'success' that violates a constraint is
    reported as failed and the safe start is returned."""
    p, _ = kinematics.ee_pose(Q0)
    prob = _problem(kinematics, Q0, p, p + [0.0, 0.0, 0.3], d_min=0.02)
    bad = Q0 + 0.5

    def liar(problem):
        return IKResult(q=bad, success=True, message="liar: ok", iterations=1,
                        max_violation=0.0, min_distance=1.0, backend="liar")

    monkeypatch.setitem(ik_solvers.BACKENDS, "liar", liar)
    # make the liar's answer unsafe: an obstacle on its end effector
    prob = dataclasses.replace(prob, obstacle_centers=kinematics.ee_pose(bad)[0][None])
    assert violation(prob, bad)[0] > 0 and violation(prob, Q0)[0] == 0
    result = solve_ik(prob, "liar")
    assert not result.success and "rejected" in result.message
    np.testing.assert_array_equal(result.q, Q0)


@pytest.mark.skipif(len(BACKENDS) < 2, reason="needs both backends")
def test_backends_agree_on_a_simple_problem(kinematics):
    p, _ = kinematics.ee_pose(Q0)
    prob = _problem(kinematics, Q0, p + [0.01, -0.01, -0.005], [[0.5, -0.3, 0.5]],
                    step=kinematics.spec.qd_max * 0.02, regularization_weight=1e-6)
    a, b = (solve_ik(prob, name) for name in ("drake", "slsqp"))
    assert a.success and b.success
    fa, fb = (objective(prob, kinematics.evaluate(r.q, np.zeros(7)), r.q)[0] for r in (a, b))
    assert fa == pytest.approx(fb, rel=1e-2)  # SNOPT stops ~0.3 % above SLSQP's optimum here
    # q may differ along the (nearly flat, w_q = 1e-6) self-motion; the end effector may not
    np.testing.assert_allclose(kinematics.ee_pose(a.q)[0], kinematics.ee_pose(b.q)[0], atol=2e-4)


@pytest.mark.skipif("drake" not in BACKENDS, reason="needs drake (pip install drake)")
def test_drakes_reused_program_answers_as_a_fresh_one(kinematics):
    """Every solve reuses the world's program (its box bounds set, its distance constraint
    replaced when d_min changes, its costs replaced): the answers are a fresh program's to the
    bit, through changes of d_min, iteration limits and failed solves."""
    from tamedpuma.ik_solvers import drake

    rng = np.random.default_rng(3)
    for k in range(12):
        q, target, centers = _random_scene(kinematics, rng)
        if k % 4 == 3:  # an obstacle on a body sphere: hard or infeasible
            centers = kinematics.sphere_centers(q)[3:4] + 0.02
        prob = _problem(kinematics, q, target, centers, step=0.05,
                        d_min=[0.02, 0.0, 0.05][k % 3], max_iterations=[100, 2][k % 5 == 4],
                        target_rotation=kinematics.ee_frame(q)[1], orientation_weight=0.1)
        reused = drake.solve(prob)
        drake._world(kinematics, prob.obstacle_radii).program = None  # the next solve builds it
        fresh = drake.solve(prob)
        np.testing.assert_array_equal(reused.q, fresh.q)
        assert (reused.success, reused.iterations, reused.message) == (
            fresh.success, fresh.iterations, fresh.message)


def test_one_placement_pass_gives_the_hand_and_the_spheres(kinematics):
    """placement(q): ee_frame's and sphere_centers' numbers to the bit; solve_ik's answer carries
    its end-effector position from the check's pass."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        q = rng.uniform(kinematics.spec.q_min, kinematics.spec.q_max)
        p, rot, centers = ik_solvers.placement(kinematics, q)
        p_ee, rot_ee = kinematics.ee_frame(q)
        np.testing.assert_array_equal(p, p_ee)
        np.testing.assert_array_equal(rot, rot_ee)
        np.testing.assert_array_equal(centers, kinematics.sphere_centers(q))
    prob = _problem(kinematics, Q0, kinematics.ee_pose(Q0)[0] + 0.01, [[0.5, -0.3, 0.5]],
                    step=0.05)
    result = solve_ik(prob, BACKENDS[0])
    np.testing.assert_array_equal(result.ee_position, kinematics.ee_frame(result.q)[0])
    assert violation(prob, result.q, ik_solvers.placement(kinematics, result.q)[2]) == \
        violation(prob, result.q)


@pytest.mark.skipif("drake" not in BACKENDS, reason="needs drake (pip install drake)")
def test_drakes_plant_is_built_without_warnings(kinematics, caplog):
    """The IK's plant takes the URDF's kinematic tree alone: Drake warned on the iiwa base's
    massless inertia at every build (one line in every Modulation-IK run's output)."""
    from tamedpuma.ik_solvers import drake

    drake._WORLDS.clear()
    with caplog.at_level("WARNING", logger="drake"):
        ik_solvers.warm_up(kinematics, [0.1, 0.15], "drake")
    assert not [r for r in caplog.records if r.name == "drake"], caplog.text


# -- controller ----------------------------------------------------------------------------

def make(cfg, kinematics, primitive=None):
    """The controller of a plain method config, typed by the schema."""
    return modulation_ik.make(method_settings(cfg), kinematics, primitive)


def _method_cfg(**changes):
    cfg = load_group("method", "modulation_ik")
    cfg.update(task="tomato", checkpoint="runs/puma/tomato_position/puma.pt",
               ik_backend=BACKENDS[0])  # drake if installed, else slsqp
    cfg.update(changes)
    return cfg


def _obs(q, centers=(), velocities=None):
    centers = np.reshape(np.asarray(centers, float), (-1, 3))
    velocities = np.zeros_like(centers) if velocities is None else velocities
    return Observation(t=0.0, step=0, q=q, qd=np.zeros(7), obstacle_centers=centers,
                       obstacle_radii=np.full(len(centers), 0.05),
                       obstacle_velocities=velocities, goal_position=TOMATO_GOAL,
                       goal_quaternion=TOMATO_QUAT, goal_velocity=np.zeros(3))


def test_config_resolves_the_checkpoint_from_the_task():
    from tamedpuma.app.train import compose
    from tamedpuma.puma import store

    cfg = compose("sweep", ["method=modulation_ik", "task=pouring", "method.model=shipped"])
    assert cfg["method"]["checkpoint"] is None  # the best model at hand (tamedpuma.puma.store)
    assert cfg["method"]["task"] == "pouring" and cfg["method"]["name"] == "modulation_ik"
    method = run_config(cfg).method
    assert store.resolve_for_method(method.name, method_settings(method)).name == \
        "pouring_position"


def test_missing_checkpoint_names_the_train_command(kinematics, tmp_path):
    with pytest.raises(CheckpointError) as err:
        make(_method_cfg(checkpoint=str(tmp_path / "tomato_position" / "puma.pt")), kinematics)
    msg = str(err.value)
    assert "\n" not in msg and "file not found" in msg
    assert (f"python -m tamedpuma.train task=tomato puma=position "
            f"out_dir={tmp_path / 'tomato_position'}") in msg


def test_corrupt_checkpoint_is_a_checkpoint_error(kinematics, tmp_path):
    bad = tmp_path / "puma.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="python -m tamedpuma.train task=tomato"):
        make(_method_cfg(checkpoint=str(bad)), kinematics)


@pytest.mark.parametrize("changes, match", [
    ({"bogus": 1}, "unknown key"),
    ({"d_min": -1.0}, "d_min"),
    ({"ik_backend": "nope"}, "ik_backend"),
    ({"trust": "abc"}, r"method\.trust: .*abc"),
])
def test_bad_method_config_is_a_config_error(kinematics, changes, match):
    with pytest.raises(ConfigError, match=match):
        make(_method_cfg(**changes), kinematics, primitive=LinearVelocityField())


@pytest.fixture(scope="module")
def tiny_position_checkpoint(tmp_path_factory):
    """A tiny first-order R³ PUMA trained in seconds (inaccurate; exercises loading)."""
    from tamedpuma.app import train

    out = tmp_path_factory.mktemp("tiny_position")
    assert train.main(["task=tomato", "puma=tiny", "puma.orientation=false", "puma.order=1",
                       f"out_dir={out}", "progress=false", "evaluate=false"]) == 0
    return out / "puma.pt"


def test_a_trained_position_primitive_drives_the_controller(kinematics,
                                                            tiny_position_checkpoint):
    ctrl = make(_method_cfg(checkpoint=str(tiny_position_checkpoint), ik_backend=BACKENDS[0]),
                kinematics)
    obs = _obs(Q0, [[0.5, -0.3, 0.5]])
    command = ctrl.step(obs)
    assert command.qdd.shape == (7,) and np.all(np.isfinite(command.qdd))
    assert command.scalars["ik_success"] == 1.0
    # PUMA's ψ of the position model at the hand, for the log only (not in the timed step)
    assert "psi" not in command.scalars
    hand = kinematics.ee_frame(Q0)[0]
    psi, _ = ctrl.primitive.potential(hand, obs.goal_position)
    assert command.logged_later() == {"psi": pytest.approx(psi, rel=1e-12)} and psi > 0
    plain = make(_method_cfg(ik_backend=BACKENDS[0]), kinematics, primitive=LinearVelocityField())
    assert plain.step(obs).logged_later is None  # a field without ψ logs none


def test_a_pose_checkpoint_is_refused(kinematics, tmp_path):
    from tamedpuma.app import train

    out = tmp_path / "pose"
    assert train.main(["task=tomato", "puma=tiny", f"out_dir={out}", "progress=false",
                       "evaluate=false"]) == 0
    with pytest.raises(CheckpointError, match="first-order 3-D position primitive"):
        make(_method_cfg(checkpoint=str(out / "puma.pt")), kinematics)


@pytest.mark.parametrize("backend", BACKENDS)
def test_step_logs_the_internals_and_tracks_the_ik(kinematics, backend):
    ctrl = make(_method_cfg(ik_backend=backend), kinematics, primitive=LinearVelocityField(1.0))
    command = ctrl.step(_obs(Q0, [[0.5, -0.3, 0.5], [0.24355761, 0.45252747, 0.2]]))
    s = command.scalars
    assert {"ik_success", "ik_iterations", "ik_constraint_violation_m", "modulation_gamma_min",
            "min_clearance_m", "ik_solve_ms", "ik_brake"} <= set(s)
    assert s["ik_success"] == 1.0 and s["ik_brake"] == 0.0 and s["ik_iterations"] >= 1
    assert s["min_clearance_m"] >= ctrl.params.d_min - 1e-5
    assert 1.0 < s["modulation_gamma_min"] < 100
    # the commanded velocity q̇ + q̈Δt moves the joints to q_ik in one step, within the limits
    qd_cmd = command.qdd * 0.02
    assert np.all(np.abs(qd_cmd) <= kinematics.spec.qd_max + 1e-9)
    assert np.linalg.norm(qd_cmd) > 0


def test_the_end_effector_position_is_modulated_in_the_base_frame(kinematics):
    """EE on the inflated boundary of an obstacle (in the base frame), nominal velocity partly
    into it: the target step has no inward normal component and keeps its tangential one."""
    ctrl = make(_method_cfg(ik_backend=BACKENDS[0]), kinematics,
                primitive=LinearVelocityField(1.0))
    state = kinematics.evaluate(Q0, np.zeros(7))
    p = state.ee_position
    normal = np.array([0.0, 0.6, 0.8])
    tangent = np.array([1.0, 0.0, 0.0])
    center = p - (0.05 + ctrl.params.safety_radius) * normal
    assert ctrl.params.safety_radius >= 0.07 + ctrl.params.d_min  # the IK allows this start
    obs = dataclasses.replace(_obs(Q0, [center]), goal_position=p + 0.2 * (tangent - normal))
    p_target, _, v, v_mod, mod = ctrl._targets(obs, p, state.ee_rotation)
    assert mod.gamma_min == pytest.approx(1.0)
    assert v @ normal < 0 and v_mod @ normal == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(v_mod, 2.0 * (v @ tangent) * tangent, atol=1e-12)
    np.testing.assert_allclose(p_target, p + 0.02 * v_mod, atol=1e-15)
    command = ctrl.step(obs)
    assert command.scalars["modulation_gamma_min"] == pytest.approx(1.0)
    assert command.scalars["ik_success"] == 1.0


def test_the_ik_target_stays_inside_the_joint_limits_by_the_margin(kinematics):
    ctrl = make(_method_cfg(ik_backend=BACKENDS[0]), kinematics, primitive=LinearVelocityField())
    q = Q0.copy()
    q[6] = kinematics.spec.q_max[6] - 1e-3  # inside the limit, but within the margin
    command = ctrl.step(_obs(q))
    q_ik = q + command.qdd * 0.02**2  # q̇ = 0: q_ik = q + q̈Δt²
    assert q_ik[6] <= kinematics.spec.q_max[6] - ctrl.params.limit_margin + 1e-9
    assert np.all(q_ik >= kinematics.spec.q_min + ctrl.params.limit_margin - 1e-9)


@pytest.mark.parametrize("start_is_safe", [True, False])
def test_a_failed_solve_brakes(kinematics, monkeypatch, start_is_safe):
    def failing(problem):
        return IKResult(q=problem.q_start + 1.0, success=False, message="fail", iterations=3,
                        max_violation=0.0, min_distance=0.0, backend="failing")

    monkeypatch.setitem(ik_solvers.BACKENDS, "failing", failing)
    ctrl = make(_method_cfg(ik_backend="slsqp"), kinematics, primitive=LinearVelocityField())
    ctrl.params = dataclasses.replace(ctrl.params, ik_backend="failing")
    # unsafe start: an obstacle on the link-4 sphere
    center = [0.5, -0.3, 0.5] if start_is_safe else kinematics.sphere_centers(Q0)[1]
    obs = dataclasses.replace(_obs(Q0, [center]), qd=np.full(7, 0.1))
    command = ctrl.step(obs)
    s = command.scalars
    assert s["ik_success"] == 0.0 and s["ik_iterations"] == 3.0 and s["ik_brake"] == 1.0
    # the unsafe answer (outside the step box) is never used: brake, q̇_cmd = q̇ + q̈Δt = 0
    assert (s["ik_constraint_violation_m"] > 0) != start_is_safe
    np.testing.assert_allclose(obs.qd + command.qdd * 0.02, 0.0, atol=1e-12)


# -- end to end ----------------------------------------------------------------------------

def _default_scenario(robot_spec):
    from tamedpuma.worlds.scenarios import scenario_from_config

    cfg = load_group("scenario", "default")
    task = load_group("task", "tomato")
    cfg["goal"].update(position=task["goal_position"], quaternion=task["goal_quaternion"])
    return scenario_from_config(typed_scenario(cfg), robot_spec, task="tomato", **start_options())


def test_episode_with_an_obstacle_moving_into_the_arm(robot_spec, kinematics):
    """An obstacle crossing the workspace toward the arm: no body sphere ever penetrates it."""
    from tamedpuma.episode import run_episode
    from tamedpuma.types import Obstacles
    from tamedpuma.worlds.bullet import Simulator

    scenario = _default_scenario(robot_spec)
    p0 = kinematics.ee_pose(scenario.q0)[0]
    moving = Obstacles(centers=[p0 + [0.0, 0.45, -0.1]], radii=[0.05],
                       velocities=[[0.0, -0.1, 0.0]])
    scenario = dataclasses.replace(scenario, obstacles=moving, max_steps=300)
    ctrl = make(_method_cfg(ik_backend=BACKENDS[0]), kinematics,
                primitive=LinearVelocityField(1.0))
    with Simulator(robot_spec) as sim:
        result = run_episode(scenario, ctrl, sim)
    assert result.metrics.min_clearance_m > 0 and not result.metrics.collided

@pytest.mark.parametrize("backend", BACKENDS)
def test_episode_reaches_the_tomato_goal_without_penetration(robot_spec, kinematics, backend):
    from tamedpuma.episode import run_episode
    from tamedpuma.worlds.bullet import Simulator
    from tamedpuma.worlds.scenarios import scenario_from_config

    cfg = load_group("scenario", "default")
    task = load_group("task", "tomato")
    cfg["goal"].update(position=task["goal_position"], quaternion=task["goal_quaternion"])
    scenario = scenario_from_config(typed_scenario(cfg), robot_spec,
                                    task="tomato", **start_options())
    ctrl = make(_method_cfg(ik_backend=backend), kinematics, primitive=LinearVelocityField(1.0))
    scalars = []
    step = ctrl.step

    def logged(obs):
        command = step(obs)
        scalars.append(command.scalars)
        return command

    ctrl.step = logged
    with Simulator(robot_spec) as sim:
        result = run_episode(scenario, ctrl, sim)
    m = result.metrics
    assert m.success and m.final_position_error_m <= 0.05, result.stop_reason
    assert m.min_clearance_m > 0 and not m.collided
    assert m.joint_limit_violation_steps == 0
    assert all(s["ik_success"] == 1.0 for s in scalars)
    assert min(s["min_clearance_m"] for s in scalars) >= ctrl.params.d_min - 1e-5


@pytest.mark.parametrize("backend", BACKENDS)
def test_an_arm_that_starts_within_d_min_backs_out(kinematics, backend):
    """An obstacle 2 cm from the elbow's sphere (d_min = 5 cm). With a fixed d_min no step in the
    trust box is admissible, every solve fails and the arm is held (Table-1 tomato 1 and 6 for
    40 s); with ``hold_clearance`` the bound is the current clearance plus the recovery (2 mm
    per step): every solve succeeds and the arm backs out to d_min, its clearance never falling."""
    c = kinematics.sphere_centers(Q0)[1]
    center = c + np.array([0.0, 0.0, 1.0]) * (kinematics.spec.sphere_radii[1] + 0.05 + 0.02)
    held = make(_method_cfg(ik_backend=backend, hold_clearance=False), kinematics,
                primitive=LinearVelocityField(1.0)).step(_obs(Q0, [center]))
    assert held.scalars["ik_brake"] == 1.0
    np.testing.assert_allclose(held.qdd * 0.02, 0.0, atol=1e-12)  # q̇_cmd = 0: held
    ctrl = make(_method_cfg(ik_backend=backend), kinematics, primitive=LinearVelocityField(1.0))

    def gap(q):
        return float(np.min(np.linalg.norm(kinematics.sphere_centers(q) - center, axis=1)
                            - kinematics.spec.sphere_radii - 0.05))

    q, gaps, bounds = Q0.copy(), [gap(Q0)], []
    for _ in range(20):
        command = ctrl.step(_obs(q, [center]))
        assert command.scalars["ik_success"] == 1.0 and command.scalars["ik_brake"] == 0.0
        bounds.append(command.scalars["ik_d_min_m"])
        q = q + command.qdd * 0.02 * 0.02  # q̇_cmd Δt from rest: the IK's answer
        gaps.append(gap(q))
    assert bounds[0] == pytest.approx(0.022, abs=1e-6) and bounds[-1] == 0.05
    assert np.all(np.diff(gaps) >= -1e-5) and gaps[-1] >= 0.05 - 1e-4


def test_hold_clearance_must_be_a_boolean(kinematics):
    with pytest.raises(ConfigError, match=r"method\.hold_clearance: .*maybe"):
        make(_method_cfg(hold_clearance="maybe"), kinematics, primitive=LinearVelocityField(1.0))
