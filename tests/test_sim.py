"""The PyBullet world: determinism, the velocity-control law, moving obstacles, contacts."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.types import Goal, Obstacles, Scenario
from tamedpuma.worlds.bullet import Simulator

Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])
GOAL = Goal([0.58, -0.214, 0.115], [-0.5459, 0.5806, -0.4112, 0.4426])


def _scenario(obstacles=None, goal=GOAL, steps=50):
    return Scenario(name="t", task="tomato", q0=Q0, goal=goal,
                    obstacles=obstacles or Obstacles.empty(), dt=0.02,
                    max_steps=steps, goal_tolerance=0.05)


def _rollout(spec, scenario, qdd_of):
    with Simulator(spec) as sim:
        obs = sim.reset(scenario)
        qs = [obs.q]
        for k in range(scenario.max_steps):
            obs = sim.step(qdd_of(k, obs))
            qs.append(obs.q)
    return np.array(qs)


def test_same_inputs_give_identical_trajectories(robot_spec):
    def law(k, obs):
        return np.sin(0.1 * k + np.arange(7)) - 2.0 * obs.qd

    a = _rollout(robot_spec, _scenario(), law)
    b = _rollout(robot_spec, _scenario(), law)
    assert np.array_equal(a, b)
    assert np.ptp(a, axis=0).max() > 0.05  # the arm really moved


def test_velocity_command_is_qd_plus_qdd_dt_clipped(robot_spec):
    sc = _scenario()
    with Simulator(robot_spec) as sim:
        obs = sim.reset(sc)
        qdd = np.array([1.0, -1.0, 0.5, 0.0, 0.0, 0.0, 200.0])
        obs1 = sim.step(qdd)
        expected = np.clip(obs.qd + qdd * sc.dt, -robot_spec.qd_max, robot_spec.qd_max)
        np.testing.assert_allclose(sim.last_velocity_command, expected)
        assert sim.last_velocity_command[6] == pytest.approx(robot_spec.qd_max[6])
        # the motors track the commanded velocity
        np.testing.assert_allclose(obs1.qd, expected, atol=5e-3)


def test_obstacles_and_goal_move_with_constant_velocity(robot_spec):
    obst = Obstacles([[1.0, 1.0, 1.0]], [0.05], [[0.1, 0.0, -0.2]])
    goal = Goal(GOAL.position, GOAL.quaternion, [0.0, -0.01, 0.0])
    with Simulator(robot_spec) as sim:
        sim.reset(_scenario(obst, goal))
        for _ in range(10):
            obs = sim.step(np.zeros(7))
    np.testing.assert_allclose(obs.t, 0.2)
    np.testing.assert_allclose(obs.obstacle_centers[0], [1.02, 1.0, 0.96])
    np.testing.assert_allclose(obs.goal_position, GOAL.position + [0, -0.002, 0])


def test_contact_and_clearance_queries(robot_spec, kinematics):
    centers = kinematics.sphere_centers(Q0)
    far = Obstacles([[2.0, 2.0, 2.0]], [0.05], [[0, 0, 0]])
    inside = Obstacles([centers[2]], [0.05], [[0, 0, 0]])  # on link 5's sphere centre
    with Simulator(robot_spec) as sim:
        sim.reset(_scenario(far))
        sim.step(np.zeros(7))
        pos, quat = sim.link_poses()
        sph = sim.body_sphere_centers(pos, quat)
        c = sim.contacts(sph)
        expected = np.linalg.norm(sph - [2, 2, 2], axis=1) - robot_spec.sphere_radii - 0.05
        assert c.sphere_clearance == pytest.approx(expected.min())
        assert not c.obstacle_contact and not c.ground_contact

        sim.reset(_scenario(inside))
        sim.step(np.zeros(7))
        pos, quat = sim.link_poses()
        c = sim.contacts(sim.body_sphere_centers(pos, quat))
        assert c.sphere_clearance < -0.05  # penetrating (contact forces push the arm a bit)
        assert c.obstacle_contact


def test_link_poses_match_pinocchio(robot_spec, kinematics):
    with Simulator(robot_spec) as sim:
        sim.reset(_scenario())
        pos, _ = sim.link_poses()
    ref, _ = kinematics.link_poses(Q0)
    np.testing.assert_allclose(pos, ref, atol=1e-6)


def test_link_poses_are_pybullets_link_states_one_link_at_a_time(robot_spec):
    """The one batched query, written into its rows, gives each link's own ``getLinkState``
    (the base: the origin), to the bit."""
    import pybullet as pb

    with Simulator(robot_spec) as sim:
        sim.reset(_scenario())
        for k in range(3):
            sim.step(np.sin(np.arange(7.0) + k))
        pos, quat = sim.link_poses()
        for row, link in enumerate(sim._link_idx):
            if link < 0:
                want = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)
            else:
                state = pb.getLinkState(sim._robot, link, computeForwardKinematics=True,
                                        physicsClientId=sim._client)
                want = state[4], state[5]
            assert pos[row].tolist() == list(want[0]) and quat[row].tolist() == list(want[1])


def test_contacts_are_checked_among_1000_obstacles(robot_spec, kinematics):
    """The scaling experiment's largest count: 999 seeded clutter spheres kept clear of the arm
    plus one on link 4 — the mesh contact and the sphere penetration are both reported; without
    that one, none is."""
    from dataclasses import replace

    from tamedpuma.worlds.scenarios import arm_points, with_clutter

    keep_out = arm_points(kinematics, Q0)
    clutter = with_clutter(_scenario(), 999, 0.05, [-1.2, -1.2, 0.05], [1.2, 1.2, 1.4],
                           keep_out, 0.1, np.random.default_rng(0))
    on_link = kinematics.sphere_centers(Q0)[1]  # link 4's sphere centre
    obst = clutter.obstacles
    touching = Obstacles(np.vstack([obst.centers, on_link]), np.r_[obst.radii, 0.05],
                         np.vstack([obst.velocities, np.zeros(3)]))
    for obstacles, expect in ((obst, False), (touching, True)):
        with Simulator(robot_spec) as sim:
            sim.reset(replace(clutter, obstacles=obstacles))
            sim.step(np.zeros(7))  # one control period of physics
            pos, quat = sim.link_poses()
            contacts = sim.contacts(sim.body_sphere_centers(pos, quat))
        assert len(obstacles) == 999 + expect
        assert contacts.obstacle_contact == expect
        assert (contacts.sphere_clearance < 0) == expect


def test_rotation_matrices_and_sphere_centres_are_bullets_to_the_last_bit(robot_spec):
    """The vectorised rotation is Bullet's own arithmetic (``getMatrixFromQuaternion``), unit
    or not, and the body spheres of a moving arm are ``p_l + R(q_l) o_i`` computed one sphere
    at a time with PyBullet's matrix: equal bit for bit, so the recorded clearances are."""
    from dataclasses import replace

    import pybullet as pb

    from tamedpuma.robot.kinematics import BodySphere
    from tamedpuma.robot.rotations import bullet_rotation_matrices

    rng = np.random.default_rng(3)
    robot_spec = replace(robot_spec, spheres=robot_spec.spheres + tuple(  # offset spheres
        BodySphere(link, 0.1, tuple(rng.normal(scale=0.1, size=3)))
        for link in robot_spec.link_names[1:]))
    quats = rng.normal(size=(200, 4)) * rng.uniform(0.5, 2.0, size=(200, 1))
    ref = np.array([np.reshape(pb.getMatrixFromQuaternion(q.tolist()), (3, 3)) for q in quats])
    assert np.array_equal(bullet_rotation_matrices(quats), ref)
    offsets = np.array([s.offset for s in robot_spec.spheres])
    assert np.any(offsets != 0)  # the check below covers offset spheres
    link_of = [robot_spec.link_names.index(s.link) for s in robot_spec.spheres]
    with Simulator(robot_spec) as sim:
        sim.reset(_scenario())
        for k in range(5):
            sim.step(np.sin(k + np.arange(7)))
            pos, quat = sim.link_poses()
            expected = np.array([
                pos[i] + np.reshape(pb.getMatrixFromQuaternion(quat[i].tolist()), (3, 3)) @ o
                if np.any(o) else pos[i] for i, o in zip(link_of, offsets)])
            assert np.array_equal(sim.body_sphere_centers(pos, quat), expected)


