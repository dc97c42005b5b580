"""The forward kinematics of a chain of revolute joints with the placements, Jacobians and
curvature terms of any frames on it, in two compiled calls (numba, where installed: the
``fast`` extra).

Joint j turns by q_j about its axis a_j (its own frame) after the fixed placement (R⁰_j, p⁰_j)
from its parent joint: in the world, its rotation and origin

    R_j = R_parent (R⁰_j Rot(a_j, q_j)),     o_j = R_parent p⁰_j + o_parent,

its axis z_j = R_j a_j, its body's angular velocity ω_j = ω_parent + z_j q̇_j and its origin's
velocity ȯ_j = ȯ_parent + ω_parent × (o_j − o_parent) (:func:`joint_motion`). A frame fixed
to joint j at (R_f, p_f) is at R = R_j R_f, p = R_j p_f + o_j, moves at ṗ = ȯ_j + ω_j × (p − o_j)
and, summed over the joints k that support it (the mask s),

    J_p   = [ z_k × (p − o_k) ;  z_k ]_k                                  (6, n)  [m/rad; 1]
    J̇_p q̇ = Σ_k q̇_k [ (ω_k × z_k) × (p − o_k) + z_k × (ṗ − ȯ_k) ;  ω_k × z_k ]   [m/s²; rad/s²]

(:func:`frame_motion`): the world-aligned Jacobian at the frame's origin and its classical
acceleration at q̈ = 0, the numbers of pinocchio's ``getFrameJacobian`` and
``getFrameClassicalAcceleration`` (LOCAL_WORLD_ALIGNED) to rounding, without their Python call
per frame and quantity (tests/test_point_motion.py holds them to 1e-12 and to finite
differences). The end effector's quaternion is Eigen's conversion, as pinocchio's
(:func:`~tamedpuma.robot.rotations.matrix_to_quat_eigen`).

The functions are plain Python loops: compiled by numba the end effector and every body sphere
are one call of a few microseconds (:func:`chain_evaluate`); run plain they are slower than
pinocchio's own calls, so :class:`~tamedpuma.robot.kinematics.Kinematics` uses pinocchio where
numba is missing (:func:`compiled` is None) or the model has a joint other than a revolute one.
"""

from __future__ import annotations

import importlib.util
import math

import numpy as np

from tamedpuma.robot.rotations import matrix_to_quat_eigen

#: numba is installed (imported only by :func:`compiled`)
AVAILABLE = importlib.util.find_spec("numba") is not None
_COMPILED: list = []  # [] before the first compiled(); then [dict of functions, or None]


def joint_motion(q, qd, R0, p0, axes, parents):
    """The joint state S (n, 7, 3) at (q, q̇) (see the module): per joint its world rotation R
    (rows 0-2), origin o [m] (3), axis z (4), body angular velocity ω [rad/s] (5) and origin
    velocity ȯ [m/s] (6), one array (returning each alone costs a boxing each);
    R0 (n, 3, 3), p0 (n, 3): the placements from the parent joints, axes (n, 3): unit axes in
    the joints' frames, parents (n,): the parent joint's index (−1: the base)."""
    n = q.shape[0]
    S = np.empty((n, 7, 3))
    R, o, z, w, od = S[:, :3], S[:, 3], S[:, 4], S[:, 5], S[:, 6]
    L = np.empty((3, 3))
    for j in range(n):
        # the joint's own turn Rq: Rodrigues about the unit axis a; L = R⁰ Rq
        ax, ay, az = axes[j, 0], axes[j, 1], axes[j, 2]
        c, s = math.cos(q[j]), math.sin(q[j])
        t = 1.0 - c
        q00, q01, q02 = c + t * ax * ax, t * ax * ay - s * az, t * ax * az + s * ay
        q10, q11, q12 = t * ax * ay + s * az, c + t * ay * ay, t * ay * az - s * ax
        q20, q21, q22 = t * ax * az - s * ay, t * ay * az + s * ax, c + t * az * az
        for a in range(3):
            r0, r1, r2 = R0[j, a, 0], R0[j, a, 1], R0[j, a, 2]
            L[a, 0] = r0 * q00 + r1 * q10 + r2 * q20
            L[a, 1] = r0 * q01 + r1 * q11 + r2 * q21
            L[a, 2] = r0 * q02 + r1 * q12 + r2 * q22
        par = parents[j]
        if par < 0:
            R[j] = L
            o[j] = p0[j]
            wx = wy = wz = 0.0
            od[j, 0] = od[j, 1] = od[j, 2] = 0.0
        else:
            for a in range(3):
                for b in range(3):
                    R[j, a, b] = (R[par, a, 0] * L[0, b] + R[par, a, 1] * L[1, b]
                                  + R[par, a, 2] * L[2, b])
                o[j, a] = (R[par, a, 0] * p0[j, 0] + R[par, a, 1] * p0[j, 1]
                           + R[par, a, 2] * p0[j, 2]) + o[par, a]
            wx, wy, wz = w[par, 0], w[par, 1], w[par, 2]
            rx, ry, rz = o[j, 0] - o[par, 0], o[j, 1] - o[par, 1], o[j, 2] - o[par, 2]
            od[j, 0] = od[par, 0] + (wy * rz - wz * ry)
            od[j, 1] = od[par, 1] + (wz * rx - wx * rz)
            od[j, 2] = od[par, 2] + (wx * ry - wy * rx)
        for a in range(3):
            z[j, a] = R[j, a, 0] * ax + R[j, a, 1] * ay + R[j, a, 2] * az
        w[j, 0] = wx + z[j, 0] * qd[j]
        w[j, 1] = wy + z[j, 1] * qd[j]
        w[j, 2] = wz + z[j, 2] * qd[j]
    return S


