"""The random scenario generator: deterministic per seed, every scenario valid, and
reachable from the sweep's config (``scenario=random``)."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.app.config import load_group, robot_config, table1_starts
from tamedpuma.app.schema import ScenarioSchema
from tamedpuma.errors import ScenarioError
from tamedpuma.robot.ik import solve_pose_ik
from tamedpuma.worlds.random_scenarios import (
    REJECT_REASONS,
    START_KINDS,
    RandomParams,
    TaskRegion,
    generate,
    scenario_config,
)
from tamedpuma.worlds.scenarios import build_scenario


def _region(task):
    from tamedpuma.app.schema import TaskSchema, typed

    return TaskRegion.from_task_config(typed(TaskSchema, load_group("task", task), "task"))


#: the scenario's own settings, as the schema's defaults give them to a random scenario
EPISODE = {"dt": ScenarioSchema.dt, "max_steps": ScenarioSchema.max_steps,
           "goal_tolerance": ScenarioSchema.goal_tolerance}


def _angle(a, b):
    return 2.0 * np.arccos(min(1.0, abs(float(a @ b))))


@pytest.mark.parametrize("task", ["tomato", "pouring"])
@pytest.mark.parametrize("kind", START_KINDS)
def test_every_generated_scenario_is_valid(kinematics, task, kind):
    region, params = _region(task), RandomParams()
    spec, horizon = kinematics.spec, EPISODE["max_steps"] * EPISODE["dt"]
    for seed in range(25):
        g = generate(region, kinematics, seed, params, table1_starts(task), start_kind=kind,
                     **EPISODE)
        sc = g.scenario
        assert (sc.dt, sc.max_steps, sc.goal_tolerance) == tuple(EPISODE.values())
        assert set(g.rejected) <= set(REJECT_REASONS)
        assert sum(g.rejected.values()) == g.tries - 1
        assert np.all(sc.q0 >= spec.q_min + params.limit_margin)
        assert np.all(sc.q0 <= spec.q_max - params.limit_margin)
        ee_p, ee_quat = kinematics.ee_pose(sc.q0)
        rel = ee_p - sc.goal.position
        assert np.all(rel >= region.position_low) and np.all(rel <= region.position_high)
        assert _angle(ee_quat, sc.goal.quaternion) <= region.max_angle
        assert np.linalg.norm(sc.goal.position - region.goal_position) <= params.goal_shift_max
        assert np.linalg.norm(sc.goal.velocity) <= params.goal_speed_max
        assert sc.goal.velocity[2] == 0
        obs = sc.obstacles
        assert 1 <= len(obs) <= 2
        assert np.all((obs.radii >= 0.04) & (obs.radii <= 0.07))
        assert np.all(obs.centers[:, 2] >= obs.radii)
        centers = kinematics.sphere_centers(sc.q0)
        assert np.min(centers[:, 2] - spec.sphere_radii) >= params.ground_clearance
        gaps = (np.linalg.norm(centers[:, None] - obs.centers[None], axis=-1)
                - spec.sphere_radii[:, None] - obs.radii[None])
        assert gaps.min() >= params.start_clearance
        for t in np.linspace(0.0, horizon, 41):
            d = np.linalg.norm(obs.at(t) - sc.goal.at(t), axis=1) - obs.radii
            assert d.min() >= params.goal_clearance - 1e-9
        # the goal pose stays within reach: solved afresh at the end of the episode
        end = solve_pose_ik(kinematics, sc.goal.at(horizon), sc.goal.quaternion, sc.q0,
                            tolerance=1e-4, margin=params.limit_margin, restarts=32, seed=7)
        assert end.converged, (seed, end.position_error, end.orientation_error)


def test_a_goal_that_moves_out_of_reach_is_redrawn(kinematics):
    """A goal moving at up to 10 m/s leaves the arm's reach within the 40 s episode in every
    draw of this seed: no scenario, the draws counted as ``goal_unreachable``; over 1 s one of
    them stays within reach."""
    region, starts = _region("pouring"), table1_starts("pouring")
    params = RandomParams(goal_moving_prob=1.0, goal_speed_max=10.0, max_tries=300)
    with pytest.raises(ScenarioError, match="goal_unreachable"):
        generate(region, kinematics, 3, params, starts, start_kind="near_table1", **EPISODE)
    short = {**EPISODE, "max_steps": 2}
    sc = generate(region, kinematics, 3, params, starts, start_kind="near_table1",
                  **short).scenario
    assert np.linalg.norm(sc.goal.velocity) > 0


def test_same_seed_same_scenario_other_seed_other_scenario(kinematics):
    region, starts = _region("tomato"), table1_starts("tomato")
    params = RandomParams()

    def draw(seed, kind="near_table1"):
        return scenario_config(generate(region, kinematics, seed, params, starts,
                                        start_kind=kind, **EPISODE).scenario)

    a, b, c, d = draw(7), draw(7), draw(8), draw(7, "anywhere")
    assert a == b
    assert a["q0"] != c["q0"] and a["q0"] != d["q0"]


def test_a_process_draws_a_scenario_once_and_hands_out_the_same_frozen_one(kinematics,
                                                                        monkeypatch):
    from tamedpuma.worlds import random_scenarios, scenarios

    monkeypatch.setattr(scenarios, "_GENERATED", {})
    drawn = []

    def counted(*args, **kwargs):
        drawn.append(args[2])
        return generate(*args, **kwargs)
    monkeypatch.setattr(random_scenarios, "generate", counted)
    region, starts = _region("tomato"), table1_starts("tomato")

    def draw(seed, kind="near_table1", params=None):
        return scenarios._generated(region, kinematics, seed, params or RandomParams(), starts,
                                    start_kind=kind, **EPISODE).scenario

    first = draw(7)
    assert draw(7) is first and drawn == [7]  # with and without its obstacles: one draw
    assert draw(8) is not first and draw(7, "anywhere") is not first
    assert draw(7, params=RandomParams(lateral_max=0.05)) is not first
    assert drawn == [7, 8, 7, 7]
    assert scenario_config(first) == scenario_config(generate(
        region, kinematics, 7, RandomParams(), starts, start_kind="near_table1",
        **EPISODE).scenario)
    for seed in (9, 10, 11, 12):  # the last few are kept, the oldest dropped
        draw(seed)
    assert len(scenarios._GENERATED) == scenarios._GENERATED_KEPT
    draw(7)
    assert drawn[-1] == 7 and len(drawn) == 9


def test_near_table1_starts_lie_near_a_table1_start(kinematics):
    starts = np.array(table1_starts("pouring"))
    assert starts.shape == (15, 7)
    params = RandomParams()
    dist = [np.min(np.linalg.norm(starts - generate(
        _region("pouring"), kinematics, s, params, starts, start_kind="near_table1",
        **EPISODE).scenario.q0, axis=1)) for s in range(20)]
    assert np.median(dist) < 0.3 * np.sqrt(7) * 1.5  # σ = 0.3 per joint


def test_impossible_parameters_raise_with_the_counted_reasons(kinematics):
    params = RandomParams(goal_clearance=5.0, max_tries=50)
    with pytest.raises(ScenarioError, match="goal_blocked|workspace"):
        generate(_region("tomato"), kinematics, 0, params, start_kind="anywhere", **EPISODE)
    with pytest.raises(ScenarioError, match="start_kind"):
        generate(_region("tomato"), kinematics, 0, RandomParams(), start_kind="somewhere",
                 **EPISODE)
    with pytest.raises(ValueError, match="radius_range"):
        RandomParams(radius_range=(0.07, 0.04))


def test_scenario_random_config_builds_the_generated_scenario(kinematics):
    from omegaconf import OmegaConf

    from tamedpuma.app.schema import run_config

    cfg = {"robot": robot_config("iiwa14"), "task": load_group("task", "pouring"),
           "scenario": load_group("scenario", "random"), "seed": 0,
           "without_obstacles": False, "clutter": {"count": 0, "total": None}}
    cfg["scenario"].update(random_seed=1003, start_kind="anywhere")
    plain = run_config({**OmegaConf.to_container(OmegaConf.create(cfg), resolve=True),
                        "method": {"name": "fpm"}})
    sc = build_scenario(plain, kinematics.spec, kinematics)
    assert sc.name == "random_pouring_anywhere_1003"
    ref = generate(_region("pouring"), kinematics, 1003, RandomParams(), start_kind="anywhere",
                   **EPISODE)
    np.testing.assert_array_equal(sc.q0, ref.scenario.q0)
    np.testing.assert_array_equal(sc.obstacles.centers, ref.scenario.obstacles.centers)


def test_near_table1_draws_around_the_starts_the_app_layer_hands_down(kinematics):
    """worlds reads no config file: the Table-1 starts come from the caller (the sweep passes
    :func:`tamedpuma.app.config.table1_starts`); without them near_table1 is refused."""
    from omegaconf import OmegaConf

    from tamedpuma.app.schema import run_config

    cfg = {"robot": robot_config("iiwa14"), "task": load_group("task", "pouring"),
           "scenario": load_group("scenario", "random"), "seed": 0,
           "without_obstacles": False, "clutter": {"count": 0, "total": None}}
    cfg["scenario"].update(random_seed=1003, start_kind="near_table1")
    plain = run_config({**OmegaConf.to_container(OmegaConf.create(cfg), resolve=True),
                        "method": {"name": "fpm"}})
    asked = []
    sc = build_scenario(plain, kinematics.spec, kinematics,
                        table1_starts=lambda task: asked.append(task) or table1_starts(task))
    assert asked == ["pouring"] and len(table1_starts("pouring")) > 0
    ref = generate(_region("pouring"), kinematics, 1003, RandomParams(), table1_starts("pouring"),
                   start_kind="near_table1", **EPISODE)
    np.testing.assert_array_equal(sc.q0, ref.scenario.q0)
    with pytest.raises(ScenarioError, match="Table-1 starts"):
        build_scenario(plain, kinematics.spec, kinematics)
