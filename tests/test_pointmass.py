"""The 2-D point-mass world: its integration law, identity kinematics and the episode loop."""

from __future__ import annotations

import numpy as np

from tamedpuma.episode import run_episode
from tamedpuma.types import Command
from tamedpuma.worlds.pointmass import (
    POINT_GOAL,
    PointKinematics,
    PointMassWorld,
    point_scenario,
    point_spec,
)


class _Attractor:
    def reset(self, scenario):
        pass

    def step(self, obs):
        return Command(qdd=-2.0 * (obs.q - obs.goal_position[:2]) - 3.0 * obs.qd)


def test_world_integrates_the_velocity_control_law():
    world = PointMassWorld()
    sc = point_scenario()
    world.reset(sc)
    obs = world.step(np.array([1.0, -500.0]))
    np.testing.assert_allclose(obs.qd, [0.02, -2.0])  # clipped at the speed limit
    np.testing.assert_allclose(obs.q, obs.qd * sc.dt)


def test_identity_kinematics():
    kin = PointKinematics(point_spec())
    s = kin.evaluate(np.array([1.0, 2.0]), np.array([3.0, 4.0]))
    np.testing.assert_array_equal(s.ee_position, [1, 2, 0])
    np.testing.assert_array_equal(s.ee_jacobian[:3] @ [3.0, 4.0], [3, 4, 0])
    np.testing.assert_array_equal(s.sphere_jacobians[0] @ [3.0, 4.0], [3, 4, 0])


def test_straight_attractor_reaches_the_goal_but_hits_the_obstacle():
    free = run_episode(point_scenario(obstacles=False), _Attractor(), PointMassWorld())
    assert free.metrics.success and free.stop_reason == "goal_reached"
    assert np.linalg.norm(free.ee_position[-1, :2] - POINT_GOAL) <= 0.05
    blocked = run_episode(point_scenario(), _Attractor(), PointMassWorld())
    assert blocked.metrics.collided and not blocked.metrics.success


def test_the_run_continues_for_the_settle_time_after_the_first_reach():
    sc = point_scenario(obstacles=False)
    plain = run_episode(sc, _Attractor(), PointMassWorld())
    settled = run_episode(sc, _Attractor(), PointMassWorld(), settle_time=1.0)
    reach = plain.metrics.steps - 1
    assert settled.metrics.steps == plain.metrics.steps + round(1.0 / sc.dt)
    assert settled.stop_reason == "goal_reached" and settled.metrics.settle_time_s == 1.0
    np.testing.assert_array_equal(settled.q[: reach + 1], plain.q)  # same run, only longer
    assert settled.metrics.time_to_success_s == plain.metrics.time_to_success_s
