"""The compiled chain kinematics (tamedpuma/robot/point_motion.py) against pinocchio: the
placements, Jacobians and J̇q̇ of ``Kinematics.evaluate`` and of the frames read after it, to
rounding, compiled and plain, and against finite differences, on the iiwa and the Panda (whose
reduced model locks the fingers)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from tamedpuma.app.config import robot_config
from tamedpuma.robot import point_motion
from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config
from tamedpuma.robot.rotations import matrix_to_quat_eigen

TOL = dict(rtol=1e-12, atol=1e-12)


@pytest.fixture(scope="module", params=["iiwa14", "panda"])
def kin(request):
    return Kinematics(robot_spec_from_config(robot_config(request.param)))


def _states(kin, n=40, seed=3):
    rng = np.random.default_rng(seed)
    lo, hi = kin.spec.q_min, kin.spec.q_max
    for _ in range(n):
        yield rng.uniform(lo, hi), rng.normal(size=kin.model.nv) * 2.0


def test_the_kinematics_is_compiled_where_numba_is_installed(kin):
    assert (kin._fast is not None) == point_motion.AVAILABLE


def test_evaluate_is_pinocchios_evaluation_to_rounding(kin):
    for q, qd in _states(kin):
        ours = kin.evaluate(q, qd)
        theirs = kin._evaluate_per_frame(q, qd)
        for name in ("ee_position", "ee_rotation", "ee_quaternion", "sphere_centers",
                     "ee_jacobian", "ee_jdqd", "sphere_jacobians", "sphere_jdqd"):
            np.testing.assert_allclose(getattr(ours, name), getattr(theirs, name), **TOL,
                                       err_msg=name)


def test_evaluate_arrays_are_contiguous_and_fresh(kin):
    """The step's compiled kernels take C-contiguous arrays (another layout is another type)."""
    q, qd = next(_states(kin))
    a, b = kin.evaluate(q, qd), kin.evaluate(q, qd)
    for name in ("ee_jacobian", "ee_jdqd", "sphere_centers", "sphere_jacobians", "sphere_jdqd"):
        arr = getattr(a, name)
        assert arr.flags["C_CONTIGUOUS"], name
        assert not np.shares_memory(arr, getattr(b, name)), name


def test_frames_after_evaluate_are_pinocchios(kin):
    """frame_placements, frame_motion and link_position_jacobian at the last evaluate: the
    links' placements, Jacobians and classical accelerations of pinocchio's own pass."""
    world = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    model, data = kin.model, kin.data
    ids = kin.link_ids  # the base's frame (fixed) among them
    for q, qd in _states(kin, n=20):
        kin.evaluate(q, qd)
        R, p = kin.frame_placements(ids)
        J, acc = kin.frame_motion(ids)
        link_p, link_J = kin.link_position_jacobian(kin.spec.link_names[-1])
        pin.forwardKinematics(model, data, q, qd, np.zeros(model.nv))
        pin.computeJointJacobians(model, data)
        pin.updateFramePlacements(model, data)
        for n, fid in enumerate(ids):
            np.testing.assert_allclose(R[n], data.oMf[fid].rotation, **TOL)
            np.testing.assert_allclose(p[n], data.oMf[fid].translation, **TOL)
            np.testing.assert_allclose(J[n], pin.getFrameJacobian(model, data, fid, world),
                                       **TOL)
            np.testing.assert_allclose(
                acc[n], pin.getFrameClassicalAcceleration(model, data, fid, world).vector,
                **TOL)
        np.testing.assert_array_equal(link_p, p[-1])
        np.testing.assert_array_equal(link_J, J[-1, :3])


def test_the_quaternion_is_eigens(kin):
    rng = np.random.default_rng(2)
    for _ in range(200):
        R = pin.Quaternion(*rng.normal(size=4)).normalized().matrix()  # every branch
        np.testing.assert_allclose(matrix_to_quat_eigen(R), pin.Quaternion(R).coeffs(),
                                   rtol=0, atol=1e-15)


def test_the_plain_functions_are_the_compiled_ones(kin):
    """One code: run plain (Python loops) the functions give the compiled numbers."""
    if kin._fast is None:
        pytest.skip("numba is not installed: the kinematics uses pinocchio's calls")
    ids = kin.sphere_ids + (kin.ee_id,)
    table = kin._table(ids)
    for q, qd in _states(kin, n=10):
        fast_state = kin._fast["joint_motion"](q, qd, *kin._chain)
        plain_state = point_motion.joint_motion(q, qd, *kin._chain)
        for rows in (3, 6):
            fast = kin._fast["frame_motion"](fast_state, qd, *table, rows)
            plain = point_motion.frame_motion(plain_state, qd, *table, rows)
            for f, p in zip(fast, plain):
                np.testing.assert_allclose(f, p, rtol=1e-14, atol=1e-14)


