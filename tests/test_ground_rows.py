"""The ground rows of the control-rate barrier step (tamedpuma/robot/ground.py): each moving link's
lowest collision-hull point, its height checked against every mesh vertex placed by an independent
forward-kinematics route, its row and curvature term against finite differences, and the barrier
step keeping every link's mesh above the plane while the arm is driven into the ground."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.app.config import robot_config
from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._tamed import ControlRate
from tamedpuma.robot.body_model import urdf_collision_geometry
from tamedpuma.robot.ground import (
    hull_ground_rows,
    hull_heights_from_poses,
    link_hulls,
    sphere_ground_rows,
)
from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config
from tamedpuma.robot.rotations import quat_to_matrix

Q0 = np.array([0.0, 0.7, 0.0, -1.2, 0.0, 1.0, 0.0])


@pytest.fixture(scope="module")
def hulls(kinematics):
    return link_hulls(kinematics)


def _rows_at(kinematics, hulls, q, qd, below=np.inf):
    """The ground rows at (q, q̇): one evaluate, then the rows read from its pass."""
    kinematics.evaluate(q, qd)
    return hull_ground_rows(kinematics, hulls, qd, below)


def _lowest_mesh_points(kinematics, hulls, q):
    """min z over every vertex of each hull link's mesh, placed with link_poses (quaternions)."""
    geometry = urdf_collision_geometry(kinematics.spec.urdf_path)
    pos, quat = kinematics.link_poses(q)
    names = list(kinematics.spec.link_names)
    out = []
    for link in hulls.links:
        i = names.index(link)
        world = geometry[link].vertices @ quat_to_matrix(quat[i]).T + pos[i]
        out.append(world[:, 2].min())
    return np.array(out)


def test_the_hulls_are_the_moving_links(kinematics, hulls):
    assert "lbr_iiwa_link_0" not in hulls.links  # the base never moves
    assert {"lbr_iiwa_link_4", "lbr_iiwa_link_7"} <= set(hulls.links)
    assert all(v.ndim == 2 and v.shape[1] == 3 and len(v) >= 4 for v in hulls.vertices)


def test_heights_are_the_lowest_mesh_points(kinematics, hulls):
    rng = np.random.default_rng(0)
    lo, hi = kinematics.spec.q_min, kinematics.spec.q_max
    for _ in range(10):
        q = rng.uniform(lo, hi)
        g = _rows_at(kinematics, hulls, q, np.zeros(7))
        assert np.allclose(g.heights, _lowest_mesh_points(kinematics, hulls, q), atol=1e-9)
        logged = hull_heights_from_poses(hulls, kinematics.spec.link_names,
                                         *kinematics.link_poses(q))  # a step record's poses
        assert np.allclose(logged, g.heights, atol=1e-9)
        low = _rows_at(kinematics, hulls, q, np.zeros(7), below=0.3)
        assert np.array_equal(low.heights, g.heights[g.heights < 0.3])


def test_a_grippers_fingers_are_hulls_too():
    panda = link_hulls(Kinematics(robot_spec_from_config(robot_config("panda"))))
    assert {"panda_hand", "panda_leftfinger", "panda_rightfinger"} <= set(panda.links)
    assert "panda_link0" not in panda.links


def test_rows_and_curvature_match_finite_differences(kinematics, hulls):
    """a = ∂x/∂q and ȧq̇ = d²x/dt² along q(t) = q + t q̇ (q̈ = 0), both by central differences
    (the lowest vertex stays the same over the tiny steps)."""
    rng = np.random.default_rng(1)
    for _ in range(10):
        q = rng.uniform(kinematics.spec.q_min + 0.2, kinematics.spec.q_max - 0.2)
        qd = rng.normal(size=7)
        g = _rows_at(kinematics, hulls, q, qd)
        h = 1e-6
        x = [_rows_at(kinematics, hulls, q + s * h * qd, qd).heights for s in (-1, 0, 1)]
        assert np.allclose(g.rows @ qd, (x[2] - x[0]) / (2 * h), atol=1e-6)
        h = 1e-4
        x = [_rows_at(kinematics, hulls, q + s * h * qd, qd).heights for s in (-1, 0, 1)]
        second = (x[2] - 2 * x[1] + x[0]) / h**2
        assert np.allclose(g.jdqd, second, atol=1e-3 * (1 + np.abs(g.jdqd)))


def _rows_link_by_link(kinematics, hulls, q, qd, below):
    """The ground rows written out link by link from pinocchio's own pass and per-frame calls
    (the reference the batched :func:`hull_ground_rows` must equal to rounding)."""
    import pinocchio as pin

    world = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    model, data = kinematics.model, kinematics.data
    pin.forwardKinematics(model, data, q, qd, np.zeros(model.nv))
    pin.computeJointJacobians(model, data)
    pin.updateFramePlacements(model, data)
    heights, rows, jdqd = [], [], []
    for fid, v in zip(hulls.frame_ids, hulls.vertices):
        placement = data.oMf[fid]
        R = placement.rotation
        z = v @ R[2]
        j = int(np.argmin(z))
        height = float(placement.translation[2] + z[j])
        if height >= below:
            continue
        r = R @ v[j]
        J = pin.getFrameJacobian(model, data, fid, world)
        acc = pin.getFrameClassicalAcceleration(model, data, fid, world)
        lin, ang, w = acc.linear, acc.angular, J[3:] @ qd
        heights.append(height)
        rows.append(J[2] + J[3] * r[1] - J[4] * r[0])
        jdqd.append(lin[2] + ang[0] * r[1] - ang[1] * r[0]
                    + w[2] * float(w @ r) - r[2] * float(w @ w))
    return np.array(heights), np.array(rows).reshape(-1, model.nv), np.array(jdqd)


