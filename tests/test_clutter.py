"""Feasible clutter (tamedpuma/worlds/clutter.py): kept clear of a reference motion's swept
volume, so the reference stays a collision-free path of the cluttered scene."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tamedpuma.errors import ScenarioError
from tamedpuma.worlds.clutter import place_clutter, skeleton, swept_volume

Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])  # the default start
Q1 = Q0 + np.array([1.2, 0.5, 0.0, 0.6, 0.0, 0.4, 0.0])
PATH = Q0 + np.linspace(0.0, 1.0, 60)[:, None] * (Q1 - Q0)  # a joint-space line, 60 samples
OWN_CENTERS = np.array([[0.5, -0.3, 0.5], [0.24355761, 0.45252747, 0.2]])
OWN_RADII = np.array([0.05, 0.05])
BOX = ([-1.2, -1.2, 0.05], [1.2, 1.2, 1.4])
MARGIN, RADIUS, ARM = 0.05, 0.05, 0.15


def _fine(path: np.ndarray, factor: int = 10) -> np.ndarray:
    """The joint-linear path at ``factor`` × its samples (what the sweep's motion passes)."""
    s = np.linspace(0.0, 1.0, factor + 1)[:-1]
    rows = [a + s[:, None] * (b - a) for a, b in zip(path[:-1], path[1:])]
    return np.concatenate([*rows, path[-1:]])


@pytest.fixture(scope="module")
def volume(kinematics):
    return swept_volume(kinematics, PATH, arm_radius=ARM)


@pytest.fixture(scope="module", params=["box", "shell"])
def placed(request, volume):
    def draw(seed: int, count: int = 1000):
        return place_clutter(count, RADIUS, *BOX, volume, MARGIN, OWN_CENTERS, OWN_RADII,
                             np.random.default_rng(seed), region=request.param)
    return request.param, draw


def test_count_is_exact_and_a_seed_gives_the_same_clutter(placed):
    _, draw = placed
    a, b, c = draw(3), draw(3), draw(4)
    assert a.shape == (1000, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.all(a >= BOX[0]) and np.all(a <= BOX[1])
    gaps = np.linalg.norm(a[:, None] - a[None], axis=-1) + np.eye(len(a)) * 9
    assert gaps.min() > 2 * RADIUS  # no two overlap
    own = np.linalg.norm(a[:, None] - OWN_CENTERS[None], axis=-1) - RADIUS - OWN_RADII
    assert own.min() > 0  # nor the scenario's own obstacles


def test_every_sphere_is_clear_of_the_swept_volume_by_the_margin(placed, volume):
    region, draw = placed
    centers = draw(5)
    assert volume.clearance(centers, RADIUS).min() >= MARGIN + 0.5 * volume.resolution - 1e-9
    if region == "shell":  # dense round the reference: every sphere within the shell
        assert volume.clearance(centers, RADIUS).max() <= MARGIN + 0.5 * volume.resolution + 0.3


def test_the_reference_stays_collision_free_among_the_clutter(placed, kinematics):
    """At 10 × the reference's samples: every body sphere and every link-axis point is at least
    the margin from every clutter sphere's surface (body spheres at their own radius)."""
    _, draw = placed
    centers = draw(6)
    radii = kinematics.spec.sphere_radii
    for q in _fine(PATH):
        spheres = kinematics.sphere_centers(q)
        gap = (np.linalg.norm(spheres[:, None] - centers[None], axis=-1)
               - radii[:, None] - RADIUS)
        assert gap.min() >= MARGIN - 1e-9
        axis = skeleton(kinematics, q, 0.01)
        gap = np.linalg.norm(axis[:, None] - centers[None], axis=-1) - RADIUS
        assert gap.min() >= MARGIN + ARM - 1e-9


def test_pybullet_finds_the_arm_meshes_clear_of_the_clutter(placed, robot_spec, kinematics):
    """PyBullet's mesh distances along the reference (every 3rd fine sample): no link of the
    URDF comes within the margin of a clutter sphere."""
    import pybullet as pb

    _, draw = placed
    centers = draw(7)
    client = pb.connect(pb.DIRECT)
    try:
        robot = pb.loadURDF(robot_spec.urdf_path, useFixedBase=True, physicsClientId=client)
        names = [pb.getJointInfo(robot, i, physicsClientId=client)[1].decode()
                 for i in range(pb.getNumJoints(robot, physicsClientId=client))]
        joints = [names.index(n) for n in robot_spec.joint_names]
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=RADIUS, physicsClientId=client)
        ids = [pb.createMultiBody(0, shape, -1, list(c), physicsClientId=client)
               for c in centers]
        nearest = np.inf
        for q in _fine(PATH)[::3]:
            for j, v in zip(joints, q):
                pb.resetJointState(robot, j, float(v), physicsClientId=client)
            near = np.flatnonzero(np.linalg.norm(
                centers[:, None] - skeleton(kinematics, q, 0.05)[None], axis=-1).min(1) < 0.4)
            for i in near:
                for p in pb.getClosestPoints(robot, ids[i], MARGIN + 0.05,
                                             physicsClientId=client):
                    nearest = min(nearest, p[8])
        assert nearest >= MARGIN
    finally:
        pb.disconnect(client)


def test_too_many_spheres_is_a_one_line_error(volume):
    with pytest.raises(ScenarioError, match=r"cannot place 500 clutter spheres .* only \d+ fit"):
        place_clutter(500, RADIUS, [0.0, 0.0, 0.05], [0.4, 0.4, 0.4], volume, MARGIN,
                      OWN_CENTERS, OWN_RADII, np.random.default_rng(0), max_tries=20_000)


def test_swept_volume_samples_every_point_within_the_resolution(kinematics, volume):
    """Between any two consecutive fine configurations, every skeleton point is within the
    resolution of a sampled point (so the half-resolution term in the margin covers it)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(volume.points)
    for q in _fine(PATH, 7):
        d, _ = tree.query(skeleton(kinematics, q, volume.resolution))
        assert d.max() <= volume.resolution


def test_build_scenario_keeps_path_clutter_clear_and_needs_a_reference(robot_spec, kinematics):
    from test_scenarios import _run_cfg

    from tamedpuma.worlds.scenarios import build_scenario

    cfg = _run_cfg(clutter=dict(total=100, keep_clear="path", margin=MARGIN, region="shell",
                                shell=0.3, arm_radius=ARM))
    path = Q0 + np.linspace(0.0, 1.0, 40)[:, None] * (Q1 - Q0)
    calls = []

    def reference():
        calls.append(1)
        return path

    a = build_scenario(cfg, robot_spec, kinematics, reference)
    b = build_scenario(cfg, robot_spec, kinematics, path)
    assert len(a.obstacles) == 100 and len(calls) == 1
    np.testing.assert_array_equal(a.obstacles.centers, b.obstacles.centers)
    np.testing.assert_allclose(a.obstacles.centers[:2], OWN_CENTERS)  # the scenario's own first
    vol = swept_volume(kinematics, path, ARM)
    assert vol.clearance(a.obstacles.centers[2:], RADIUS).min() >= MARGIN
    cfg = replace(cfg, clutter=replace(cfg.clutter, total=2))  # the scenario's own two:
    #                                                          no clutter, no reference run
    assert len(build_scenario(cfg, robot_spec, kinematics, reference).obstacles) == 2
    assert len(calls) == 1
    cfg = replace(cfg, clutter=replace(cfg.clutter, total=10))
    with pytest.raises(ScenarioError, match="needs a reference motion"):
        build_scenario(cfg, robot_spec, kinematics, None)
    with pytest.raises(ScenarioError, match="does not start at the scenario's q0"):
        build_scenario(cfg, robot_spec, kinematics, path[::-1])


@pytest.mark.parametrize("override, message", [
    ("clutter.keep_clear=goal", r"clutter\.keep_clear must be start_goal or path"),
    ("clutter.region=ball", r"clutter\.region must be box or shell"),
    ("clutter.margin=-0.1", r"clutter\.margin"),
])
def test_schema_refuses_bad_clutter_options(override, message):
    from hydra import compose, initialize_config_dir

    from tamedpuma.app.config import CONF_DIR
    from tamedpuma.app.schema import run_config
    from tamedpuma.errors import ConfigError

    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("sweep", overrides=[override])
    with pytest.raises(ConfigError, match=message):
        run_config(cfg)
