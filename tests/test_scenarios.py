"""Scenario configs: parsing, validation and start clamping."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from tamedpuma.app.config import load_group, robot_config, start_options, typed_scenario
from tamedpuma.errors import ConfigError, ScenarioError
from tamedpuma.worlds.scenarios import clamp_start, scenario_from_config

POURING_STARTS_PAST_LIMIT = [  # experiments.md: pouring #2, #3 (also #7, #8)
    [-0.06968, -2.0944, 1.25021, 1.91157, -0.902882, 0.387756, 1.26118],
    [0.487286, -2.0944, 1.46101, 1.53229, -0.980283, 0.194411, 1.53735],
]


def _default_cfg():
    cfg = load_group("scenario", "default")
    task = load_group("task", "tomato")
    cfg["goal"]["position"] = task["goal_position"]
    cfg["goal"]["quaternion"] = task["goal_quaternion"]
    return cfg


def test_default_scenario_parses(robot_spec):
    sc = scenario_from_config(typed_scenario(_default_cfg()), robot_spec,
                              task="tomato", **start_options())
    assert sc.q0.shape == (7,) and len(sc.obstacles) == 2
    np.testing.assert_allclose(sc.obstacles.at(1.0), sc.obstacles.centers)
    assert abs(np.linalg.norm(sc.goal.quaternion) - 1) < 1e-12


@pytest.mark.parametrize("q0", POURING_STARTS_PAST_LIMIT)
def test_paper_starts_past_a_limit_are_clamped_inside_with_a_warning(robot_spec, q0, caplog):
    with caplog.at_level(logging.WARNING):
        q = clamp_start(np.array(q0), robot_spec, tolerance=1e-4, margin=1e-3)
    assert np.all(q > robot_spec.q_min) and np.all(q < robot_spec.q_max)
    assert q[1] == pytest.approx(robot_spec.q_min[1] + 1e-3)
    np.testing.assert_array_equal(np.delete(q, 1), np.delete(q0, 1))
    assert "outside joint 2's limit" in caplog.text


def test_start_far_outside_the_limits_is_an_error(robot_spec):
    q0 = np.zeros(7)
    q0[3] = 2.2
    with pytest.raises(ScenarioError, match="outside joint 4's limits"):
        clamp_start(q0, robot_spec, tolerance=1e-4, margin=1e-3)


@pytest.mark.parametrize("bad", [
    {"q0": [0.0] * 6},
    {"q0": [0.0, float("nan"), 0, 0, 0, 0, 0]},
    {"obstacles": [{"center": [0, 0], "radius": 0.05}]},
    {"obstacles": [{"center": [0, 0, 1], "radius": 0.0}]},
    {"goal": {"position": [0, 0, 1], "quaternion": [0, 0, 0, 0]}},
])
def test_invalid_scenarios_raise_scenario_error(robot_spec, bad):
    cfg = {**_default_cfg(), **bad}
    with pytest.raises((ScenarioError, ConfigError)):  # the schema's checks or the world's
        scenario_from_config(typed_scenario(cfg), robot_spec, task="tomato", **start_options())


def _run_cfg(clutter=None, scenario=None, **top):
    """The typed run config of the default scenario on tomato (iiwa14, FPM), with ``clutter``
    and ``scenario`` keys and top-level keys changed."""
    from tamedpuma.app.schema import run_config

    cfg = {"robot": robot_config("iiwa14"), "task": load_group("task", "tomato"),
           "scenario": {**_default_cfg(), **(scenario or {})}, "method": {"name": "fpm"},
           "clutter": clutter or {}, **top}
    return run_config(cfg)


def test_clutter_is_seeded_and_keeps_clear_of_start_and_goal(robot_spec, kinematics):
    from tamedpuma.worlds.scenarios import build_scenario

    cfg = _run_cfg(clutter={"count": 300})
    a = build_scenario(cfg, robot_spec, kinematics)
    b = build_scenario(cfg, robot_spec, kinematics)
    c = build_scenario(_run_cfg(clutter={"count": 300}, seed=1), robot_spec, kinematics)
    assert len(a.obstacles) == 302
    np.testing.assert_array_equal(a.obstacles.centers, b.obstacles.centers)
    assert not np.array_equal(a.obstacles.centers, c.obstacles.centers)
    extra = a.obstacles.centers[2:]
    keep = np.concatenate([kinematics.sphere_centers(a.q0), a.goal.position[None]])
    assert (np.linalg.norm(extra[:, None] - keep[None], axis=-1) - 0.05 >= 0.1).all()
    assert np.all(extra >= [-1.2, -1.2, 0.05]) and np.all(extra <= [1.2, 1.2, 1.4])


def test_without_obstacles_and_task_mismatch(robot_spec, kinematics):
    from tamedpuma.worlds.scenarios import build_scenario

    assert len(build_scenario(_run_cfg(without_obstacles=True), robot_spec, kinematics)
               .obstacles) == 0
    cfg = _run_cfg(scenario={"task": "pouring"})
    with pytest.raises(ScenarioError, match="belongs to task 'pouring'"):
        build_scenario(cfg, robot_spec, kinematics)


@pytest.mark.parametrize("task", ["tomato", "pouring"])
def test_all_table1_scenarios_load(robot_spec, task):
    from tamedpuma.app.config import CONF_DIR

    files = sorted((CONF_DIR / "scenario" / task).glob("*.yaml"))
    assert len(files) == 15
    for f in files:
        cfg = load_group("scenario", f"{task}/{f.stem}")
        sc = scenario_from_config(typed_scenario(cfg), robot_spec, task=task, **start_options())
        assert 1 <= len(sc.obstacles) <= 2 and sc.name == f"{task}_{f.stem}"


@pytest.mark.parametrize("task", ["tomato", "pouring"])
def test_task_workspace_covers_every_scenario_start(robot_spec, kinematics, task):
    """PUMA is trained (stability, compatibility) only inside the task's workspace; a start
    outside it met an untrained, incompatible field (CPM stalled on tomato 12 and 13)."""
    from tamedpuma.robot.rotations import quat_to_matrix, rotation_error

    ws = load_group("task", task)["workspace"]
    low, high = np.array(ws["position_low"]), np.array(ws["position_high"])
    names = ["default"] + [f"{task}/{i:02d}" for i in range(15)]
    for name in names:
        cfg = load_group("scenario", name)
        if name == "default":
            t = load_group("task", task)
            cfg["goal"].update(position=t["goal_position"], quaternion=t["goal_quaternion"])
        sc = scenario_from_config(typed_scenario(cfg), robot_spec, task=task, **start_options())
        state = kinematics.evaluate(sc.q0, np.zeros(robot_spec.dof))
        e = state.ee_position - sc.goal.position
        assert np.all(e > low) and np.all(e < high), (name, e)
        angle = np.linalg.norm(rotation_error(quat_to_matrix(state.ee_quaternion),
                                              quat_to_matrix(sc.goal.quaternion)))
        assert angle < ws["max_angle"], (name, angle)
