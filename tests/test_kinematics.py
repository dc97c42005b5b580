"""Pinocchio kinematics against PyBullet and against central finite differences."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from tamedpuma.robot.ik import solve_pose_ik
from tamedpuma.robot.rotations import quat_to_matrix, rotation_error


def _random_q(spec, rng, n):
    return rng.uniform(spec.q_min, spec.q_max, size=(n, spec.dof))


def test_fk_of_every_link_equals_pybullet(robot_spec, kinematics):
    rng = np.random.default_rng(0)
    client = pb.connect(pb.DIRECT)
    try:
        robot = pb.loadURDF(robot_spec.urdf_path, useFixedBase=True, physicsClientId=client)
        child = {pb.getJointInfo(robot, i, physicsClientId=client)[12].decode(): i
                 for i in range(pb.getNumJoints(robot, physicsClientId=client))}
        link_idx = [child[n] for n in robot_spec.link_names[1:]]
        for q in _random_q(robot_spec, rng, 120):
            for j, qj in enumerate(q):
                pb.resetJointState(robot, j, qj, physicsClientId=client)
            states = pb.getLinkStates(robot, link_idx, computeForwardKinematics=True,
                                      physicsClientId=client)
            pos, quat = kinematics.link_poses(q)
            np.testing.assert_allclose(pos[0], 0.0, atol=1e-12)  # base at the origin
            for k, s in enumerate(states, start=1):
                np.testing.assert_allclose(pos[k], s[4], atol=1e-6)
                np.testing.assert_allclose(quat_to_matrix(quat[k]), quat_to_matrix(s[5]),
                                           atol=1e-6)
    finally:
        pb.disconnect(client)


def _pose(kin, q):
    p, quat = kin.ee_pose(q)
    return p, quat_to_matrix(quat)


def test_ee_jacobian_matches_central_differences(robot_spec, kinematics):
    rng = np.random.default_rng(1)
    h = 1e-6
    for q in _random_q(robot_spec, rng, 20):
        jac = kinematics.evaluate(q, np.zeros(7)).ee_jacobian
        fd = np.zeros((6, 7))
        for i in range(7):
            dq = np.zeros(7)
            dq[i] = h
            p1, r1 = _pose(kinematics, q + dq)
            p0, r0 = _pose(kinematics, q - dq)
            fd[:3, i] = (p1 - p0) / (2 * h)
            fd[3:, i] = rotation_error(r0, r1) / (2 * h)
        np.testing.assert_allclose(jac, fd, atol=1e-5)


def test_jdot_qdot_matches_central_differences(robot_spec, kinematics):
    """J̇q̇ = d/dt (J(q) q̇) along q(t) = q + t q̇, by central differences in t."""
    rng = np.random.default_rng(2)
    h = 1e-6
    for q in _random_q(robot_spec, rng, 20):
        qd = rng.uniform(-1.5, 1.5, 7)
        s = kinematics.evaluate(q, qd)
        sp = kinematics.evaluate(q + h * qd, qd)
        sm = kinematics.evaluate(q - h * qd, qd)
        fd_ee = (sp.ee_jacobian - sm.ee_jacobian) @ qd / (2 * h)
        np.testing.assert_allclose(s.ee_jdqd, fd_ee, atol=1e-5)
        fd_sph = np.einsum("kij,j->ki", sp.sphere_jacobians - sm.sphere_jacobians, qd) / (2 * h)
        np.testing.assert_allclose(s.sphere_jdqd, fd_sph, atol=1e-5)


def test_sphere_centres_and_jacobians(robot_spec, kinematics):
    rng = np.random.default_rng(3)
    h = 1e-6
    link_index = [robot_spec.link_names.index(s.link) for s in robot_spec.spheres]
    for q in _random_q(robot_spec, rng, 20):
        s = kinematics.evaluate(q, np.zeros(7))
        pos, _ = kinematics.link_poses(q)
        np.testing.assert_allclose(s.sphere_centers, pos[link_index], atol=1e-12)
        for i in range(7):
            dq = np.zeros(7)
            dq[i] = h
            fd = (kinematics.sphere_centers(q + dq) - kinematics.sphere_centers(q - dq)) / (2 * h)
            np.testing.assert_allclose(s.sphere_jacobians[:, :, i], fd, atol=1e-5)
    assert s.sphere_radii.tolist() == [0.09, 0.09, 0.09, 0.09, 0.07]


def test_ee_quaternion_is_xyzw_of_the_rotation(robot_spec, kinematics):
    q = _random_q(robot_spec, np.random.default_rng(4), 1)[0]
    s = kinematics.evaluate(q, np.zeros(7))
    np.testing.assert_allclose(quat_to_matrix(s.ee_quaternion), s.ee_rotation, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_ik_reaches_reachable_poses(robot_spec, kinematics, seed):
    rng = np.random.default_rng(seed)
    q_goal = rng.uniform(robot_spec.q_min * 0.6, robot_spec.q_max * 0.6)
    p, quat = kinematics.ee_pose(q_goal)
    q_init = np.clip(q_goal + rng.normal(0, 0.3, 7), robot_spec.q_min, robot_spec.q_max)
    result = solve_pose_ik(kinematics, p, quat, q_init)
    assert result.converged
    p2, quat2 = kinematics.ee_pose(result.q)
    np.testing.assert_allclose(p2, p, atol=1e-5)
    assert np.all(result.q >= robot_spec.q_min) and np.all(result.q <= robot_spec.q_max)


def test_the_placement_only_calls_give_evaluates_numbers_bit_for_bit(robot_spec, kinematics):
    """ee_frame and sphere_centers (one placement pass, for callers that need no Jacobian:
    Modulation-IK's targets and its distance check) return exactly evaluate()'s pose and
    centres, and sphere_radii its radii."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        q = rng.uniform(robot_spec.q_min, robot_spec.q_max)
        state = kinematics.evaluate(q, rng.normal(size=q.size))
        p, rot = kinematics.ee_frame(q)
        np.testing.assert_array_equal(p, state.ee_position)
        np.testing.assert_array_equal(rot, state.ee_rotation)
        np.testing.assert_array_equal(kinematics.sphere_centers(q), state.sphere_centers)
    np.testing.assert_array_equal(kinematics.sphere_radii, robot_spec.sphere_radii)


def test_the_ik_pass_gives_evaluates_pose_and_jacobian_bit_for_bit(robot_spec, kinematics):
    """ee_pose_jacobian (the IK iteration's pass: placements and joint Jacobians only) returns
    exactly evaluate()'s end-effector position, rotation and Jacobian at any q̇, and leaves the
    data at q as evaluate does (link_position_jacobian reads the same numbers)."""
    rng = np.random.default_rng(4)
    for _ in range(300):
        q = rng.uniform(robot_spec.q_min, robot_spec.q_max)
        state = kinematics.evaluate(q, rng.normal(size=q.size))
        link = kinematics.link_position_jacobian("lbr_iiwa_link_4")
        p, rot, jac = kinematics.ee_pose_jacobian(q)
        np.testing.assert_array_equal(p, state.ee_position)
        np.testing.assert_array_equal(rot, state.ee_rotation)
        np.testing.assert_array_equal(jac, state.ee_jacobian)
        for ours, theirs in zip(kinematics.link_position_jacobian("lbr_iiwa_link_4"), link):
            np.testing.assert_array_equal(ours, theirs)
