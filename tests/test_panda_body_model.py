"""The Franka Panda from pybullet_data: its URDF in pinocchio against PyBullet, and the body
collision models generated from the URDF collision meshes (Panda and iiwa) against their claims."""

from __future__ import annotations

import re

import numpy as np
import pybullet as pb
import pytest

from tamedpuma.app.config import CONF_DIR, robot_config
from tamedpuma.robot import body_model as bm
from tamedpuma.robot.ik import solve_pose_ik
from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config
from tamedpuma.robot.rotations import quat_to_matrix, rotation_error


def _spec(name):
    cfg = robot_config(name)  # a derived option (iiwa14_mesh): its base, then its own keys
    return cfg, robot_spec_from_config(cfg)


@pytest.fixture(scope="module")
def panda():
    cfg, spec = _spec("panda")
    return spec, Kinematics(spec)


def test_panda_fk_of_every_link_and_sphere_equals_pybullet(panda):
    spec, kin = panda
    rng = np.random.default_rng(0)
    client = pb.connect(pb.DIRECT)
    try:
        robot = pb.loadURDF(spec.urdf_path, useFixedBase=True, physicsClientId=client)
        info = [pb.getJointInfo(robot, i, physicsClientId=client)
                for i in range(pb.getNumJoints(robot, physicsClientId=client))]
        joint = {i[1].decode(): i[0] for i in info}
        child = {i[12].decode(): i[0] for i in info}
        link_idx = [child[n] for n in spec.link_names[1:]]
        for q in rng.uniform(spec.q_min, spec.q_max, size=(60, spec.dof)):
            for name, qj in zip(spec.joint_names, q):
                pb.resetJointState(robot, joint[name], qj, physicsClientId=client)
            states = pb.getLinkStates(robot, link_idx, computeForwardKinematics=True,
                                      physicsClientId=client)
            pos, quat = kin.link_poses(q)
            np.testing.assert_allclose(pos[0], 0.0, atol=1e-12)
            for k, s in enumerate(states, start=1):
                np.testing.assert_allclose(pos[k], s[4], atol=1e-6)
                np.testing.assert_allclose(quat_to_matrix(quat[k]), quat_to_matrix(s[5]),
                                           atol=1e-6)
            # every body sphere: its link's PyBullet frame plus the offset
            centers = kin.sphere_centers(q)
            for c, sphere in zip(centers, spec.spheres):
                s = states[spec.link_names.index(sphere.link) - 1]
                want = np.asarray(s[4]) + quat_to_matrix(s[5]) @ np.asarray(sphere.offset)
                np.testing.assert_allclose(c, want, atol=1e-6)
    finally:
        pb.disconnect(client)


def test_panda_limits_are_the_datasheets_and_inside_the_urdfs(panda):
    spec, kin = panda
    np.testing.assert_allclose(spec.q_min, [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973,
                                            -0.0175, -2.8973])
    np.testing.assert_allclose(spec.qd_max, [2.175] * 4 + [2.61] * 3)
    assert np.all(spec.q_min >= kin.model.lowerPositionLimit - 1e-9)
    assert np.all(spec.q_max <= kin.model.upperPositionLimit + 1e-9)
    assert kin.model.nq == 7  # fingers locked


def test_panda_jacobian_and_ik(panda):
    spec, kin = panda
    rng = np.random.default_rng(1)
    h = 1e-6
    for q in rng.uniform(spec.q_min, spec.q_max, size=(10, 7)):
        jac = kin.evaluate(q, np.zeros(7)).ee_jacobian
        fd = np.zeros((6, 7))
        for i in range(7):
            dq = np.zeros(7)
            dq[i] = h
            (p1, q1), (p0, q0) = kin.ee_pose(q + dq), kin.ee_pose(q - dq)
            fd[:3, i] = (p1 - p0) / (2 * h)
            fd[3:, i] = rotation_error(quat_to_matrix(q0), quat_to_matrix(q1)) / (2 * h)
        np.testing.assert_allclose(jac, fd, atol=1e-5)
    mid = (spec.q_min + spec.q_max) / 2
    q_goal = mid + rng.uniform(-0.3, 0.3, 7) * (spec.q_max - spec.q_min) / 2
    p, quat = kin.ee_pose(q_goal)
    result = solve_pose_ik(kin, p, quat, np.clip(q_goal + rng.normal(0, 0.2, 7), spec.q_min,
                                                 spec.q_max))
    assert result.converged
    np.testing.assert_allclose(kin.ee_pose(result.q)[0], p, atol=1e-5)


def _frames(kin, q):
    import pinocchio as pin

    pin.framesForwardKinematics(kin.model, kin.data, q)

    def frame(link):
        m = kin.data.oMf[kin.model.getFrameId(link)]
        return m.rotation.copy(), m.translation.copy()

    return frame