def frame_motion(S, qd, parents, Rf, pf, support, rows):
    """The frames' world rotations (F, 3, 3), origins (F, 3) [m], Jacobians (F, rows, n) and
    J̇q̇ (F, rows) (rows 0: the placements only; 3: the position rows; 6: [linear; angular])
    from :func:`joint_motion`'s joint state S; each frame fixed to joint ``parents[f]`` at
    (Rf[f], pf[f]), moved by the joints ``support[f]`` (bool (n,))."""
    F, n = parents.shape[0], S.shape[0]
    R, o, z, w, od = S[:, :3], S[:, 3], S[:, 4], S[:, 5], S[:, 6]
    Rw, p = np.empty((F, 3, 3)), np.empty((F, 3))
    jac, acc = np.zeros((F, rows, n)), np.zeros((F, rows))
    for f in range(F):
        j = parents[f]
        if j < 0:  # fixed to the base: no motion
            Rw[f] = Rf[f]
            p[f] = pf[f]
            continue
        for a in range(3):
            for b in range(3):
                Rw[f, a, b] = (R[j, a, 0] * Rf[f, 0, b] + R[j, a, 1] * Rf[f, 1, b]
                               + R[j, a, 2] * Rf[f, 2, b])
            p[f, a] = (R[j, a, 0] * pf[f, 0] + R[j, a, 1] * pf[f, 1]
                       + R[j, a, 2] * pf[f, 2]) + o[j, a]
        if rows == 0:  # placements only
            continue
        px, py, pz = p[f, 0], p[f, 1], p[f, 2]
        rx, ry, rz = px - o[j, 0], py - o[j, 1], pz - o[j, 2]
        vx = od[j, 0] + (w[j, 1] * rz - w[j, 2] * ry)  # ṗ
        vy = od[j, 1] + (w[j, 2] * rx - w[j, 0] * rz)
        vz = od[j, 2] + (w[j, 0] * ry - w[j, 1] * rx)
        for k in range(n):
            if not support[f, k]:
                continue
            zx, zy, zz = z[k, 0], z[k, 1], z[k, 2]
            ex, ey, ez = px - o[k, 0], py - o[k, 1], pz - o[k, 2]
            jac[f, 0, k] = zy * ez - zz * ey
            jac[f, 1, k] = zz * ex - zx * ez
            jac[f, 2, k] = zx * ey - zy * ex
            # ż_k = ω_k × z_k
            dx = w[k, 1] * zz - w[k, 2] * zy
            dy = w[k, 2] * zx - w[k, 0] * zz
            dz = w[k, 0] * zy - w[k, 1] * zx
            # ṗ − ȯ_k
            ux, uy, uz = vx - od[k, 0], vy - od[k, 1], vz - od[k, 2]
            v = qd[k]
            acc[f, 0] += v * ((dy * ez - dz * ey) + (zy * uz - zz * uy))
            acc[f, 1] += v * ((dz * ex - dx * ez) + (zz * ux - zx * uz))
            acc[f, 2] += v * ((dx * ey - dy * ex) + (zx * uy - zy * ux))
            if rows == 6:
                jac[f, 3, k], jac[f, 4, k], jac[f, 5, k] = zx, zy, zz
                acc[f, 3] += v * dx
                acc[f, 4] += v * dy
                acc[f, 5] += v * dz
    return Rw, p, jac, acc