def test_joint_state_read_once_per_physics_state_is_a_fresh_copy(robot_spec):
    """The observation's arrays are the caller's: changing them changes neither the next
    observation nor the state ``step`` integrates from."""
    with Simulator(robot_spec) as sim:
        obs = sim.reset(_scenario())
        q0 = obs.q.copy()
        obs.q[:] = 9.0
        obs.qd[:] = 9.0
        again = sim.observe()
        assert np.array_equal(again.q, q0) and not np.any(again.qd == 9.0)
        nxt = sim.step(np.zeros(7))
        assert np.abs(nxt.q - q0).max() < 0.01  # integrated from the true state, not from 9


def test_a_link_within_bullets_contact_margin_but_clear_is_not_a_contact(robot_spec, kinematics):
    """Bullet reports contact points for pairs closer than its margin that do not touch
    (``contactDistance`` > 0); only a signed distance ≤ 0 is a contact. An obstacle 1 mm from
    link 7's mesh: Bullet lists the pair, ``contacts`` does not; 1 mm inside: a contact."""
    import pybullet as pb

    def closest(sim):
        points = pb.getClosestPoints(sim._robot, sim._obstacle_ids[0], 0.5,
                                     physicsClientId=sim._client)
        return min(points, key=lambda p: p[8])

    start = kinematics.sphere_centers(Q0)[4] + [0.0, 0.0, 0.2]  # above link 7
    with Simulator(robot_spec) as sim:
        sim.reset(_scenario(Obstacles([start], [0.05], [[0, 0, 0]])))
        p = closest(sim)
        normal = np.asarray(p[7])  # contactNormalOnB: from the obstacle towards the robot
        for gap, expect in ((0.001, False), (-0.001, True)):
            center = np.asarray(start) + normal * (p[8] - gap)
            sim.reset(_scenario(Obstacles([center], [0.05], [[0, 0, 0]])))
            assert closest(sim)[8] == pytest.approx(gap, abs=2e-4)
            sim.step(np.zeros(7))
            reported = [c for c in pb.getContactPoints(bodyA=sim._robot,
                                                       physicsClientId=sim._client)
                        if c[2] in sim._obstacle_set]
            assert reported  # Bullet lists the pair either way
            pos, quat = sim.link_poses()
            assert sim.contacts(sim.body_sphere_centers(pos, quat)).obstacle_contact == expect
