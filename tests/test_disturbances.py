"""The disturbance experiment's behaviours in PyBullet: an online goal change, an
external push, noisy 30 Hz obstacle sensing and a 1 kHz joint impedance controller, each driven
by FPM.

FPM's forcing policy here is an analytic stable second-order pose system standing in for a
trained PUMA (a tiny CI model is not accurate enough to reach a goal), so these tests run in CI
and check the simulator and FPM's fabric around any stable policy. With a real-data tomato model
at hand (``conftest.real_model``: ``$TAMEDPUMA_MODELS/tomato/puma.pt``, else the one a run
with ``method.model=real`` takes) the same checks also run with PUMA (skipped
otherwise).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import real_model

from tamedpuma.app.config import load_group, start_options, typed_scenario
from tamedpuma.app.schema import method_settings
from tamedpuma.episode import run_episode
from tamedpuma.fabrics import Fabric
from tamedpuma.methods import make
from tamedpuma.methods._learned import null_objective
from tamedpuma.methods._policy import PoseTask
from tamedpuma.methods.fpm import FpmController
from tamedpuma.methods.puma import PumaController
from tamedpuma.robot.rotations import quat_to_matrix, rotation_error
from tamedpuma.worlds.bullet import Disturbance, SimConfig, Simulator
from tamedpuma.worlds.scenarios import scenario_from_config

REAL_MODELS = [p for p in (real_model("tomato"),) if p is not None]
IMPEDANCE = SimConfig(control="impedance")
VELOCITY = SimConfig()
NO_DISTURBANCE = Disturbance()


class StablePose:
    """ẍ = k_p (p_g − p) − k_d v, α̇ = k_r log(R_g Rᵀ) − k_w ω: a globally stable pose system with
    the interface of a second-order PUMA primitive (no potential: FPM does not use one)."""

    def __init__(self, kp=1.0, kd=2.0, kr=1.0, kw=2.0):
        self.kp, self.kd, self.kr, self.kw = kp, kd, kr, kw

    def acceleration(self, p, quat, v, omega, goal_p, goal_quat):
        a = self.kp * (np.asarray(goal_p) - p) - self.kd * np.asarray(v)
        err = rotation_error(quat_to_matrix(quat), quat_to_matrix(goal_quat))
        return a, self.kr * err - self.kw * np.asarray(omega)


def _scenario(robot_spec, **changes):
    cfg = load_group("scenario", "default")
    task = load_group("task", "tomato")
    cfg["goal"].update(position=task["goal_position"], quaternion=task["goal_quaternion"])
    scenario = scenario_from_config(typed_scenario(cfg), robot_spec,
                                    task="tomato", **start_options())
    return replace(scenario, **changes)


def _fpm(kinematics, source):
    method = {**load_group("method", "puma"), **load_group("method", "fpm")}
    method.pop("defaults")
    method["fabric"] = load_group("fabric", "default")
    method["task"] = "tomato"
    if source == "analytic":
        settings = method_settings(method)
        puma = PumaController(PoseTask(StablePose()), kinematics,
                              float(settings.pinv_damping), null_objective(settings.null_space))
        spec = kinematics.spec
        return FpmController(puma, Fabric(settings.fabric, spec.q_min, spec.q_max))
    method["checkpoint"] = str(source)
    return make("fpm", method_settings(method), kinematics)


def _sources(known_gap: str | None = None) -> list:
    """The analytic stand-in, and the real tomato model where it is at hand (slow; an expected
    failure with ``known_gap`` as its reason)."""
    marks = [pytest.mark.slow]
    if known_gap:
        marks.append(pytest.mark.xfail(strict=False, reason=f"known gap (BENCHMARKS.md, "
                                       f"'Safety beyond Table 1'): {known_gap}"))
    return ["analytic"] + [pytest.param(p, marks=marks, id="real") for p in REAL_MODELS[:1]]


SOURCES = _sources()


def _run(robot_spec, kinematics, source, scenario, sim=VELOCITY, dist=NO_DISTURBANCE):
    with Simulator(robot_spec, sim, dist) as world:
        return run_episode(scenario, _fpm(kinematics, source), world)


def _max_deviation(path, reference):
    """Largest distance [m] from a point of ``path`` to the nearest point of ``reference``."""
    return float(np.linalg.norm(path[:, None] - reference[None], axis=-1).min(axis=1).max())


@pytest.mark.parametrize("source", SOURCES)
def test_fpm_reaches_the_default_goal_under_joint_impedance_control(robot_spec, kinematics,
                                                                     source):
    scenario = _scenario(robot_spec, dt=0.033, max_steps=1212)  # 30 Hz policy, 40 s
    run = _run(robot_spec, kinematics, source, scenario, IMPEDANCE)
    m = run.metrics
    assert run.stop_reason == "converged" and m.success_whole_body, m.failure_whole_body
    assert m.min_clearance_m > 0


PUSH_SOURCES = _sources()  # the analytic stand-in and, where it is at hand, the real model


@pytest.mark.parametrize("source", PUSH_SOURCES)
def test_a_push_moves_the_arm_off_its_path_and_fpm_still_reaches_the_goal(
        robot_spec, kinematics, source):
    """The push (40 N on the hand for 0.3 s, 3 s in) takes the hand farther off its undisturbed
    path than the goal ball's radius: 0.26 m with the analytic stand-in, 0.09-0.29 m with six
    real-data tomato models (two training recipes, seeds 0-2), as the motion's speed and
    posture at the onset decide; FPM still reaches the goal, and the recovery time is counted
    from the push."""
    scenario = _scenario(robot_spec, dt=0.033, max_steps=1212)
    free = _run(robot_spec, kinematics, source, scenario, IMPEDANCE)
    push = load_group("disturbance", "push")["disturbance"]
    dist = Disturbance(**push)
    assert dist.onset < free.metrics.time_to_success_s - 0.5  # the push comes mid-motion
    pushed = _run(robot_spec, kinematics, source, scenario, IMPEDANCE, dist)
    assert _max_deviation(pushed.ee_position, free.ee_position) > scenario.goal_tolerance
    m = pushed.metrics
    assert m.success_whole_body, m.failure_whole_body
    assert m.recovery_time_s == pytest.approx(m.time_to_success_s - dist.onset)


# the analytic stand-in, and the real tomato model where it is at hand
GOAL_CHANGE_SOURCES = _sources()


@pytest.mark.parametrize("source", GOAL_CHANGE_SOURCES)
def test_after_an_online_goal_change_fpm_reaches_the_new_goal(robot_spec, kinematics, source):
    scenario = _scenario(robot_spec)
    cfg = load_group("disturbance", "goal_change")["disturbance"]
    dist = Disturbance(**cfg)
    run = _run(robot_spec, kinematics, source, scenario, dist=dist)
    new_goal = scenario.goal.position + np.asarray(dist.goal_offset)
    assert np.linalg.norm(dist.goal_offset) >= 0.1
    assert run.metrics.success_whole_body, run.metrics.failure_whole_body
    assert run.metrics.time_to_success_s >= dist.onset  # only a reach after the change counts
    # and came to rest in the new goal's ball (the reach is no pass through it)
    assert run.metrics.converged_whole_body
    to_new = np.linalg.norm(run.ee_position[-1] - new_goal)
    to_old = np.linalg.norm(run.ee_position[-1] - scenario.goal.position)
    # it went to the new goal, not the old one: at the end outside the old goal's ball and
    # nearer the new one (with |offset| = 0.14 m and a 0.05 m ball the end can be 0.09 m from
    # the old goal)
    assert to_old > scenario.goal_tolerance and to_old > to_new
    # and is in the new goal's ball at the end: the run stops when the hand rests there. With
    # the real tomato model of `models build` the hand rested in the ball at 16 s, drifted out
    # with two joints at their limits and stayed 6.7 cm off to the end while the configuration
    # pull, its search overtaken by the hand, waited for a new arming of the stall pull
    # (tests/test_configuration_pull.py); measured with six real-data models: all end inside
    assert to_new <= scenario.goal_tolerance


def test_obstacles_are_seen_at_30_hz_with_noise_while_the_truth_decides_contacts(robot_spec):
    scenario = _scenario(robot_spec, seed=3)
    dist = Disturbance(kind="obstacle_noise", noise_std=0.02, sensor_rate=30.0)

    def observed(dist, steps=60):
        with Simulator(robot_spec, SimConfig(), dist) as sim:
            obs = [sim.reset(scenario)]
            obs += [sim.step(np.zeros(7)) for _ in range(steps)]
            truth = sim.obstacle_centers()
        return np.array([o.obstacle_centers for o in obs]), np.array([o.t for o in obs]), truth

    seen, t, truth = observed(dist)
    err = seen - scenario.obstacles.centers[None]  # static obstacles
    assert 0.01 < err.std() < 0.03 and abs(err.mean()) < 0.01
    np.testing.assert_array_equal(truth, scenario.obstacles.centers)
    sample = np.floor(t * 30.0 + 1e-9)
    for k in range(1, len(t)):  # held between samples, a new draw at each 1/30 s sample
        same = np.array_equal(seen[k], seen[k - 1])
        assert same == (sample[k] == sample[k - 1])
    again, _, _ = observed(dist)
    np.testing.assert_array_equal(seen, again)  # seeded by the scenario seed
    clean, _, _ = observed(Disturbance())
    np.testing.assert_array_equal(clean, np.broadcast_to(scenario.obstacles.centers, clean.shape))


def test_impedance_control_tracks_the_velocity_controlled_motion(robot_spec, kinematics):
    """The same joint-space controller under both control chains: paths within a few cm."""
    scenario = _scenario(robot_spec, dt=0.033, max_steps=400)
    runs = {}
    for mode in ("velocity", "impedance"):
        controller = make("joint_attractor",
                          method_settings(load_group("method", "joint_attractor")), kinematics)
        with Simulator(robot_spec, SimConfig(control=mode)) as sim:
            runs[mode] = run_episode(scenario, controller, sim)
    assert all(r.metrics.success_whole_body for r in runs.values())
    assert _max_deviation(runs["impedance"].ee_position, runs["velocity"].ee_position) < 0.05


def test_bad_disturbance_and_control_settings_are_rejected():
    with pytest.raises(ValueError, match="kind"):
        Disturbance(kind="earthquake")
    with pytest.raises(ValueError, match="control"):
        SimConfig(control="position")


def test_the_impedance_gains_and_the_pushed_link_are_the_robot_s(robot_spec):
    """The simulator's settings name no joint or link of a robot: the impedance controller's
    gains are ``robot.impedance`` (the iiwa's datasheet torque limits), a push lands on the
    robot's end-effector link unless a link is named, and a robot without gains is refused
    impedance control in one line."""
    from dataclasses import fields

    from tamedpuma.app.compose import compose
    from tamedpuma.app.config import robot_config
    from tamedpuma.app.schema import run_config
    from tamedpuma.errors import ConfigError
    from tamedpuma.robot.kinematics import robot_spec_from_config

    assert robot_spec.impedance.torque_limit == (320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0)
    assert not {"stiffness", "damping", "torque_limit"} & {f.name for f in fields(SimConfig)}
    assert Disturbance().link is None and load_group("disturbance", "push")[
        "disturbance"]["link"] is None
    panda = robot_spec_from_config(robot_config("panda"))
    assert panda.impedance is None
    with pytest.raises(ConfigError, match=r"sim\.control .*robot panda.*robot\.impedance"):
        run_config(compose("sweep", ["robot=panda", "disturbance=impedance"]))
    with pytest.raises(ValueError, match=r"robot\.impedance"):
        with Simulator(panda, SimConfig(control="impedance")):
            pass