@pytest.mark.parametrize("robot", ["panda", "iiwa14_mesh"])
def test_generated_body_model_holds_every_collision_vertex_within_its_tolerance(robot):
    """The committed generated spheres, at random configurations: every collision-mesh vertex of
    every covered link (and merged fingers) is within the stated tolerance; the volumes stated in
    the config match a recomputation (excess > 0, missed hull volume ~ 0)."""
    cfg, spec = _spec(robot)
    kin = Kinematics(spec)
    tol = float(cfg.body_model_tolerance)
    links = sorted({s.link for s in spec.spheres} | set(cfg.body_model.merge))
    spheres = [(s.link, s.offset, s.radius) for s in spec.spheres]
    rng = np.random.default_rng(2)
    for q in rng.uniform(spec.q_min, spec.q_max, size=(5, spec.dof)):
        cov = bm.coverage_of(spec.urdf_path, spheres, _frames(kin, q), links)
        assert cov["max_outside_m"] <= tol + 1e-9, cov
        assert cov["vertices"] > 500
    # the stated volumes (comment lines of the generated block) are what the spheres give
    text = (CONF_DIR / "robot" / f"{robot}.yaml").read_text()
    stated = {m[0]: (float(m[1]), float(m[2]), float(m[3])) for m in re.findall(
        r"#\s+(\S+): \d+ sphere\(s\), hull ([\d.]+), union ([\d.]+), excess ([\d.]+)", text)}
    assert set(stated) == {s.link for s in spec.spheres}
    geoms = bm.urdf_collision_geometry(spec.urdf_path)
    for link, (hull, union, excess) in stated.items():
        assert excess > 0
        mine = [s for s in spec.spheres if s.link == link]
        merged_into = link in cfg.body_model.merge.values()
        vol = None if merged_into else bm.volumes(
            geoms[link].vertices, [s.offset for s in mine], [s.radius for s in mine],
            samples=40_000)
        if vol is not None:
            assert vol["hull"] * 1e3 == pytest.approx(hull, rel=0.08, abs=0.05)
            assert vol["union"] * 1e3 == pytest.approx(union, rel=0.08, abs=0.05)
            assert vol["missed"] <= 0.02 * vol["hull"]


def test_fitting_a_link_covers_its_vertices_and_states_its_volumes():
    _, spec = _spec("panda")
    (fit,) = bm.fit_body(spec.urdf_path, ["panda_link4"], samples=20_000)
    assert fit.max_outside <= 1e-9 and fit.excess_volume > 0
    assert fit.union_volume >= fit.hull_volume - fit.missed_volume - 1e-6
    (loose,) = bm.fit_body(spec.urdf_path, ["panda_link4"], tolerance=0.01, samples=20_000)
    assert 0 < loose.max_outside <= 0.01 + 1e-9
    assert loose.union_volume < fit.union_volume


def test_the_body_model_command_writes_a_robot_option_and_updates_its_block(tmp_path):
    from omegaconf import OmegaConf

    from tamedpuma.app import body_model as app

    out = tmp_path / "robot" / "panda_quick.yaml"
    args = ["robot=panda", f"out={out}", "samples=4000", "max_spheres=1"]
    assert app.main(args) == 0
    text = out.read_text()
    assert text.count(app.BEGIN) == 1 and "excess" in text and "defaults:" in text
    cfg = OmegaConf.to_container(OmegaConf.load(out))
    assert len(cfg["spheres"]) == 8 and cfg["body_model_tolerance"] == 0.0  # one per link
    assert cfg["guard_spheres"] == []  # a generated covering takes no guards from its base
    # run again on the file it wrote: the block is replaced, not appended
    assert app.main(args) == 0
    assert out.read_text().count(app.BEGIN) == 1
    bare = tmp_path / "bare.yaml"
    bare.write_text("name: x\n")
    assert app.main(["robot=panda", f"out={bare}", "samples=4000", "max_spheres=1"]) == 2


def test_a_robot_of_a_users_config_folder_is_updated_in_that_folder(tmp_path):
    """``--config-dir DIR robot=mine``: the block of ``DIR/robot/mine.yaml`` is rewritten, and
    nothing is written into the package's config folder (installed: site-packages)."""
    from omegaconf import OmegaConf

    from tamedpuma.app import body_model as app

    mine = tmp_path / "robot" / "mine.yaml"
    mine.parent.mkdir()
    mine.write_text(f"defaults:\n  - panda\n  - _self_\nname: mine\n{app.BEGIN}\n{app.END}\n")
    before = set((CONF_DIR / "robot").iterdir())
    try:
        assert app.main(["--config-dir", str(tmp_path), "robot=mine", "samples=4000",
                         "max_spheres=1"]) == 0
    finally:
        written = set((CONF_DIR / "robot").iterdir()) - before
        for path in written:  # not left behind for the other tests when this one fails
            path.unlink()
    assert not written, f"wrote into the package: {sorted(map(str, written))}"
    assert len(OmegaConf.to_container(OmegaConf.load(mine))["spheres"]) == 8
    assert app.robot_file(["robot=panda"]) == CONF_DIR / "robot" / "panda.yaml"
