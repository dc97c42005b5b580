"""The 2-D point-mass world: its integration law, identity kinematics and the episode loop."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

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
    assert free.metrics.success and free.stop_reason == "converged"
    assert np.linalg.norm(free.ee_position[-1, :2] - POINT_GOAL) <= 0.05
    blocked = run_episode(point_scenario(), _Attractor(), PointMassWorld())
    assert blocked.metrics.collided and not blocked.metrics.success


def test_the_run_continues_for_the_settle_time_after_the_first_reach():
    sc = point_scenario(obstacles=False)
    plain = run_episode(sc, _Attractor(), PointMassWorld())
    settle = 12.0  # longer than the attractor takes to come to rest
    settled = run_episode(sc, _Attractor(), PointMassWorld(), settle_time=settle)
    reach = round(plain.metrics.time_to_success_s / sc.dt)
    assert settled.metrics.steps == reach + round(settle / sc.dt) + 1
    assert settled.stop_reason == "converged" and settled.metrics.settle_time_s == settle
    np.testing.assert_array_equal(settled.q[: plain.metrics.steps], plain.q)  # only longer
    assert settled.metrics.time_to_success_s == plain.metrics.time_to_success_s


class _PassThrough:
    """Drives the point at constant speed through the goal and on: it reaches, never rests."""

    def reset(self, scenario):
        self.direction = None

    def step(self, obs):
        if self.direction is None:
            d = obs.goal_position[:2] - obs.q
            self.direction = d / np.linalg.norm(d)
        return Command(qdd=(1.0 * self.direction - obs.qd) / 0.02)


class _Hover:
    """Tracks a 1 Hz circle of 2 cm radius round the goal: inside the ball, never at rest."""

    def reset(self, scenario):
        pass

    def step(self, obs):
        w = 2 * np.pi
        target = obs.goal_position[:2] + 0.02 * np.array([np.cos(w * obs.t), np.sin(w * obs.t)])
        vt = 0.02 * w * np.array([-np.sin(w * obs.t), np.cos(w * obs.t)])
        return Command(qdd=25.0 * (target - obs.q) + 10.0 * (vt - obs.qd))


def test_a_hand_passing_through_the_ball_reached_but_did_not_converge():
    run = run_episode(point_scenario(obstacles=False), _PassThrough(), PointMassWorld())
    m = run.metrics
    assert m.success_paper and m.success_whole_body  # the paper's criterion: reached
    assert not m.converged_paper and not m.converged_whole_body
    assert m.left_after_reach and m.max_error_after_reach_m > 1.0
    assert run.stop_reason == "max_steps" and np.isnan(m.rest_time_s)


def test_a_hand_hovering_in_the_ball_does_not_converge_and_a_resting_one_does():
    sc = point_scenario(obstacles=False)
    hover = run_episode(sc, _Hover(), PointMassWorld()).metrics
    assert hover.success_paper and not hover.left_after_reach
    assert not hover.converged_paper
    rest = run_episode(sc, _Attractor(), PointMassWorld())
    m = rest.metrics
    assert m.converged_paper and m.converged_whole_body and not m.left_after_reach
    assert m.time_to_success_s < m.rest_time_s <= rest.t[-1]
    # at rest: the last rest window moved less than the rest distance
    window = rest.ee_position[rest.t >= rest.t[-1] - 1.0 + 1e-9]
    assert np.linalg.norm(window - rest.ee_position[-1], axis=1).max() <= 0.005


class _Log:
    """A recorder that notes what happened to it; ``fail_open`` raises from its open (as an
    interrupt that lands while a slow recorder starts)."""

    def __init__(self, fail_open=None):
        self.fail_open, self.events = fail_open, []

    def open(self, info):
        self.events.append("open")
        if self.fail_open is not None:
            raise self.fail_open

    def write(self, record):
        self.events.append("write")

    def close(self, complete, summary):
        self.events.append(("close", complete, summary["stop_reason"]))


def test_an_interrupt_while_a_recorder_opens_closes_the_logs_already_open():
    first, second, never = _Log(), _Log(fail_open=KeyboardInterrupt()), _Log()
    with pytest.raises(KeyboardInterrupt):
        run_episode(point_scenario(), _Attractor(), PointMassWorld(), [first, second, never])
    assert first.events == ["open", ("close", False, "interrupted")]
    assert second.events == ["open", ("close", False, "interrupted")]  # half open: closed too
    assert never.events == []


def test_both_worlds_are_what_the_episode_loop_drives():
    """PyBullet's arm and the point robot implement :class:`tamedpuma.types.World` (every
    method and property of the protocol), so the loop needs no adapter."""
    from tamedpuma.types import World
    from tamedpuma.worlds.bullet import Simulator

    members = {n for n in vars(World) if not n.startswith("_")}
    assert members >= {"reset", "step", "contacts", "obstacle_centers", "disturbance_time"}
    for world in (Simulator, PointMassWorld):
        assert all(hasattr(world, n) for n in members), world
        assert isinstance(vars(world)["disturbance_time"], property), world
    world = PointMassWorld()
    world.reset(point_scenario())
    assert world.disturbance_time is None
    np.testing.assert_array_equal(world.obstacle_centers(), world.observe().obstacle_centers)


class _Finaliser:
    """Sends this process SIGTERM from its finaliser, where Python loses the handler's exception
    ("Exception ignored in ... __del__"), as a SIGTERM landing during garbage collection does."""

    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(100):  # bytecode after the kill: the handler runs in here
            pass


class _SignalledAtStep:
    """The attractor, whose fifth step drops a :class:`_Finaliser`."""

    def reset(self, scenario):
        self.k = 0

    def step(self, obs):
        self.k += 1
        if self.k == 5:
            _Finaliser()  # unreferenced: finalised at once
        return _Attractor().step(obs)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_sigterm_lost_in_a_finaliser_still_ends_the_run_at_the_next_step():
    from tamedpuma import termination
    from tamedpuma.app import sweep

    log = _Log()
    previous = signal.signal(signal.SIGTERM, sweep._terminated_main)
    try:
        with pytest.raises(SystemExit) as raised:
            run_episode(point_scenario(), _SignalledAtStep(), PointMassWorld(), [log])
    finally:
        signal.signal(signal.SIGTERM, previous)
        termination.clear()
    assert raised.value.code == 143
    assert log.events == ["open", *["write"] * 5, ("close", False, "interrupted")]