def test_the_one_call_pass_is_the_calls_one_by_one(kin):
    """chain_evaluate (evaluate's one compiled call) gives the numbers of joint_motion, the two
    frame_motion calls and matrix_to_quat_eigen made one by one (compiled: bit for bit; plain:
    the plain functions' numbers, to rounding of the compiled ones)."""
    if kin._fast is None:
        pytest.skip("numba is not installed: the kinematics uses pinocchio's calls")
    fast = kin._fast
    tables = (*kin._chain, *kin._ee_table, *kin._sphere_table)
    for q, qd in _states(kin, n=20):
        S = fast["joint_motion"](q, qd, *kin._chain)
        ee = fast["frame_motion"](S, qd, *kin._ee_table, 6)
        spheres = fast["frame_motion"](S, qd, *kin._sphere_table, 3)
        want = (S, *ee, *spheres[1:], fast["matrix_to_quat_eigen"](ee[0][0]))
        got = fast["chain_evaluate"](q, qd, *tables)
        plain = point_motion.chain_evaluate(q, qd, *tables)
        assert len(got) == len(want) == len(plain)
        for g, w, p in zip(got, want, plain):
            np.testing.assert_array_equal(g, w)
            np.testing.assert_allclose(p, w, rtol=1e-14, atol=1e-14)
        state = kin.evaluate(q, qd)
        np.testing.assert_array_equal(state.ee_jacobian, ee[2][0])
        np.testing.assert_array_equal(state.sphere_jdqd, spheres[3])


def test_jdqd_is_the_time_derivative_of_the_jacobian_along_the_motion(kin):
    """J̇q̇ = d/dt (J(q(t))) q̇ at q(t) = q + t q̇: central differences of J q̇."""
    h = 1e-6
    for q, qd in _states(kin, n=8, seed=11):
        s = kin.evaluate(q, qd)
        plus, minus = kin.evaluate(q + h * qd, qd), kin.evaluate(q - h * qd, qd)
        fd = (plus.sphere_jacobians @ qd - minus.sphere_jacobians @ qd) / (2 * h)
        np.testing.assert_allclose(s.sphere_jdqd, fd, atol=1e-5 * (1 + np.abs(fd).max()))
        fd_ee = (plus.ee_jacobian @ qd - minus.ee_jacobian @ qd) / (2 * h)
        np.testing.assert_allclose(s.ee_jdqd, fd_ee, atol=1e-5 * (1 + np.abs(fd_ee).max()))


def test_without_numba_the_kinematics_uses_pinocchios_calls(kin, monkeypatch):
    q, qd = next(_states(kin))
    want = kin.evaluate(q, qd)
    monkeypatch.setattr(kin, "_fast", None)
    got = kin.evaluate(q, qd)
    for name in ("ee_jacobian", "ee_jdqd", "sphere_jacobians", "sphere_jdqd"):
        np.testing.assert_allclose(getattr(got, name), getattr(want, name), **TOL)
    _, _, jac = kin.ee_pose_jacobian(q)
    np.testing.assert_allclose(jac, want.ee_jacobian, **TOL)


def test_a_vector_of_the_wrong_size_is_a_value_error(kin):
    """The compiled functions do not check bounds: the kinematics does, before calling them."""
    n = kin.model.nv
    for bad in (np.zeros(n - 1), np.zeros(n + 1), np.zeros((n, 1))):
        with pytest.raises(ValueError, match=f"expected a vector of {n} joint values"):
            kin.evaluate(bad, np.zeros(n))
        with pytest.raises(ValueError, match=f"expected a vector of {n} joint values"):
            kin.ee_pose_jacobian(bad)


def test_pinocchio_data_holds_the_last_pass_when_read(kin):
    """After evaluate, ``data`` is pinocchio's own pass at its (q, q̇) (run when read); a later
    call with a pass of its own (ee_pose_jacobian, placements) leaves that pass, not
    evaluate's."""
    other = Kinematics(kin.spec)
    model, ref = other.model, other.model.createData()
    (q, qd), (q2, _) = list(_states(kin, n=2, seed=11))
    kin.evaluate(q, qd)
    pin.forwardKinematics(model, ref, q, qd, np.zeros(model.nv))
    pin.computeJointJacobians(model, ref)
    pin.updateFramePlacements(model, ref)
    data = kin.data
    for fid in kin.link_ids + (kin.ee_id,):
        np.testing.assert_array_equal(data.oMf[fid].homogeneous, ref.oMf[fid].homogeneous)
    np.testing.assert_array_equal(data.J, ref.J)
    kin.evaluate(q, qd)
    kin.ee_pose_jacobian(q2)  # its pass replaces the one evaluate left to run
    pin.forwardKinematics(model, ref, q2)
    np.testing.assert_array_equal(kin.data.oMi[model.njoints - 1].homogeneous,
                                  ref.oMi[model.njoints - 1].homogeneous)