def chain_evaluate(q, qd, R0, p0, axes, parents, ee_parents, ee_Rf, ee_pf, ee_support,
                   s_parents, s_Rf, s_pf, s_support):
    """One kinematics pass in one call: :func:`joint_motion` at (q, q̇), then
    :func:`frame_motion` of the end effector (rows 6) and of the body spheres (rows 3) and the
    end effector's quaternion (:func:`~tamedpuma.robot.rotations.matrix_to_quat_eigen`), the
    calls :class:`~tamedpuma.robot.kinematics.Kinematics` would make one by one. Returns
    (S, R_ee (1, 3, 3), p_ee (1, 3), J_ee (1, 6, n), J̇q̇_ee (1, 6), sphere centres (F, 3),
    their Jacobians (F, 3, n), their J̇q̇ (F, 3), quaternion (4,))."""
    S = joint_motion(q, qd, R0, p0, axes, parents)
    R, p, J, acc = frame_motion(S, qd, ee_parents, ee_Rf, ee_pf, ee_support, 6)
    _, centers, jacobians, jdqd = frame_motion(S, qd, s_parents, s_Rf, s_pf, s_support, 3)
    return S, R, p, J, acc, centers, jacobians, jdqd, matrix_to_quat_eigen(R[0])


FUNCTIONS = (joint_motion, frame_motion, matrix_to_quat_eigen)


def compiled() -> dict | None:
    """:data:`FUNCTIONS` compiled by numba (from its on-disk cache after the first time) by
    name, each called once here with the argument types the kinematics passes, then frozen: they
    compile nothing more inside a step, and a call with other argument types raises TypeError.
    None without numba, or where numba fails to compile (with a warning)."""
    from tamedpuma.jit import compile_once

    return compile_once(_COMPILED, _compile, AVAILABLE, "the chain kinematics",
                        "pinocchio answers")


def _compile() -> dict:
    """:data:`FUNCTIONS` and :func:`chain_evaluate` compiled, called once each and frozen."""
    import numba

    from tamedpuma.jit import compile_kernels

    fast = {f.__name__: numba.njit(cache=True, nogil=True)(f) for f in FUNCTIONS}
    fast.update(compile_kernels(globals(), (chain_evaluate,), FUNCTIONS))
    _first_calls(fast)
    return fast


def _first_calls(fast: dict, n: int = 2) -> None:
    """One call per argument-type combination the kinematics passes (C-contiguous float64
    arrays, int64 parents, bool supports, int rows), then no more compiling."""
    q, eye = np.zeros(n), np.eye(3)
    state = fast["joint_motion"](q, q, np.stack([eye] * n), np.zeros((n, 3)),
                                 np.tile([0.0, 0.0, 1.0], (n, 1)), np.arange(n) - 1)
    for rows in (0, 3, 6):
        fast["frame_motion"](state, q, np.zeros(1, np.int64), eye[None], np.zeros((1, 3)),
                             np.ones((1, n), np.bool_), rows)
    fast["matrix_to_quat_eigen"](eye)
    frame = (np.zeros(1, np.int64), eye[None], np.zeros((1, 3)), np.ones((1, n), np.bool_))
    fast["chain_evaluate"](q, q, np.stack([eye] * n), np.zeros((n, 3)),
                           np.tile([0.0, 0.0, 1.0], (n, 1)), np.arange(n) - 1, *frame, *frame)
    for f in fast.values():
        f.disable_compile()
