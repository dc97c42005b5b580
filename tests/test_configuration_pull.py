"""The configuration pull (``method.forcing.configuration_pull``,
:mod:`tamedpuma.methods._configuration_pull`): its goal configuration, when it engages and lets
go, and the joint-limit trap it removes, in PyBullet with FPM around a globally stable
task-space pose attractor standing in for PUMA (no trained model needed)."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import tamedpuma.methods._configuration_pull as cpull
import tamedpuma.methods._tamed as tamed
from tamedpuma import methods
from tamedpuma.app.config import load_group, start_options, typed_scenario
from tamedpuma.app.schema import method_settings
from tamedpuma.episode import run_episode
from tamedpuma.errors import ConfigError
from tamedpuma.methods._configuration_pull import (
    VIA_RADIUS,
    ConfigurationMonitor,
    ConfigurationPull,
    Ground,
    PoseSolutions,
    _segment_clear,
    goal_candidates,
    goal_configuration,
    goal_route,
)
from tamedpuma.methods._policy import PoseTask, TaskAcceleration
from tamedpuma.methods._stall import StallMonitor, StallPull
from tamedpuma.methods._tamed import Forcing
from tamedpuma.methods.cpm import CpmController
from tamedpuma.robot.ground import (
    hull_ground_rows,
    hull_heights,
    hull_heights_and_spheres,
    link_hulls,
)
from tamedpuma.robot.ik import pose_dls, run_to_end
from tamedpuma.robot.rotations import quat_to_matrix, rotation_error
from tamedpuma.types import Obstacles
from tamedpuma.worlds.bullet import Disturbance, SimConfig, Simulator
from tamedpuma.worlds.scenarios import scenario_from_config

#: the whole search in one step; straight segments only, and not engaging near the goal
PULL = ConfigurationPull(budget=0, near_release=0.0, waypoints=0)


def test_the_goal_configuration_reaches_the_pose_inside_the_limits_clear_of_everything(
        kinematics):
    spec = kinematics.spec
    rng = np.random.default_rng(3)
    found = 0
    for _ in range(4):
        target = rng.uniform(spec.q_min + 0.3, spec.q_max - 0.3)
        p_goal, rot_goal = kinematics.ee_frame(target)
        if p_goal[2] < 0.25:
            continue
        quat = kinematics.evaluate(target, np.zeros(7)).ee_quaternion
        q = rng.uniform(spec.q_min + 0.1, spec.q_max - 0.1)
        obstacle = p_goal + np.array([0.0, 0.0, 0.25])  # 25 cm above the goal, r = 5 cm
        qg = goal_configuration(kinematics, p_goal, quat, q, obstacle[None], np.array([0.05]),
                                PULL)
        assert qg is not None
        found += 1
        p, rot = kinematics.ee_frame(qg)
        assert np.linalg.norm(p - p_goal) < 1e-3
        assert np.linalg.norm(rotation_error(rot, rot_goal)) < 1e-3
        assert np.all(qg >= spec.q_min + PULL.margin - 1e-12)
        assert np.all(qg <= spec.q_max - PULL.margin + 1e-12)
        spheres = kinematics.sphere_centers(qg)
        radii = np.asarray(kinematics.sphere_radii)
        gaps = np.linalg.norm(spheres - obstacle, axis=1) - radii - 0.05
        assert gaps.min() >= PULL.clearance
        assert np.all(spheres[:, 2] - radii >= PULL.clearance)
        # deterministic, and no farther from q than the solution started from q alone
        again = goal_configuration(kinematics, p_goal, quat, q, obstacle[None],
                                   np.array([0.05]), PULL)
        np.testing.assert_array_equal(qg, again)
        local = goal_configuration(kinematics, p_goal, quat, q, obstacle[None],
                                   np.array([0.05]), replace(PULL, restarts=0))
        if local is not None and np.linalg.norm(rotation_error(kinematics.ee_frame(local)[1],
                                                               rot_goal)) < 1e-3:
            # (q's own solution of the pose, where it is clear; else one of the position)
            assert np.linalg.norm(qg - q) <= np.linalg.norm(local - q) + 1e-12
    assert found >= 2


def test_an_unreachable_pose_gives_no_goal_configuration(kinematics):
    quat = np.array([0.0, 0.0, 0.0, 1.0])
    assert goal_configuration(kinematics, np.array([3.0, 0.0, 0.5]), quat, np.zeros(7),
                              np.zeros((0, 3)), np.zeros(0), replace(PULL, restarts=2)) is None


def _blocked(monitor, obs) -> bool:
    """Whether no prepared solution of the goal pose is clear of ``obs``'s obstacles (the
    judgement the monitor's search makes)."""
    return not run_to_end(cpull._clear_of_obstacles(
        monitor.kin, monitor.solutions, np.zeros(7), np.asarray(obs.obstacle_centers, float),
        np.asarray(obs.obstacle_radii, float), monitor.pull, position=False))


def _stall(t_armed, distance, stuck=False):
    return SimpleNamespace(t_armed=t_armed, armed=t_armed is not None, distance=distance,
                           hold=lambda held: None, stuck=lambda t: stuck)


