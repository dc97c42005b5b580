"""Guard spheres (``robot.guard_spheres``): the controllers avoid with them, the paper's collision
check keeps the robot's ``spheres`` (a link mesh touching an obstacle while the paper's
spheres are clear: the ``mesh`` failure class)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pybullet_data
import pytest
from omegaconf import OmegaConf

from tamedpuma.app.config import robot_config
from tamedpuma.app.sweep import build
from tamedpuma.app.train import compose
from tamedpuma.errors import ConfigError
from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config
from tamedpuma.robot.rotations import rotation_entries
from tamedpuma.types import Goal, Obstacles, Scenario
from tamedpuma.worlds.bullet import Simulator

Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])


@pytest.fixture(scope="module")
def guarded():
    return robot_spec_from_config(robot_config("iiwa14"))


@pytest.fixture(scope="module")
def five():
    return replace(robot_spec_from_config(robot_config("iiwa14")), guard_spheres=())


def _mesh_vertices(link: int) -> np.ndarray:
    path = f"{pybullet_data.getDataPath()}/kuka_iiwa/meshes/link_{link}.obj"
    with open(path) as f:
        return np.array([[float(v) for v in line.split()[1:4]] for line in f
                         if line.startswith("v ")])


def _uncovered(spec, link: int, q: np.ndarray) -> float:
    """The farthest a vertex of link ``link``'s mesh lies outside every sphere of ``spec`` [m]."""
    kin = Kinematics(spec)
    pos, quat = kin.link_poses(q)
    i = list(spec.link_names).index(f"lbr_iiwa_link_{link}")
    rot = np.array(rotation_entries(*quat[i])).reshape(3, 3)
    verts = _mesh_vertices(link) @ rot.T + pos[i]
    gaps = np.linalg.norm(verts[:, None] - kin.sphere_centers(q)[None], axis=-1) - spec.sphere_radii
    return float(gaps.min(axis=1).max())


def test_controller_body_is_spheres_then_guards(guarded, five):
    body = guarded.controller_body()
    assert body.spheres == guarded.spheres + guarded.guard_spheres
    assert len(guarded.spheres) == 5 and len(guarded.guard_spheres) == 2
    assert body.guard_spheres == ()
    assert five.controller_body() is five  # no guards: the same spec


@pytest.mark.parametrize("option", ["iiwa14_covered", "iiwa14_mesh"])
def test_the_covering_body_models_need_no_guards(option):
    assert robot_spec_from_config(robot_config(option)).guard_spheres == ()


def test_guards_cover_the_forearm_the_five_spheres_leave_open(guarded, five):
    q = np.random.default_rng(3).uniform(guarded.q_min, guarded.q_max)
    without, with_guards = _uncovered(five, 5, q), _uncovered(guarded.controller_body(), 5, q)
    assert without > 0.035 and with_guards < 0.02  # link 5 (the forearm): 4.0 cm -> 1.4 cm
    assert _uncovered(guarded.controller_body(), 4, q) < _uncovered(five, 4, q) - 0.005


def test_the_controller_sees_an_obstacle_at_the_gap_the_paper_check_does_not(guarded):
    """An obstacle touching the forearm between the link-5 and link-6 spheres: the controllers'
    clearance (guards included) is negative, the simulator's (the five spheres) is positive."""
    kin = Kinematics(guarded.controller_body())
    centers = kin.sphere_centers(Q0)
    guard = centers[len(guarded.spheres) + 1]  # the link-5 guard
    away = guard - 0.5 * (centers[2] + centers[3])
    obstacle = guard + 0.09 * away / np.linalg.norm(away)  # 1 cm inside the guard
    scenario = Scenario(name="gap", task="tomato", q0=Q0,
                        goal=Goal([0.58, -0.214, 0.115], [-0.5459, 0.5806, -0.4112, 0.4426]),
                        obstacles=Obstacles([obstacle], [0.02], [[0.0, 0.0, 0.0]]), dt=0.02,
                        max_steps=1,
                        goal_tolerance=0.05)
    # the Fabrics method as the sweep builds it (methods.make: the controller body)
    controller = build(OmegaConf.create(compose("sweep", ["method=fabrics",
                                                         "recorder=none"]))).controller
    controller.reset(scenario)
    with Simulator(guarded) as sim:
        obs = sim.reset(scenario)
        assert sim.contacts(sim.body_sphere_centers(*sim.link_poses())).sphere_clearance > 0.0
    with pytest.warns(RuntimeWarning, match="penetration"):  # the controller sees it touch
        seen = controller.step(obs).scalars
    assert seen["min_clearance_m"] == pytest.approx(-0.01, abs=1e-3)


@pytest.mark.parametrize("override, n_controller", [(None, 7), ("robot.guard_spheres=[]", 5)])
def test_a_sweep_run_checks_the_five_spheres_whatever_the_controller_avoids_with(override,
                                                                               n_controller):
    built = build(OmegaConf.create(compose("sweep", ["method=fpm", "recorder=none",
                                                     *([override] if override else [])])))
    assert len(built.spec.spheres) == 5  # the simulator's, the recorders', the paper check's
    assert len(built.controller.kinematics.spec.spheres) == n_controller


@pytest.mark.parametrize("override, message", [
    ("robot.guard_spheres=[{link: lbr_iiwa_link_5, radius: -0.1}]", r"radius must be a finite"),
    ("robot.guard_spheres=[{link: no_such_link, radius: 0.1}]", r"no_such_link"),
])
def test_bad_guard_spheres_are_one_line_config_errors(override, message):
    with pytest.raises(ConfigError, match=message) as err:
        build(OmegaConf.create(compose("sweep", ["method=fabrics", "recorder=none", override])))
    assert "\n" not in str(err.value)
