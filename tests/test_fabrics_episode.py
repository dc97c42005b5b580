"""Vanilla Fabrics in PyBullet: the tomato default scenario end to end (acceptance)."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.app.config import load_group, start_options, typed_scenario
from tamedpuma.app.schema import method_settings
from tamedpuma.episode import run_episode
from tamedpuma.methods import make
from tamedpuma.worlds.bullet import Simulator
from tamedpuma.worlds.scenarios import scenario_from_config


def _tomato_default(robot_spec):
    cfg = load_group("scenario", "default")
    task = load_group("task", "tomato")
    cfg["goal"].update(position=task["goal_position"], quaternion=task["goal_quaternion"])
    return scenario_from_config(typed_scenario(cfg), robot_spec, task="tomato", **start_options())


@pytest.mark.slow
def test_fabrics_reaches_the_tomato_goal_without_collision(robot_spec, kinematics):
    scenario = _tomato_default(robot_spec)
    # The scenario the issue names: default start, two static obstacles, the tomato goal.
    np.testing.assert_allclose(scenario.q0, [-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])
    np.testing.assert_allclose(scenario.obstacles.centers,
                               [[0.5, -0.30, 0.5], [0.24355761, 0.45252747, 0.2]])
    assert np.all(scenario.obstacles.velocities == 0)
    np.testing.assert_allclose(scenario.goal.position, [0.58, -0.214, 0.115])
    controller = make("fabrics", method_settings({"name": "fabrics"}), kinematics)
    with Simulator(robot_spec) as sim:
        result = run_episode(scenario, controller, sim)
    m = result.metrics
    assert m.success and m.final_position_error_m <= 0.05, result.stop_reason
    assert not m.collided and not m.obstacle_contact
    assert m.min_clearance_m > 0.0          # no body sphere penetrates an obstacle
    assert m.joint_limit_violation_steps == 0
    assert np.all(result.q >= robot_spec.q_min) and np.all(result.q <= robot_spec.q_max)