def _goal_without_obstacles(kinematics, t=0.0):
    """An observation at time t [s] of a reachable goal pose with no obstacles, and a stand-in
    for PUMA's task rows (what the monitor returns untouched while it does not act)."""
    q_goal = np.array([-0.5, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
    p_goal, _ = kinematics.ee_frame(q_goal)
    quat = kinematics.evaluate(q_goal, np.zeros(7)).ee_quaternion
    obs = SimpleNamespace(t=t, goal_position=p_goal, goal_quaternion=quat,
                          obstacle_centers=np.zeros((0, 3)), obstacle_radii=np.zeros(0))
    return obs, TaskAcceleration(np.ones(6), np.zeros((6, 7)), np.zeros(6))


def test_the_monitor_engages_once_per_arming_and_lets_go_near_the_goal(kinematics):
    spec = kinematics.spec
    obs, task = _goal_without_obstacles(kinematics)
    monitor = ConfigurationMonitor(PULL, spec)
    free = np.array([1.0, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0])  # no joint within 0.1 rad of a limit
    at_limit = free.copy()
    at_limit[0] = spec.q_max[0] - 0.05
    qd = np.zeros(7)
    assert monitor.applied(at_limit, qd, 0.5, _stall(None, 0.5), obs, task) is task  # not armed
    monitor = ConfigurationMonitor(PULL, spec)
    spec_q = monitor.applied(at_limit, qd, 0.5, _stall(3.0, 0.5), obs, task)
    assert monitor.engaged and spec_q is not task
    np.testing.assert_array_equal(spec_q.J, np.eye(7))
    # at rest the attractor points at q_g with the constant pull g beyond ℓ
    e = monitor.q_goal - at_limit
    assert spec_q.xdd @ e > 0
    assert np.linalg.norm(spec_q.xdd) == pytest.approx(PULL.gain)
    # the same arming with the hand at the release distance: let go, and not again for it
    assert monitor.applied(at_limit, qd, PULL.release, _stall(3.0, 0.15), obs, task) is task
    assert monitor.applied(at_limit, qd, 0.5, _stall(3.0, 0.5), obs, task) is task
    # a new arming engages again; far from the goal no joint needs to be at a limit
    assert monitor.applied(at_limit, qd, 0.5, _stall(9.0, 0.5), obs, task) is not task
    free_monitor = ConfigurationMonitor(PULL, spec)
    assert free_monitor.applied(free, qd, 0.5, _stall(3.0, 0.5), obs, task) is not task


def test_near_the_goal_the_monitor_engages_only_with_a_near_release_and_lets_go_there(
        kinematics):
    spec = kinematics.spec
    obs, task = _goal_without_obstacles(kinematics)
    q = np.array([spec.q_max[0] - 0.05, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0])  # base at its limit
    qd = np.zeros(7)
    near = 0.5 * PULL.release  # armed inside the release distance
    assert ConfigurationMonitor(PULL, spec).applied(q, qd, near, _stall(3.0, near), obs,
                                                    task) is task  # near_release 0: never
    pull = replace(PULL, near_release=0.03)
    late = ConfigurationMonitor(pull, spec)  # near the goal only at the arming step
    assert late.applied(q, qd, near, _stall(-1.0, near), obs, task) is task
    monitor = ConfigurationMonitor(pull, spec)
    obs.t = 3.0
    assert monitor.applied(q, qd, near, _stall(3.0, near), obs, task) is not task
    assert monitor.release_at == pull.near_release
    # still engaged between near_release and release, let go within near_release
    assert monitor.applied(q, qd, 0.04, _stall(3.0, 0.04), obs, task) is not task
    assert monitor.applied(q, qd, 0.03, _stall(3.0, 0.03), obs, task) is task
    # armed within near_release: nothing to do
    inside = ConfigurationMonitor(pull, spec)
    assert inside.applied(q, qd, 0.02, _stall(3.0, 0.02), obs, task) is task
    # armed far away it engages any time while armed, and it too lets go only within
    # near_release (the arm nearly at rest), not at the release distance
    far = ConfigurationMonitor(pull, spec)
    assert far.applied(q, qd, 0.5, _stall(1.0, 0.5), obs, task) is not task
    assert far.release_at == pull.near_release
    assert far.applied(q, qd, pull.release, _stall(1.0, pull.release), obs, task) is not task
    assert far.applied(q, qd, pull.near_release, _stall(1.0, 0.03), obs, task) is task
    # without a near_release it lets go at the release distance
    plain = ConfigurationMonitor(PULL, spec)
    assert plain.applied(q, qd, 0.5, _stall(1.0, 0.5), obs, task) is not task
    assert plain.release_at == PULL.release
    assert plain.applied(q, qd, PULL.release, _stall(1.0, PULL.release), obs, task) is task
    # near the goal an arming engages only with a joint at a limit
    free = np.array([1.0, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0])  # no joint within 0.1 rad of a limit
    assert ConfigurationMonitor(pull, spec).applied(free, qd, near, _stall(3.0, near), obs,
                                                    task) is task
    assert ConfigurationMonitor(pull, spec).applied(q, qd, near, _stall(3.0, near), obs,
                                                    task) is not task


def test_a_search_the_hand_overtakes_leaves_its_arming_unserved(kinematics):
    """An arming whose search the hand overtakes (inside near_release before the search ends:
    nothing to engage for) is not served: when the hand is out again and the armed stall pull
    is stuck, the pull engages for it. Served, it never did: after a goal change FPM came to
    rest in the goal ball, drifted out with two joints at their limits and rested 6.7 cm from
    the goal to the end, the stall pull armed and the pull waiting for a new arming."""
    spec = kinematics.spec
    obs, task = _goal_without_obstacles(kinematics)
    q = np.array([spec.q_max[0] - 0.05, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0])  # base at its limit
    qd = np.zeros(7)
    pull = replace(PULL, near_release=0.03, budget=1)
    monitor = ConfigurationMonitor(pull, spec)
    obs.t = 3.0
    near = 0.5 * pull.release
    assert monitor.applied(q, qd, near, _stall(3.0, near), obs, task) is task
    assert monitor.search is not None  # one pass a step: the search goes on
    assert monitor.applied(q, qd, 0.02, _stall(3.0, 0.02), obs, task) is task
    assert monitor.search is None and not monitor.engaged  # overtaken, dropped
    obs.t = 6.0
    out = monitor.applied(q, qd, 0.06, _stall(3.0, 0.06), obs, task)
    assert out is task and monitor.search is None  # out again, the stall pull still moving
    for _ in range(5000):  # stuck: this arming's engagement, its search a pass a step
        out = monitor.applied(q, qd, 0.06, _stall(3.0, 0.06, stuck=True), obs, task)
        if out is not task:
            break
    assert monitor.engaged and out is not task
    np.testing.assert_array_equal(out.J, np.eye(7))


def test_position_only_ik_reaches_the_position_and_leaves_the_orientation_free(kinematics):
    spec = kinematics.spec
    target = np.array([0.4, 0.5, 0.2, -1.3, 0.3, 0.9, 0.4])
    p_goal, rot_goal = kinematics.ee_frame(target)
    lo, hi = spec.q_min + 0.1, spec.q_max - 0.1
    start = np.array([-0.3, 0.2, -0.4, -1.0, -0.5, 0.4, -1.0])
    q, err, _ = pose_dls(kinematics, p_goal, rot_goal, start, lo, hi, damping=0.05,
                         tolerance=1e-5, max_iterations=300, rotation_weight=0.0)
    p, rot = kinematics.ee_frame(q)
    assert np.linalg.norm(p - p_goal) < 1e-4
    np.testing.assert_array_equal(err[3:], 0.0)
    assert np.linalg.norm(rotation_error(rot, rot_goal)) > 0.05  # not the goal's orientation


def _blocked_pose(kinematics):
    """(goal position, quaternion, obstacle centres (1, 3), radii (1,)): a reachable goal pose
    with an obstacle on the body sphere rigid with the hand farthest from the task point, so
    that every solution of the pose collides with it."""
    target = np.array([0.2, 0.5, 0.0, -1.3, 0.0, 0.9, 0.3])
    p_goal, rot_goal = kinematics.ee_frame(target)
    quat = kinematics.evaluate(target, np.zeros(7)).ee_quaternion
    # the body spheres rigid with the hand sit where they are for every solution of the pose:
    # an obstacle on the one farthest from the task point collides with all of them
    other = goal_candidates(kinematics, p_goal, quat, np.zeros(7), np.zeros((0, 3)),
                            np.zeros(0), PULL, seed=5)
    assert len(other) >= 2
    centers = [kinematics.sphere_centers(qg) for qg in other]
    rigid = np.all([np.linalg.norm(c - centers[0], axis=1) < 1e-3 for c in centers], axis=0)
    reach = np.where(rigid, np.linalg.norm(centers[0] - p_goal, axis=1), -1.0)
    k = int(np.argmax(reach))
    assert reach[k] > 0.03
    r_k = kinematics.sphere_radii[k]
    out = (centers[0][k] - p_goal) / reach[k]
    obstacle = (centers[0][k] + out * r_k)[None]
    return p_goal, quat, obstacle, np.array([0.8 * r_k])


def test_where_every_solution_of_the_pose_collides_the_position_alone_frees_the_orientation(
        kinematics):
    p_goal, quat, obstacle, radius = _blocked_pose(kinematics)
    pull = replace(PULL, restarts=8)
    free = goal_candidates(kinematics, p_goal, quat, np.zeros(7), np.zeros((0, 3)),
                           np.zeros(0), pull)
    goal = quat_to_matrix(quat)
    assert free and all(np.linalg.norm(rotation_error(kinematics.ee_frame(qg)[1], goal)) < 0.01
                        for qg in free)  # without the obstacle: the pose's own solutions
    found = goal_candidates(kinematics, p_goal, quat, np.zeros(7), obstacle, radius, pull)
    assert found
    assert all(np.linalg.norm(rotation_error(kinematics.ee_frame(qg)[1], goal)) > 0.01
               for qg in found)  # the position's solutions, the orientation off the goal's
    for qg in found:
        p, _ = kinematics.ee_frame(qg)
        assert np.linalg.norm(p - p_goal) < 1e-3
        gap = np.min(np.linalg.norm(kinematics.sphere_centers(qg)[:, None] - obstacle[None],
                                    axis=2) - kinematics.sphere_radii[:, None] - radius)
        assert gap >= pull.clearance


def test_where_the_goal_pose_is_blocked_an_arming_near_the_goal_engages_on_the_position_and_holds(
        kinematics):
    """No clear configuration holds the goal pose: an arming within ``release`` engages without a
    joint at a limit once the stall pull has itself stopped making progress, towards the goal
    position alone solved from the arm's configuration (no farther from it than any prepared
    solution of the position), and holds there (PUMA, handed the arm back, would carry it into
    the obstacle again) until the pose comes clear; with the pose clear the same arming leaves
    PUMA's rows alone."""
    spec = kinematics.spec
    p_goal, quat, obstacle, radius = _blocked_pose(kinematics)
    pull = replace(PULL, restarts=8, near_release=0.03)
    found = goal_candidates(kinematics, p_goal, quat, np.zeros(7), obstacle, radius, pull)
    assert found
    q = found[0] + 0.03  # near the best solution, the segment to it clear
    qd = np.zeros(7)
    obs = SimpleNamespace(t=3.0, goal_position=p_goal, goal_quaternion=quat,
                          obstacle_centers=obstacle, obstacle_radii=radius)
    task = TaskAcceleration(np.ones(6), np.zeros((6, 7)), np.zeros(6))
    near = 0.5 * pull.release
    monitor = ConfigurationMonitor(pull, spec)
    monitor.prepare(p_goal, quat, np.zeros(7))
    assert not monitor.at_limit(q) and _blocked(monitor, obs)
    # not at the arming: first the stall pull itself must stop making progress
    assert monitor.applied(q, qd, near, _stall(3.0, near), obs, task) is task
    obs.t = 5.0
    assert monitor.applied(q, qd, near, _stall(3.0, near, stuck=True), obs, task) is not task
    assert monitor.engaged and monitor.holding
    p, _ = kinematics.ee_frame(monitor.q_goal)
    assert np.linalg.norm(p - p_goal) < 1e-3
    assert np.min(np.linalg.norm(kinematics.sphere_centers(monitor.q_goal)[:, None] - obstacle,
                                 axis=2) - kinematics.sphere_radii[:, None] - radius) >= 0.01
    assert np.linalg.norm(monitor.q_goal - q) <= min(np.linalg.norm(qg - q) for qg in found)
    # it does not let go within near_release, nor resting at q_g for longer than the window
    for t in (3.5, 4.0, 9.0):
        obs.t = t
        assert monitor.applied(monitor.q_goal, qd, 0.0, _stall(3.0, 0.0), obs,
                               task) is not task
    assert monitor.holding
    # the obstacle moves away: a window after the last check the pull turns to the pose
    obs.obstacle_centers, obs.t = obstacle + np.array([0.0, 0.0, 1.0]), 9.0 + pull.window
    assert monitor.applied(monitor.q_goal, qd, 0.05, _stall(3.0, 0.05), obs,
                           task) is not task
    assert monitor.engaged and not monitor.holding
    p, _ = kinematics.ee_frame(monitor.q_goal)
    assert np.linalg.norm(p - p_goal) < 1e-3 and not _blocked(monitor, obs)
    # the pose clear: the same arming engages not
    free = SimpleNamespace(**{**vars(obs), "t": 3.0, "obstacle_centers": np.zeros((0, 3)),
                              "obstacle_radii": np.zeros(0)})
    clear = ConfigurationMonitor(pull, spec)
    clear.prepare(p_goal, quat, np.zeros(7))
    assert not _blocked(clear, free)
    assert clear.applied(q, qd, near, _stall(3.0, near, stuck=True), free, task) is task


def _pose_the_prepared_solutions_miss(kinematics, pull):
    """(monitor, observation at t = 3 s, PUMA's stand-in rows, q): a goal pose whose one
    prepared solution is blocked by an obstacle while the pose solved from the arm's own
    configuration q (next to the target's) is clear."""
    target = np.array([0.2, 0.5, 0.0, -1.3, 0.0, 0.9, 0.3])
    p_goal, _ = kinematics.ee_frame(target)
    quat = kinematics.evaluate(target, np.zeros(7)).ee_quaternion
    other = goal_candidates(kinematics, p_goal, quat, np.zeros(7), np.zeros((0, 3)),
                            np.zeros(0), pull, seed=5)
    radii = np.asarray(kinematics.sphere_radii)
    own = kinematics.sphere_centers(target)
    # a solution of the pose with a body sphere far from every sphere of the target's: an
    # obstacle there blocks that solution and leaves the target clear
    far = [(np.min(np.linalg.norm(c - own, axis=1) - radii - r), qg, c)
           for qg in other for c, r in zip(kinematics.sphere_centers(qg), radii)]
    gap, blocked, centre = max(far, key=lambda f: f[0])
    assert gap > 0.1
    obs = SimpleNamespace(t=3.0, goal_position=p_goal, goal_quaternion=quat,
                          obstacle_centers=centre[None], obstacle_radii=np.array([0.05]))
    task = TaskAcceleration(np.ones(6), np.zeros((6, 7)), np.zeros(6))
    monitor = ConfigurationMonitor(pull, kinematics.spec)
    monitor.solutions = PoseSolutions(p_goal, quat, (blocked,), (target,))
    q = target + 0.02
    assert not monitor.at_limit(q) and _blocked(monitor, obs)
    return monitor, obs, task, q


def test_a_pose_the_prepared_solutions_miss_is_not_taken_for_blocked(kinematics):
    """The prepared solutions are a sample of the pose's self-motion: where all of them are
    blocked but the pose solved from the arm's own configuration is clear, an arming near the
    goal leaves PUMA's rows alone."""
    pull = replace(PULL, restarts=8, near_release=0.03)
    monitor, obs, task, q = _pose_the_prepared_solutions_miss(kinematics, pull)
    near = 0.5 * pull.release
    assert monitor.applied(q, np.zeros(7), near, _stall(3.0, near, stuck=True), obs,
                           task) is task
    assert not monitor.engaged and monitor.search is None


def test_far_from_a_blocked_pose_a_stuck_stall_pull_gets_a_second_search_on_the_position(
        kinematics):
    """Farther than ``release``: the arming's search, for the pose, finds no route where every
    solution of the pose is blocked, and PUMA keeps the arm; once the stall pull armed there is
    itself stuck the pull searches once more, as near the goal, and engages on the goal position
    alone; once per arming."""
    spec = kinematics.spec
    p_goal, quat, obstacle, radius = _blocked_pose(kinematics)
    pull = replace(PULL, restarts=8)
    found = goal_candidates(kinematics, p_goal, quat, np.zeros(7), obstacle, radius, pull)
    q, qd = found[0] + 0.03, np.zeros(7)
    far = 2.0 * pull.release
    obs = SimpleNamespace(t=3.0, goal_position=p_goal, goal_quaternion=quat,
                          obstacle_centers=obstacle, obstacle_radii=radius)
    task = TaskAcceleration(np.ones(6), np.zeros((6, 7)), np.zeros(6))
    monitor = ConfigurationMonitor(pull, spec)
    monitor.prepare(p_goal, quat, np.zeros(7))
    assert not monitor.at_limit(q) and _blocked(monitor, obs)
    assert monitor.applied(q, qd, far, _stall(3.0, far), obs, task) is task  # no route
    assert not monitor.engaged and monitor.served == 3.0
    obs.t = 4.0  # the stall pull still making progress: nothing more
    assert monitor.applied(q, qd, far, _stall(3.0, far), obs, task) is task
    obs.t = 5.0
    assert monitor.applied(q, qd, far, _stall(3.0, far, stuck=True), obs, task) is not task
    assert monitor.engaged and monitor.holding
    p, _ = kinematics.ee_frame(monitor.q_goal)
    assert np.linalg.norm(p - p_goal) < 1e-3
    # let go (as a barrier holding it would): the same arming gets no third search
    monitor.engaged = False
    obs.t = 8.0
    assert monitor.applied(q, qd, far, _stall(3.0, far, stuck=True), obs, task) is task
    assert monitor.search is None
    # a new arming far out is served again from the start (the pose first)
    obs.t = 12.0
    monitor.applied(q, qd, far, _stall(12.0, far), obs, task)
    assert monitor.served == 12.0 and not monitor.engaged


def test_far_out_a_pose_the_prepared_solutions_miss_gets_no_second_search_on_the_position(
        kinematics):
    """The second search far out engages only where the pose is blocked: where every prepared
    solution is blocked but the pose solved from the arm's own configuration is clear, the
    stuck stall pull's arming leaves PUMA's rows alone (as near the goal)."""
    pull = replace(PULL, restarts=8)
    monitor, obs, task, q = _pose_the_prepared_solutions_miss(kinematics, pull)
    far = 2.0 * pull.release
    assert monitor.applied(q, np.zeros(7), far, _stall(3.0, far), obs, task) is task
    obs.t = 5.0
    assert monitor.applied(q, np.zeros(7), far, _stall(3.0, far, stuck=True), obs,
                           task) is task
    assert not monitor.engaged and monitor.search is None and monitor.served_blocked == 3.0


def test_a_goal_configuration_behind_an_obstacle_on_the_straight_segment_is_not_chosen(
        kinematics):
    q = np.array([-0.5, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
    target = np.array([0.7, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])  # the base turned 1.2 rad
    p_goal, _ = kinematics.ee_frame(target)
    quat = kinematics.evaluate(target, np.zeros(7)).ee_quaternion
    free = goal_configuration(kinematics, p_goal, quat, q, np.zeros((0, 3)), np.zeros(0), PULL)
    assert free is not None
    # an obstacle where the hand passes half way along that segment, clear of both ends
    middle = kinematics.sphere_centers(0.5 * (q + free))[-1]
    centers, radii = middle[None], np.array([0.05])
    ground = Ground(PULL.clearance)
    assert not run_to_end(_segment_clear(kinematics, q, free, centers, radii, ground, 0.0))
    chosen = goal_configuration(kinematics, p_goal, quat, q, centers, radii, PULL)
    if chosen is not None:  # another solution, reached along a clear segment
        assert run_to_end(_segment_clear(kinematics, q, chosen, centers, radii, ground, 0.0))
        assert not np.allclose(chosen, free)


def test_hull_heights_at_a_configuration_are_the_ground_rows_heights(kinematics):
    hulls = link_hulls(kinematics)
    rng = np.random.default_rng(11)
    for _ in range(5):
        q = rng.uniform(kinematics.spec.q_min, kinematics.spec.q_max)
        kinematics.evaluate(q, np.zeros(7))
        rows = hull_ground_rows(kinematics, hulls, np.zeros(7))
        np.testing.assert_allclose(hull_heights(kinematics, hulls, q), rows.heights,
                                   atol=1e-12)


@pytest.mark.parametrize("geometry", ["mesh", "spheres"])
def test_a_goal_pose_reaching_below_the_ground_is_raised_just_above_it(kinematics, geometry):
    """A goal low over the table (the hand pointing down, its flange 2 cm into the ground at
    the goal pose): the goal configuration holds the goal orientation with the hand raised
    until every height the controller's ground rows keep is above the plane, by no more than
    the pull's release distance; with no raise allowed there is none."""
    ground = Ground(0.01, link_hulls(kinematics) if geometry == "mesh" else None)
    q_pose = np.array([0.0, 0.9, 0.0, -1.2, 0.0, 1.0, 0.0])  # the hand pointing down
    p_pose, rot = kinematics.ee_frame(q_pose)
    quat = kinematics.evaluate(q_pose, np.zeros(7)).ee_quaternion
    deficit = 0.02 + float(ground.margins(kinematics, q_pose)[-1])  # the hand's (last link's)
    goal = p_pose - np.array([0.0, 0.0, deficit])  # the hand 2 cm below the plane there
    q = np.array([0.3, 0.5, 0.0, -1.5, 0.0, 1.0, 0.0])
    found = goal_candidates(kinematics, goal, quat, q, np.zeros((0, 3)), np.zeros(0), PULL,
                            ground=ground)
    assert found
    for qg in found:
        p, r = kinematics.ee_frame(qg)
        assert np.min(ground.margins(kinematics, qg)) >= 0.0
        np.testing.assert_allclose(p[:2], goal[:2], atol=1e-3)
        assert 0.02 <= p[2] - goal[2] <= PULL.release
        assert np.linalg.norm(rotation_error(r, rot)) < 1e-3
    assert not goal_candidates(kinematics, goal, quat, q, np.zeros((0, 3)), np.zeros(0),
                               replace(PULL, release=0.01), ground=ground)


def test_a_route_through_a_waypoint_where_no_straight_segment_is_clear(kinematics):
    """The only goal configuration (no restarts) lies behind an obstacle on the straight
    segment: no straight route; with waypoints, q → w → q_g with both segments clear (checked
    densely here), w inside the limits and clear, the same route for the same seed."""
    q = np.array([-0.5, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
    target = np.array([0.7, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
    p_goal, _ = kinematics.ee_frame(target)
    quat = kinematics.evaluate(target, np.zeros(7)).ee_quaternion
    none = np.zeros((0, 3)), np.zeros(0)
    pull = replace(PULL, restarts=0, waypoints=32)
    (free,) = goal_route(kinematics, p_goal, quat, q, *none, pull)
    middle = kinematics.sphere_centers(0.5 * (q + free))[-1]
    centers, radii = middle[None], np.array([0.05])
    assert goal_route(kinematics, p_goal, quat, q, centers, radii,
                      replace(pull, waypoints=0)) is None
    route = goal_route(kinematics, p_goal, quat, q, centers, radii, pull)
    assert route is not None and len(route) == 2
    w, qg = route
    np.testing.assert_allclose(qg, free, atol=1e-9)
    spec, body_r = kinematics.spec, np.asarray(kinematics.sphere_radii)
    assert np.all(w >= spec.q_min + PULL.margin) and np.all(w <= spec.q_max - PULL.margin)
    for a, b in ((q, w), (w, qg)):
        for s in np.linspace(0.0, 1.0, 400):
            spheres = kinematics.sphere_centers(a + s * (b - a))
            assert np.min(np.linalg.norm(spheres - middle, axis=1) - body_r) >= 0.05 - 1e-3
            assert np.min(spheres[:, 2] - body_r) >= PULL.clearance - 1e-3
    again = goal_route(kinematics, p_goal, quat, q, centers, radii, pull)
    np.testing.assert_array_equal(np.concatenate(route), np.concatenate(again))


def test_the_monitor_turns_from_the_waypoint_to_the_goal_configuration(kinematics):
    monitor = ConfigurationMonitor(PULL, kinematics.spec)
    w = np.array([0.0, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
    qg = w + np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    monitor.q_goal, monitor.route, monitor.engaged = w, (qg,), True
    monitor.goal_for = np.zeros(3)
    obs = SimpleNamespace(t=1.0, goal_position=np.zeros(3))
    stall = _stall(0.0, 0.5)
    task = TaskAcceleration(np.ones(6), np.zeros((6, 7)), np.zeros(6))
    far = w - np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2 * VIA_RADIUS])
    toward = monitor.applied(far, np.zeros(7), 0.5, stall, obs, task).xdd
    assert toward[6] > 0 and abs(toward[0]) < 1e-12  # still towards w
    near = w - np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5 * VIA_RADIUS])
    turned = monitor.applied(near, np.zeros(7), 0.5, stall, obs, task).xdd
    assert turned[0] > 0  # towards q_g now
    np.testing.assert_array_equal(monitor.q_goal, qg)
    assert monitor.route == ()


@pytest.mark.parametrize("name", ["fpm", "cpm"])
def test_the_controller_s_goal_configurations_keep_its_own_ground(kinematics, monkeypatch,
                                                                  name):
    """The configuration pull checks q_g against the ground the barrier step keeps: the link
    hulls at :data:`~tamedpuma.methods._tamed.GROUND_HEIGHT_M`, and the sphere clearance
    without the barrier step."""
    monkeypatch.setattr(tamed, "load_task", lambda cfg: PoseTask(StablePose()))
    method = _method_config(name)
    rate = method["control_rate"]
    ground = make(name, method, kinematics).episode.configuration.ground
    assert ground.hulls is not None and ground.height == tamed.GROUND_HEIGHT_M
    method["control_rate"] = {**rate, "barrier_step": False}
    assert make(name, method, kinematics).episode.configuration.ground is None


def test_the_monitor_lets_go_when_the_attractor_makes_no_progress(kinematics):
    spec = kinematics.spec
    obs, task = _goal_without_obstacles(kinematics)
    q = np.array([spec.q_max[0] - 0.05, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0])
    monitor = ConfigurationMonitor(PULL, spec)
    for t in np.arange(0.0, PULL.window - 0.05, 0.1):  # held where it is: engaged for a window
        obs.t = t
        assert monitor.applied(q, np.zeros(7), 0.5, _stall(0.0, 0.5), obs, task) is not task
    obs.t = PULL.window + 0.15  # the window counts from the first step engaged (t = 0.1)
    assert monitor.applied(q, np.zeros(7), 0.5, _stall(0.0, 0.5), obs, task) is task
    assert not monitor.engaged


def test_the_attractor_potential_is_the_pull_s_own_by_finite_differences(kinematics):
    """φ = g ρ_ℓ(‖q − q_g‖) (Huber): ∂φ/∂q by central differences on both sides of ℓ, and at
    rest −∂φ/∂q is the attractor's acceleration; φ is 0 at q_g and continuous at ℓ."""
    spec = kinematics.spec
    monitor = ConfigurationMonitor(PULL, spec)
    monitor.q_goal = np.array([-0.5, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
    rng = np.random.default_rng(5)
    for scale in (0.05, 0.6, 1.5, 4.0):  # × ℓ: inside and beyond it
        direction = rng.normal(size=7)
        q = monitor.q_goal + scale * PULL.length * direction / np.linalg.norm(direction)
        phi, grad = monitor.potential(q)
        h = 1e-6
        fd = np.array([(monitor.potential(q + h * e)[0] - monitor.potential(q - h * e)[0])
                       / (2 * h) for e in np.eye(7)])
        np.testing.assert_allclose(grad, fd, atol=1e-7)
        err = monitor.q_goal - q
        pull = PULL.gain * err / max(np.linalg.norm(err), PULL.length)
        np.testing.assert_allclose(-grad, pull, atol=1e-12)
        assert phi > 0.0
    assert monitor.potential(monitor.q_goal)[0] == 0.0
    u = np.eye(7)[0]
    below = monitor.potential(monitor.q_goal + (PULL.length - 1e-9) * u)[0]
    above = monitor.potential(monitor.q_goal + (PULL.length + 1e-9) * u)[0]
    assert below == pytest.approx(above, abs=1e-8)


@pytest.mark.parametrize("bad", [{"configuration_pull": "sometimes"},
                                 {"configuration_pull": "always"},
                                 {"configuration_pull": 1},
                                 {"configuration_pull_gain": 4.0}])
def test_bad_configuration_pull_settings_are_refused(bad):
    with pytest.raises(ConfigError, match="configuration_pull"):
        Forcing.from_mapping(bad)


def test_without_the_stall_pull_or_switched_off_there_is_no_monitor(robot_spec):
    assert Forcing(stall_pull=1.5).make_configuration_monitor(robot_spec) is None
    assert Forcing(stall_pull=0.0, configuration_pull=True
                   ).make_configuration_monitor(robot_spec) is None
    assert Forcing(stall_pull=1.5, configuration_pull=True
                   ).make_configuration_monitor(robot_spec) is not None


class StablePose:
    """ẍ = (p_g − p) − 2v, α̇ = log(R_g Rᵀ) − 2ω, ψ = ½‖p_g − p‖² + ½‖log(R_g Rᵀ)‖²: a
    globally stable pose attractor in task space with a potential (the stall pull watches ψ)."""

    def acceleration(self, p, quat, v, omega, goal_p, goal_quat):
        err = rotation_error(quat_to_matrix(quat), quat_to_matrix(goal_quat))
        return np.asarray(goal_p) - p - 2.0 * np.asarray(v), err - 2.0 * np.asarray(omega)

    def potential(self, p, quat, goal_p, goal_quat):
        e = np.asarray(goal_p) - p
        r = rotation_error(quat_to_matrix(quat), quat_to_matrix(goal_quat))
        return 0.5 * e @ e + 0.5 * r @ r, -e, -r


def _obstacle_free_scenario(robot_spec, task_name: str, **changes):
    """The default scenario with the task's goal pose, no obstacles, and ``changes``."""
    task = load_group("task", task_name)
    cfg = load_group("scenario", "default")
    cfg["goal"].update(position=task["goal_position"], quaternion=task["goal_quaternion"])
    scenario = scenario_from_config(typed_scenario(cfg), robot_spec,
                                    task=task_name, **start_options())
    return replace(scenario, obstacles=Obstacles(np.zeros((0, 3)), np.zeros(0),
                                                 np.zeros((0, 3))), **changes)


def _method_config(name: str) -> dict:
    """``conf/method/<name>.yaml`` over ``puma.yaml``, with the default fabric (the task's
    model is the test's stand-in)."""
    method = {**load_group("method", "puma"), **load_group("method", name)}
    method.pop("defaults", None)
    if name != "puma":
        method["fabric"] = load_group("fabric", "default")
    method["task"] = "tomato"
    return method


def make(name: str, method: dict, kinematics):
    """Method ``name``'s controller from a plain method config, typed by the schema."""
    return methods.make(name, method_settings({**method, "name": name}), kinematics)


@pytest.mark.slow
@pytest.mark.parametrize("q1", [2.2, 2.6])
def test_fpm_is_trapped_by_the_base_limit_without_it_and_reaches_the_goal_with_it(
        robot_spec, kinematics, monkeypatch, scalar_log, q1):
    """The pouring goal lies at an azimuth of −97°; the arm starts reaching out at q₁ = q1
    (126-149°): the straight task-space way round turns the base into its upper limit
    (2.97 rad), the way out leads the hand away from the goal first. The goal's IK is solved
    before the first step: no control step starts an IK solve."""
    monkeypatch.setattr(tamed, "load_task", lambda cfg: PoseTask(StablePose()))
    scenario = _obstacle_free_scenario(robot_spec, "pouring",
                                       q0=np.array([q1, 0.6, 0.0, -1.2, 0.0, 0.6, 0.0]))
    method = _method_config("fpm")
    ik = _CountingIK(monkeypatch)
    results, in_steps = {}, []
    for pull in (False, True):
        method["forcing"] = {**method["forcing"], "configuration_pull": pull}
        controller = make("fpm", method, kinematics)
        step = controller.step

        def counted_step(obs, step=step):
            before = ik.calls
            command = step(obs)
            in_steps.append(ik.calls - before)
            return command

        controller.step = counted_step
        with Simulator(robot_spec, SimConfig(), Disturbance()) as world:
            run = run_episode(scenario, controller, world, [scalar_log] if pull else [])
        results[pull] = run
    assert len(in_steps) > 100 and ik.calls > 0 and sum(in_steps) == 0  # in reset only
    assert any(s.get("configuration_pull", 0.0) > 0 for s in scalar_log.rows)  # it engaged
    trapped, freed = results[False].metrics, results[True].metrics
    assert not trapped.success_paper and trapped.final_position_error_m > 0.3
    q = results[False].q
    assert q[:, 0].max() > robot_spec.q_max[0] - 0.05  # the base on its limit
    assert freed.success_whole_body, freed.failure_whole_body
    assert results[True].q[:, 0].max() <= robot_spec.q_max[0]


@pytest.mark.slow
def test_cpm_leaves_the_base_limit_trap_on_the_attractor_s_own_potential(
        robot_spec, kinematics, monkeypatch, scalar_log):
    """CPM in the trap above (q₁ = 2.2 rad) with the configuration pull: while the pull acts, the
    regulator watches the attractor's φ, whose total energy ½‖q̇‖² + φ does not rise (CPM's
    dH/dt ≤ −β‖q̇‖² with H on φ), and the arm reaches the goal."""
    monkeypatch.setattr(tamed, "load_task", lambda cfg: PoseTask(StablePose()))
    # 60 s: CPM creeps along the limit for 22 s before the stall pull arms, and the way out is
    # 8 rad of joint travel at the attractor's cruise speed g/k (1 rad/s with the defaults)
    scenario = _obstacle_free_scenario(robot_spec, "pouring", max_steps=3000,
                                       q0=np.array([2.2, 0.6, 0.0, -1.2, 0.0, 0.6, 0.0]))
    method = _method_config("cpm")
    assert method["forcing"]["configuration_pull"] is True
    with Simulator(robot_spec, SimConfig(), Disturbance()) as world:
        run = run_episode(scenario, make("cpm", method, kinematics), world, [scalar_log])
    assert run.metrics.success_whole_body, run.metrics.failure_whole_body
    on = np.array([s["potential_attractor"] for s in scalar_log.rows]) > 0
    energy = np.array([s["energy_total"] for s in scalar_log.rows])
    assert on.sum() > 50  # it acted for at least a second
    steps = np.flatnonzero(on[1:] & on[:-1]) + 1  # consecutive steps on the same potential
    assert np.max(energy[steps] - energy[steps - 1]) < 1e-3


class ClimbingPotential(StablePose):
    """StablePose's field with a potential that climbs along its straight way: ψ = ½‖e‖²(1 +
    A·b(p)) + ½‖r‖², b(p) = exp(−‖p − c‖²/(2s²)) a bump about the midpoint c of the start and
    the goal (ψ ≥ 0, 0 only at the goal). The field is not the gradient of ψ: PUMA's field and
    its latent potential disagree like this where CPM crawled in random pouring scenarios
    (ψ rising along the hand's way)."""

    def __init__(self, centre, height=200.0, width=0.15):
        self.c, self.height, self.width = np.asarray(centre, dtype=float), height, width

    def potential(self, p, quat, goal_p, goal_quat):
        e = np.asarray(goal_p) - p
        r = rotation_error(quat_to_matrix(quat), quat_to_matrix(goal_quat))
        d = p - self.c
        b = self.height * np.exp(-(d @ d) / (2.0 * self.width ** 2))
        grad = -e * (1.0 + b) - 0.5 * (e @ e) * b * d / self.width ** 2
        return 0.5 * (e @ e) * (1.0 + b) + 0.5 * r @ r, grad, -r


@pytest.mark.slow
def test_cpm_crawling_up_its_potential_arms_the_stall_pull_and_the_attractor_takes_it_in(
        robot_spec, kinematics, monkeypatch):
    """Where ψ climbs along the way the forcing takes, CPM's regulator brakes the climb and the
    arm crawls (the ε leak). Without the creep criterion and the configuration pull the arm is
    left crawling far from the goal at 40 s: the hand closes too slowly to reach but faster than
    the stall pull's 5 mm per window. CPM's defaults (the creep criterion, the pull) arm the
    stall pull on the crawl and the configuration attractor, on its own potential, takes the
    arm in."""
    scenario = _obstacle_free_scenario(robot_spec, "tomato")
    centre = 0.5 * (kinematics.ee_pose(scenario.q0)[0] + scenario.goal.position)
    monkeypatch.setattr(tamed, "load_task", lambda cfg: PoseTask(ClimbingPotential(centre)))
    method = _method_config("cpm")
    assert method["forcing"]["configuration_pull"] is True
    assert CpmController.creep_fraction > 0
    runs = {}
    for name, forcing, creep in (("without", {"configuration_pull": False}, 0.0),
                                 ("default", {}, CpmController.creep_fraction)):
        m = {**method, "forcing": {**method["forcing"], **forcing}}
        with monkeypatch.context() as patch, Simulator(robot_spec, SimConfig(),
                                                       Disturbance()) as world:
            patch.setattr(CpmController, "creep_fraction", creep)
            runs[name] = run_episode(scenario, make("cpm", m, kinematics), world)
    crawl = runs["without"]
    assert not crawl.metrics.success_paper and crawl.metrics.final_position_error_m > 0.3
    speed = np.linalg.norm(np.diff(crawl.ee_position[-500:], axis=0), axis=1) / scenario.dt
    assert 1e-4 < np.median(speed) < 0.01  # [m/s]: crawling, neither resting nor on its way
    assert runs["default"].metrics.success_whole_body, runs["default"].metrics.failure_whole_body


class _CountingIK:
    """Counts the goal-configuration IK solves started (``pose_dls_steps`` calls)."""

    def __init__(self, monkeypatch):
        self.calls = 0
        inner = cpull.pose_dls_steps

        def counted(*args, **kwargs):
            self.calls += 1
            return inner(*args, **kwargs)

        monkeypatch.setattr(cpull, "pose_dls_steps", counted)


def test_a_prepared_monitor_solves_no_ik_at_engagement_and_spends_its_budget_per_step(
        kinematics, monkeypatch):
    """Solved before the first step, the engagement searches the route only, at most
    ``budget`` kinematic passes per step, and ends on the same route as the whole search in one
    step; a goal moved away is solved again within the same budget, the last q_g kept."""
    spec = kinematics.spec
    obs, task = _goal_without_obstacles(kinematics)
    q0 = np.array([0.3, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0])
    q = np.array([spec.q_max[0] - 0.05, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0])
    whole = ConfigurationMonitor(PULL, spec)
    whole.prepare(obs.goal_position, obs.goal_quaternion, q0)
    assert whole.applied(q, np.zeros(7), 0.5, _stall(3.0, 0.5), obs, task) is not task
    budget = 4
    monitor = ConfigurationMonitor(replace(PULL, budget=budget), spec)
    ik = _CountingIK(monkeypatch)
    monitor.prepare(obs.goal_position, obs.goal_quaternion, q0)
    assert ik.calls == 0 and monitor.solutions is whole.solutions  # kept by the process
    fresh = run_to_end(cpull.pose_solutions(kinematics, obs.goal_position,
                                            obs.goal_quaternion, q0, PULL))
    for kept, new in zip(whole.solutions.pose, fresh.pose, strict=True):
        np.testing.assert_array_equal(kept, new)
    ik.calls = 0
    steps = 0
    while not monitor.engaged:
        before = monitor.passes
        assert monitor.applied(q, np.zeros(7), 0.5, _stall(3.0, 0.5), obs, task) is task \
            or monitor.engaged
        assert monitor.passes - before <= budget
        steps += 1
        assert steps < 1000
    assert steps > 1 and ik.calls == 0
    np.testing.assert_array_equal(monitor.q_goal, whole.q_goal)
    # the goal moves 5 cm: solved again a budget at a time, the last q_g pulling meanwhile
    moved = SimpleNamespace(**{**vars(obs), "goal_position": obs.goal_position
                               + np.array([0.0, 0.0, 0.05])})
    last = monitor.q_goal.copy()
    monitor.applied(q, np.zeros(7), 0.5, _stall(3.0, 0.5), moved, task)
    assert monitor.search is not None and ik.calls >= 1 and monitor.engaged
    np.testing.assert_array_equal(monitor.q_goal, last)
    while monitor.search is not None:
        before = monitor.passes
        monitor.applied(q, np.zeros(7), 0.5, _stall(3.0, 0.5), moved, task)
        assert monitor.passes - before <= budget
    p, _ = kinematics.ee_frame(monitor.q_goal)
    assert np.linalg.norm(p - moved.goal_position) < 1e-3


def test_the_stall_arming_stands_while_the_configuration_pull_searches_and_acts(kinematics):
    """The route search spreads over steps (4 passes each) while ψ falls 3 % a step (the stall
    pull's own approach): the arming stands until the search ends and the pull engages; ψ
    falling further does not end the engagement, only its own ends do (here: the hand within
    near_release), and the stall pull's release then counts from ψ there."""
    spec = kinematics.spec
    obs, task = _goal_without_obstacles(kinematics)
    q0 = np.array([0.3, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0])
    q = np.array([spec.q_max[0] - 0.05, 0.3, 0.0, -1.0, 0.0, 0.5, 0.0])
    monitor = ConfigurationMonitor(replace(PULL, budget=4), spec)
    monitor.prepare(obs.goal_position, obs.goal_quaternion, q0)
    stall = StallMonitor(StallPull(gain=1.5, hold_radius=0.0))
    goal = np.asarray(obs.goal_position, dtype=float)
    hand = goal - np.array([0.5, 0.0, 0.0])
    for t in (0.0, 2.0):  # no progress over the window: armed
        stall.acceleration(t, hand, goal, lambda: 1.0)
    assert stall.armed
    psi, steps = 1.0, 0
    while not monitor.engaged:
        steps += 1
        obs.t, psi = 2.0 + 0.1 * steps, psi * 0.97  # one ψ sample per step
        stall.acceleration(obs.t, hand, goal, lambda v=psi: v)
        monitor.applied(q, np.zeros(7), 0.5, stall, obs, task)
        assert stall.armed and steps < 1000
    assert steps > 2 and psi < 0.9  # without the hold the arming was let go at step 2
    for _ in range(10):  # engaged: ψ falling further ends neither the arming nor the pull
        obs.t, psi = obs.t + 0.1, psi * 0.9
        stall.acceleration(obs.t, hand, goal, lambda v=psi: v)
        assert monitor.applied(q, np.zeros(7), 0.5, stall, obs, task) is not task
        assert stall.armed
    # within its release distance it lets go, and the stall pull's release counts from ψ there
    obs.t += 0.1
    stall.acceleration(obs.t, hand, goal, lambda v=psi: v)
    assert monitor.applied(q, np.zeros(7), monitor.release_at, stall, obs, task) is task
    assert not monitor.engaged and stall.armed and stall.psi_armed == psi


def test_one_placement_pass_gives_the_heights_and_spheres_of_two(kinematics):
    """The route search's sample (one forward pass) reads the same numbers as the hull heights
    and the sphere centres each from a pass of their own."""
    hulls = link_hulls(kinematics)
    q = np.array([0.4, -0.7, 0.3, -1.9, 0.2, 1.1, -0.5])
    heights, spheres = hull_heights_and_spheres(kinematics, hulls, q)
    np.testing.assert_array_equal(heights, hull_heights(kinematics, hulls, q))
    np.testing.assert_array_equal(spheres, kinematics.sphere_centers(q))
    for ground in (Ground(0.01, hulls), Ground(0.01)):
        margins, at = ground.margins_and_spheres(kinematics, q)
        np.testing.assert_array_equal(margins, ground.margins(kinematics, q))
        np.testing.assert_array_equal(at, spheres)


def test_fpm_streams_pumas_potential_every_step(robot_spec, kinematics, monkeypatch,
                                               scalar_log):
    """FPM logs ψ (the stall monitor's sample, every 0.1 s) in every step's scalars, so the
    potential plot of a run is never empty; it falls as the arm converges."""
    monkeypatch.setattr(tamed, "load_task", lambda cfg: PoseTask(StablePose()))
    scenario = _obstacle_free_scenario(robot_spec, "tomato", max_steps=150)
    with Simulator(robot_spec, SimConfig(), Disturbance()) as world:
        run_episode(scenario, make("fpm", _method_config("fpm"), kinematics), world,
                    [scalar_log], stop_on_success=False)
    psi = np.array([row["psi"] for row in scalar_log.rows])
    assert len(psi) == 150 and np.isfinite(psi).all()
    assert psi[-1] < 0.5 * psi[0]


class CountedPose(StablePose):
    """StablePose with ψ alone (counted): what the log's ψ calls."""

    def __init__(self):
        self.calls = 0

    def psi(self, p, quat, goal_p, goal_quat):
        self.calls += 1
        return self.potential(p, quat, goal_p, goal_quat)[0]


@pytest.mark.parametrize("name,config", [("puma", "puma"), ("fpm", "fpm_literal")])
def test_methods_without_a_psi_of_their_own_log_it_off_the_control_path(
        name, config, robot_spec, kinematics, monkeypatch, scalar_log):
    """PUMA (and FPM without the stall monitor) never evaluate ψ in their step: the log's ψ is
    computed after the step (``Command.logged_later``) at the pose the step saw: every step's
    ψ = ½‖p_g − p‖² + ½‖log(R_g Rᵀ)‖² of its logged errors, and never without a recorder."""
    primitive = CountedPose()
    monkeypatch.setattr(tamed, "load_task", lambda cfg: PoseTask(primitive))
    scenario = _obstacle_free_scenario(robot_spec, "tomato", max_steps=60)
    with Simulator(robot_spec, SimConfig(), Disturbance()) as world:
        controller = make(name, _method_config(config), kinematics)
        run_episode(scenario, controller, world, [scalar_log], stop_on_success=False)
        assert primitive.calls == 60
        rows = scalar_log.rows
        psi = np.array([row["psi"] for row in rows])
        expected = 0.5 * np.array([row["position_error_m"] ** 2
                                   + row["orientation_error_rad"] ** 2 for row in rows])
        np.testing.assert_allclose(psi, expected, rtol=1e-6)
        assert psi[-1] < 0.5 * psi[0]
        primitive.calls = 0
        run_episode(scenario, controller, world, [], stop_on_success=False)
        assert primitive.calls == 0  # no recorder: ψ is never computed
        obs = world.reset(scenario)
        controller.reset(scenario)
        command = controller.step(obs)
        assert "psi" not in command.scalars and primitive.calls == 0  # not in the timed step
