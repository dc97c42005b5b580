"""The vanilla Fabrics controller: config, logging, and a pure-kinematics closed loop."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from tamedpuma.app.config import load_group
from tamedpuma.app.schema import method_settings
from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import FabricGains
from tamedpuma.fabrics.gains import LIMIT_REFERENCE
from tamedpuma.methods import fabrics
from tamedpuma.types import Goal, Observation, Obstacles, Scenario


def make(cfg, kinematics):
    """The Fabrics controller of a plain method config (Hydra's ``defaults`` list left out),
    typed by the schema."""
    return fabrics.make(method_settings({k: v for k, v in cfg.items() if k != "defaults"}),
                        kinematics)

Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])
GOAL = Goal(position=[0.58, -0.214, 0.115], quaternion=[-0.5459, 0.5806, -0.4112, 0.4426])
OBSTACLES = Obstacles(centers=[[0.5, -0.30, 0.5], [0.24355761, 0.45252747, 0.2]],
                      radii=[0.05, 0.05], velocities=np.zeros((2, 3)))
SCALARS = {"energy_fabric", "energy_execution", "potential", "alpha_geometry", "alpha_0",
           "alpha_psi", "alpha_ex", "eta", "beta", "min_clearance_m", "n_clamped",
           "n_limit_clamped", "goal_distance", "orientation_error"}


def _scenario(q0=Q0, obstacles=OBSTACLES):
    return Scenario(name="tomato-default", task="tomato", q0=q0, goal=GOAL, obstacles=obstacles,
                    dt=0.02, max_steps=2000, goal_tolerance=0.05)


def _obs(scenario, q, qd, t=0.0, step=0):
    obst = scenario.obstacles
    return Observation(t=t, step=step, q=q, qd=qd, obstacle_centers=obst.at(t),
                       obstacle_radii=obst.radii, obstacle_velocities=obst.velocities,
                       goal_position=scenario.goal.at(t), goal_quaternion=scenario.goal.quaternion,
                       goal_velocity=scenario.goal.velocity)


def test_config_files_list_every_gain_at_its_default():
    defaults = FabricGains().to_mapping()
    cfg = load_group("fabric", "default")
    assert set(cfg) == set(defaults)
    for key in ("obstacle", "joint_limit", "ground"):
        assert set(cfg[key]) == set(defaults[key])
    assert FabricGains.from_mapping(cfg) == FabricGains()
    # numbers, not expression strings (the one option: which implementation computes them)
    assert not any(isinstance(v, str) for k, v in cfg.items() if k != "kernel")
    # the reference planner's file differs only in its joint-limit leaf and the obstacle leaf's
    # activation (none there)
    reference = FabricGains.from_mapping(load_group("fabric", "reference"))
    assert dataclasses.replace(reference, joint_limit=FabricGains().joint_limit,
                               obstacle_activation=2.0) == FabricGains()
    assert reference.joint_limit == LIMIT_REFERENCE and reference.obstacle_activation == np.inf


def test_method_config_composes_the_default_fabric(kinematics):
    from tamedpuma.app.train import compose

    composed = compose("sweep", ["method=fabrics"])["method"]
    assert composed["name"] == "fabrics"
    assert make(composed, kinematics).gains == FabricGains()
    assert make(load_group("method", "fabrics"), kinematics).gains == FabricGains()
    ref = compose("sweep", ["method=fabrics", "fabric@method.fabric=reference"])["method"]
    assert make(ref, kinematics).gains.joint_limit == LIMIT_REFERENCE


@pytest.mark.parametrize("bad", [
    {"name": "fabrics", "fabric": {"goal_wieght": 1.0}},
    {"name": "fabrics", "fabric": {"obstacle": {"exponent": 2}}},
    {"name": "fabrics", "fabric": {"goal_weight": "5 * w"}},
    {"name": "fabrics", "fabric": {"base_metric": -1.0}},
    {"name": "fabrics", "gains": {}},
])
def test_bad_config_is_a_config_error(bad, kinematics):
    with pytest.raises(ConfigError):
        make(bad, kinematics)


def _rollout(controller, scenario, kinematics, steps=1500, dt=0.02):
    """Pure-kinematics loop: q̇ ← clip(q̇ + q̈Δt, ±q̇_max), q ← q + q̇Δt (the simulator's command)."""
    spec = kinematics.spec
    controller.reset(scenario)
    q, qd = scenario.q0.copy(), np.zeros(7)
    trace = []
    for k in range(steps):
        cmd = controller.step(_obs(scenario, q, qd, k * dt, k))
        qd = np.clip(qd + cmd.qdd * dt, -spec.qd_max, spec.qd_max)
        q = q + qd * dt
        centers = kinematics.sphere_centers(q)
        obst = scenario.obstacles.at((k + 1) * dt)
        gap = (np.linalg.norm(centers[:, None] - obst[None], axis=-1)
               - spec.sphere_radii[:, None] - scenario.obstacles.radii[None])
        ee = kinematics.ee_pose(q)[0]
        trace.append((q, np.linalg.norm(ee - scenario.goal.at((k + 1) * dt)), gap.min(),
                      cmd.scalars))
        if trace[-1][1] < 0.02:
            break
    return trace


def test_fabrics_reaches_the_tomato_goal_in_a_kinematic_loop(kinematics):
    spec = kinematics.spec
    controller = make(load_group("method", "fabrics"), kinematics)
    trace = _rollout(controller, _scenario(), kinematics)
    qs = np.array([t[0] for t in trace])
    dist = np.array([t[1] for t in trace])
    gaps = np.array([t[2] for t in trace])
    assert dist.min() < 0.05
    first = int(np.argmax(dist < 0.05))
    assert first * 0.02 < 30.0
    assert gaps.min() > 0.0  # no body sphere penetrates an obstacle
    assert np.all(qs >= spec.q_min) and np.all(qs <= spec.q_max)
    scalars = trace[-1][3]
    assert SCALARS <= set(scalars)
    assert all(np.isfinite(v) for v in scalars.values())
    assert scalars["min_clearance_m"] == pytest.approx(gaps[-2], abs=0.02)
    assert all(t[3]["beta"] > 0 and t[3]["n_clamped"] == 0 for t in trace)


def test_fabrics_reaches_the_goal_past_a_moving_obstacle_without_penetration(kinematics):
    """An obstacle crossing the path of the arm at 0.1 m/s: reached, and never penetrated."""
    moving = Obstacles(centers=[[0.5, -0.6, 0.3]], radii=[0.05], velocities=[[0.0, 0.1, 0.0]])
    controller = make(load_group("method", "fabrics"), kinematics)
    trace = _rollout(controller, _scenario(obstacles=moving), kinematics)
    assert min(t[2] for t in trace) > 0.0
    assert min(t[1] for t in trace) < 0.05


def test_start_past_a_joint_limit_warns_and_stays_finite(kinematics):
    spec = kinematics.spec
    q0 = Q0.copy()
    q0[1] = spec.q_max[1] + 5e-6  # like pouring #2: 5e-6 rad past the limit
    controller = make({"name": "fabrics"}, kinematics)
    scenario = _scenario(q0=q0)
    with pytest.warns(RuntimeWarning, match="joint limit"):
        controller.reset(scenario)
    with pytest.warns(RuntimeWarning, match="clamped"):
        controller.reset(scenario)
        cmd = controller.step(_obs(scenario, q0, np.zeros(7)))
    assert cmd.scalars["n_limit_clamped"] >= 1
    assert np.all(np.isfinite(cmd.qdd)) and np.linalg.norm(cmd.qdd) > 0
    # the limit barrier pushes joint 2 back inside within a few steps
    with pytest.warns(RuntimeWarning):
        trace = _rollout(make({"name": "fabrics"}, kinematics), scenario, kinematics, steps=50)
    assert trace[-1][0][1] < spec.q_max[1]


def test_gains_are_dataclass_fields_without_expressions():
    fields = {f.name: f.type for f in dataclasses.fields(FabricGains)}
    assert "goal_weight" in fields and "damping_close" in fields
    with pytest.raises(ConfigError):
        FabricGains.from_mapping({"orientation_axes": [0, 0]})


def test_joint_limits_hold_where_the_reference_limit_leaf_lets_joints_creep_past(kinematics):
    """Table-1 tomato #8: the reference limit leaf (L = 0.1 s ẋ²/x, ẍ = 0.1 ẋ²/x) lets joint 2
    creep past its limit; the default (L ∝ ẋ²/x², ẍ = ẋ²/x²) keeps every joint inside."""
    spec = kinematics.spec
    scenario = _scenario(q0=np.array([0.531, 1.16, 0.070, -1.665, 0.294, -1.2, -0.242]),
                         obstacles=Obstacles(centers=[[0.45, 0.02, 0.2], [0.6, 0.02, 0.2]],
                                             radii=[0.05, 0.05], velocities=np.zeros((2, 3))))
    reference = dataclasses.asdict(LIMIT_REFERENCE)
    for limit_gains, expect_inside in (({}, True), (reference, False)):
        cfg = {"name": "fabrics", "fabric": {"joint_limit": limit_gains}}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            trace = _rollout(make(cfg, kinematics), scenario, kinematics, steps=1000)
        qs = np.array([t[0] for t in trace])
        inside = bool(np.all((qs >= spec.q_min) & (qs <= spec.q_max)))
        assert inside == expect_inside
        assert min(t[2] for t in trace) > 0.0
