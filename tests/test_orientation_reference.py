"""PUMA's orientation as a reference state (``method.orientation: reference``,
:class:`tamedpuma.methods._policy.OrientationReference`).

A learned pose field's position part depends on the orientation it is evaluated at; with the
hand's orientation held (joints on their limits) its equilibrium moves off the goal. The stand-in
here has that coupling in closed form: ``a = k_p (p_g + C e − p) − k_d v``, ``α = k_r e − k_w ω``
with ``e = log(R_g Rᵀ)``, so with e held the position rests at ``p_g + C e``.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tamedpuma.methods._policy import OrientationReference, PoseTask
from tamedpuma.robot.rotations import quat_conj, quat_exp, quat_log, quat_mul

GOAL_P = np.array([0.5, -0.2, 0.3])
GOAL_Q = np.array([0.0, 0.0, 0.0, 1.0])
COUPLING = np.array([[0.2, 0.0, 0.0], [0.0, -0.15, 0.05], [0.0, 0.0, 0.1]])  # C [m/rad]
DT = 0.02


class CoupledPose:
    """A stable pose system whose position equilibrium depends on the orientation (see module)."""

    kp, kd, kr, kw = 2.0, 3.0, 2.0, 3.0

    def acceleration(self, p, quat, v, omega, goal_p, goal_quat):
        e = quat_log(quat_mul(goal_quat, quat_conj(quat)))
        a = self.kp * (np.asarray(goal_p) + COUPLING @ e - p) - self.kd * np.asarray(v)
        return a, self.kr * e - self.kw * np.asarray(omega)


def _state(p, quat):
    """The hand as its own 6-joint task space: J = I (rows [v; ω]), J̇q̇ = 0."""
    return SimpleNamespace(ee_position=np.asarray(p, float), ee_quaternion=np.asarray(quat, float),
                           ee_jacobian=np.eye(6), ee_jdqd=np.zeros(6))


def _roll(task, p, quat, steps, orientation_free=True):
    """Integrate the hand under the task's acceleration (semi-implicit Euler, the exp map for
    the orientation, as the reference itself); orientation_free False holds it where it is."""
    v, w = np.zeros(3), np.zeros(3)
    p, quat = np.array(p, float), np.array(quat, float)
    for k in range(steps):
        state, qd = _state(p, quat), np.concatenate([v, w])
        if task.reference is not None:
            task.reference.sync(k * DT, state, qd, GOAL_P)
        xdd = task.acceleration(state, qd, GOAL_P, GOAL_Q).xdd
        v = v + DT * xdd[:3]
        p = p + DT * v
        if orientation_free:
            w = w + DT * xdd[3:]
            quat = quat_mul(quat_exp(w * DT), quat)
            quat = quat / np.linalg.norm(quat)
    return p, quat


START_Q = quat_exp(np.array([0.3, -0.4, 0.2]))  # 0.54 rad from the goal's orientation
START_P = GOAL_P + np.array([0.3, 0.2, -0.1])


def test_with_the_orientation_held_the_feedback_field_rests_off_the_goal_the_reference_reaches_it():
    held_feedback, _ = _roll(PoseTask(CoupledPose()), START_P, START_Q, 2000,
                             orientation_free=False)
    e = quat_log(quat_mul(GOAL_Q, quat_conj(START_Q)))
    np.testing.assert_allclose(held_feedback, GOAL_P + COUPLING @ e, atol=1e-4)
    assert np.linalg.norm(held_feedback - GOAL_P) > 0.05
    task = PoseTask(CoupledPose(), OrientationReference(16.0, 8.0, 3.0))
    held_reference, _ = _roll(task, START_P, START_Q, 2000, orientation_free=False)
    assert np.linalg.norm(held_reference - GOAL_P) < 1e-3
    assert np.linalg.norm(quat_log(quat_mul(task.reference.quat, quat_conj(GOAL_Q)))) < 1e-3


def test_where_the_hand_follows_the_reference_it_is_the_feedback_law():
    p_fb, q_fb = _roll(PoseTask(CoupledPose()), START_P, START_Q, 300)
    task = PoseTask(CoupledPose(), OrientationReference(16.0, 8.0, 3.0))
    p_ref, q_ref = _roll(task, START_P, START_Q, 300)
    np.testing.assert_allclose(p_ref, p_fb, atol=1e-9)
    np.testing.assert_allclose(q_ref * np.sign(q_ref[3]), q_fb * np.sign(q_fb[3]), atol=1e-9)


def test_beyond_its_radius_the_reference_is_off_and_starts_from_the_hand_within_it():
    ref = OrientationReference(16.0, 8.0, 3.0, radius=0.2)
    task, feedback = PoseTask(CoupledPose(), ref), PoseTask(CoupledPose())
    qd = np.array([0.1, -0.2, 0.05, 0.1, 0.0, -0.2])
    far = _state(GOAL_P + np.array([0.3, 0.0, 0.0]), START_Q)
    ref.sync(0.0, far, qd, GOAL_P)
    assert not ref.active  # the same computation as the feedback law, to the bit
    np.testing.assert_array_equal(task.acceleration(far, qd, GOAL_P, GOAL_Q).xdd,
                                  feedback.acceleration(far, qd, GOAL_P, GOAL_Q).xdd)
    near = _state(GOAL_P + np.array([0.1, 0.0, 0.0]), START_Q)
    ref.sync(0.02, near, qd, GOAL_P)  # comes on: the hand's orientation and angular velocity
    assert ref.active
    np.testing.assert_array_equal(ref.quat, START_Q)
    np.testing.assert_array_equal(ref.omega, qd[3:])
    alpha = task.acceleration(near, qd, GOAL_P, GOAL_Q).xdd[3:]
    np.testing.assert_allclose(alpha, feedback.acceleration(near, qd, GOAL_P, GOAL_Q).xdd[3:],
                               atol=1e-12)  # no tracking error yet
    ref.sync(0.04, near, qd, GOAL_P)  # integrated with the kept α
    np.testing.assert_allclose(ref.omega, qd[3:] + 0.02 * alpha)


def test_near_an_obstacle_the_reference_is_off():
    ref = OrientationReference(16.0, 8.0, 3.0, radius=0.2, clearance=0.1)
    near_goal = _state(GOAL_P + np.array([0.1, 0.0, 0.0]), START_Q)
    ref.sync(0.0, near_goal, np.zeros(6), GOAL_P, clearance=0.05)
    assert not ref.active
    ref.sync(0.02, near_goal, np.zeros(6), GOAL_P, clearance=0.15)
    assert ref.active
    ref.sync(0.04, near_goal, np.zeros(6), GOAL_P, clearance=0.09)
    assert not ref.active
    ref.sync(0.06, near_goal, np.zeros(6), GOAL_P)  # no obstacles: clearance inf
    assert ref.active


def test_the_tracking_acceleration_is_bounded_and_points_to_the_reference():
    ref = OrientationReference(16.0, 8.0, max_acceleration=3.0)
    ref.sync(0.0, _state(GOAL_P, GOAL_Q), np.zeros(6), GOAL_P)
    rng = np.random.default_rng(0)
    for _ in range(50):
        theta = rng.normal(size=3)
        quat = quat_exp(theta)
        acc = ref.tracking(quat, np.zeros(3), ref.omega)
        assert np.linalg.norm(acc) <= 3.0 + 1e-12
        err = quat_log(quat_mul(GOAL_Q, quat_conj(quat)))
        assert acc @ err > 0


@pytest.mark.parametrize("theta", [np.zeros(3), np.array([1e-13, 0, 0]),
                                   np.array([0.3, -1.2, 0.5]), np.array([0.0, 0.0, 3.1])])
def test_quaternion_exp_and_log_are_inverse(theta):
    np.testing.assert_allclose(quat_log(quat_exp(theta)), theta, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(quat_exp(theta)), 1.0, atol=1e-15)
    np.testing.assert_allclose(quat_log(-quat_exp(theta)), theta, atol=1e-12)
    from tamedpuma.puma.manifold import np_quat_exp, np_quat_log  # the torch reference

    np.testing.assert_allclose(quat_exp(theta), np_quat_exp(theta), atol=1e-15)
    np.testing.assert_allclose(quat_log(quat_exp(theta)), np_quat_log(np_quat_exp(theta)),
                               atol=1e-12)


def test_on_a_leash_the_reference_stays_near_the_hand_and_still_frees_the_position():
    """With the hand's orientation held 0.54 rad off, the free reference runs to the goal's
    orientation; on a 0.3 rad leash it stays within 0.3 rad of the hand at every step, and the
    position (which the coupled field would hold 0.08 m off) still comes closer to the goal than
    with the feedback law, as the reference leans towards the goal's orientation."""
    ref = OrientationReference(16.0, 8.0, 3.0, leash=0.3)
    task = PoseTask(CoupledPose(), ref)
    v, p = np.zeros(3), START_P.copy()
    for k in range(2000):
        state = _state(p, START_Q)
        ref.sync(k * DT, state, np.zeros(6), GOAL_P)
        angle = np.linalg.norm(quat_log(quat_mul(ref.quat, quat_conj(START_Q))))
        assert angle <= 0.3 + 1e-9
        v = v + DT * task.acceleration(state, np.concatenate([v, np.zeros(3)]), GOAL_P,
                                       GOAL_Q).xdd[:3]
        p = p + DT * v
    held_feedback, _ = _roll(PoseTask(CoupledPose()), START_P, START_Q, 2000,
                             orientation_free=False)
    assert np.linalg.norm(p - GOAL_P) < 0.7 * np.linalg.norm(held_feedback - GOAL_P)
    # the leash is reached and held: the reference is 0.3 rad from the hand, towards the goal
    assert angle == pytest.approx(0.3, abs=1e-6)


def test_a_leash_wider_than_the_error_changes_nothing():
    free = PoseTask(CoupledPose(), OrientationReference(16.0, 8.0, 3.0))
    leashed = PoseTask(CoupledPose(), OrientationReference(16.0, 8.0, 3.0, leash=3.0))
    np.testing.assert_allclose(_roll(leashed, START_P, START_Q, 300)[0],
                               _roll(free, START_P, START_Q, 300)[0], atol=1e-12)