def test_the_batched_rows_are_the_link_by_link_formula_to_rounding(kinematics, hulls):
    """The same numbers to rounding: the rows read the placements, Jacobians and curvature
    terms of the kinematics' own route (pinocchio's per-frame calls, or the compiled chain
    kinematics: tamedpuma/robot/point_motion.py), the reference pinocchio's."""
    rng = np.random.default_rng(5)
    lo, hi = kinematics.spec.q_min, kinematics.spec.q_max
    for i in range(200):
        q, qd = rng.uniform(lo, hi), rng.normal(size=7) * 2.0
        below = (np.inf, 0.377, 0.2)[i % 3]
        got = _rows_at(kinematics, hulls, q, qd, below)
        want = _rows_link_by_link(kinematics, hulls, q, qd, below)
        for ours, theirs in zip((got.heights, got.rows, got.jdqd), want):
            np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)


def test_the_sphere_rows_are_the_body_spheres(kinematics):
    state = kinematics.evaluate(Q0, np.ones(7))
    g = sphere_ground_rows(state)
    assert np.allclose(g.heights, state.sphere_centers[:, 2] - state.sphere_radii)
    assert np.array_equal(g.rows, state.sphere_jacobians[:, 2, :])


@pytest.mark.parametrize("geometry", ["mesh", "spheres"])
def test_the_barrier_step_keeps_the_links_above_the_plane(kinematics, hulls, geometry):
    """Drive the hand straight down at 0.5 m/s for 1.2 s through the barrier step: the rows of
    the chosen geometry never go below the plane. The mesh rows let the hand closer to the
    ground than the spheres (the hand's 7 cm sphere), and every link's mesh stays above it."""
    rate = ControlRate(barrier_step=True)  # ground rows 1 cm above the plane
    fab = Fabric(FabricGains(), kinematics.spec.q_min, kinematics.spec.q_max)
    q, qd, dt = Q0.copy(), np.zeros(7), 0.02
    far = np.array([[5.0, 5.0, 5.0]]), np.array([0.05]), np.zeros((1, 3))
    for _ in range(60):
        state = kinematics.evaluate(q, qd)
        J = state.ee_jacobian[:3]
        want = np.linalg.pinv(J) @ np.array([0.0, 0.0, -0.5])
        av = fab.avoidance(state, q, qd, *far)
        rows = (_rows_at(kinematics, hulls, q, qd) if geometry == "mesh"
                else sphere_ground_rows(state))
        qd, _ = rate.next_velocity(want, av, dt, kinematics.spec.qd_max, rows, qd)
        q = q + dt * qd
        g = (_rows_at(kinematics, hulls, q, qd) if geometry == "mesh"
             else sphere_ground_rows(kinematics.evaluate(q, qd)))
        assert g.heights.min() > 0.0
    lowest = _lowest_mesh_points(kinematics, hulls, q).min()
    assert lowest > 0.0
    hand_z = kinematics.ee_pose(q)[0][2]
    if geometry == "mesh":
        assert lowest < 0.03 and hand_z < 0.07  # down to the plane, below the sphere's 8 cm
    else:
        assert hand_z > 0.07


def test_no_hull_point_moves_up_or_down_faster_than_its_bound(kinematics, hulls):
    """The per-hull bounds that decide which links need a row hold at random configurations
    with every joint at its speed limit, either sign (each hull's fastest vertical speed, by
    differencing its vertices' heights over a tiny step), and are not vacuous: within 3x of
    the fastest seen for the links beyond the shoulder; the first link, turning about the
    vertical, never moves up or down (bound 0)."""
    import pinocchio as pin

    rng = np.random.default_rng(5)
    model, data = kinematics.model, kinematics.data
    bounds = np.array(hulls.speed_bounds)
    fastest = np.zeros(len(bounds))
    for _ in range(300):
        q = rng.uniform(kinematics.spec.q_min, kinematics.spec.q_max)
        qd = kinematics.spec.qd_max * rng.choice([-1.0, 1.0], size=7)
        h = 1e-7
        heights = []
        for qq in (q, q + h * qd):
            pin.framesForwardKinematics(model, data, qq)
            heights.append([v @ data.oMf[f].rotation[2] + data.oMf[f].translation[2]
                            for f, v in zip(hulls.frame_ids, hulls.vertices)])
        speeds = [float(np.max(np.abs(b - a))) / h for a, b in zip(*heights)]
        fastest = np.maximum(fastest, speeds)
    first = hulls.links.index("lbr_iiwa_link_1")
    assert bounds[first] == 0.0 and fastest[first] < 1e-6
    assert np.all(fastest <= bounds + 1e-6)
    beyond = [i for i, link in enumerate(hulls.links) if link[-1] in "34567"]
    assert np.all(fastest[beyond] > bounds[beyond] / 3)
