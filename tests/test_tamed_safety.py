"""FPM and CPM stay safe at the control rate on a random scenario, with a tiny trained
model: every commanded joint speed within its limit less the speed headroom and every measured
one within the limit, the energization coefficient within its
bound, no body sphere inside an obstacle, nothing below the ground (the link meshes or the body
spheres, whichever the ground rows keep), no joint past its limit; and the
singularity-robust inverse keeps the pulled acceleration bounded at the stretched elbow."""

from __future__ import annotations

import numpy as np
import pytest
from omegaconf import OmegaConf

from tamedpuma.app import train
from tamedpuma.episode import run_episode
from tamedpuma.methods._policy import Damping, TaskAcceleration, manipulability, pull_to_joints
from tamedpuma.methods._tamed import SPEED_HEADROOM
from tamedpuma.robot.ground import hull_ground_rows, link_hulls
from tamedpuma.worlds.bullet import Simulator


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny_tomato_safety")
    assert train.main(["task=tomato", "puma=tiny", f"out_dir={out}", "progress=false",
                       "evaluate=false"]) == 0
    return out / "puma.pt"


# the control-rate safety options, each switched on here (FPM and CPM's configs set their
# defaults; the schema's are off)
SAFE = ["method.control_rate.speed_limit=true",
        "method.control_rate.barrier_step=true", "method.control_rate.semi_implicit=true",
        "method.pinv_damping_max=0.1",
        "method.goal_velocity=feedforward"]


class _Spy:
    def __init__(self, controller):
        self.controller, self.rows = controller, []

    def reset(self, scenario):
        self.rows = []
        self.controller.reset(scenario)

    def step(self, obs):
        command = self.controller.step(obs)
        self.rows.append((obs.qd + 0.02 * np.asarray(command.qdd), dict(command.scalars),
                          np.array(obs.qd)))
        return command


@pytest.mark.parametrize("method", ["fpm", "cpm"])
def test_fpm_and_cpm_respect_speed_limits_and_barriers_on_a_random_scenario(
        tiny_checkpoint, kinematics, method):
    from tamedpuma.app.sweep import build

    # tomato, near a Table-1 start, seed 5: the real model's FPM flails here without the
    # control-rate safety and the execution energy (α to −9e4, commands 28× the velocity limits,
    # through q₄ = 0, 0.95 m from the goal)
    cfg = OmegaConf.create(train.compose("sweep", [
        "task=tomato", "scenario=random", "scenario.random_seed=5", f"method={method}",
        f"method.checkpoint={tiny_checkpoint}", "recorder=none", "scenario.max_steps=400",
        *SAFE]))
    built = build(cfg)
    spy = _Spy(built.controller)
    spec = built.spec
    with Simulator(spec, built.sim_config) as sim:
        run = run_episode(built.scenario, spy, sim, stop_on_success=False)
    commanded = np.array([r[0] for r in spy.rows])
    headroom = SPEED_HEADROOM
    assert np.all(np.abs(commanded) <= (1 - headroom) * spec.qd_max * (1 + 1e-9))
    measured = np.array([r[2] for r in spy.rows])  # PyBullet's joint velocities
    assert np.all(np.abs(measured) <= spec.qd_max)
    assert run.metrics.min_clearance_m > 0
    assert np.all(run.q >= spec.q_min) and np.all(run.q <= spec.q_max)
    hulls = link_hulls(kinematics)  # every link's mesh above the ground
    lowest = []
    for q in run.q:
        kinematics.evaluate(q, np.zeros(7))
        lowest.append(hull_ground_rows(kinematics, hulls, np.zeros(7)).heights.min())
    assert min(lowest) > 0


def test_singularity_robust_inverse_bounds_the_joint_acceleration(kinematics):
    """At the stretched elbow (q₄ = 0) w → 0: λ grows to λ_max and ‖q̈‖ ≤ ‖ẍ‖/(2λ); away from
    it (w ≥ w₀) the inverse is the plain damped one."""
    rule = Damping(0.01, 0.1, 0.02)
    q = np.array([0.3, 0.5, 0.2, 0.0, 0.3, 0.4, 0.0])
    J = kinematics.evaluate(q, np.zeros(7)).ee_jacobian
    w = manipulability(J)
    assert w < 0.02 and rule(J) > 0.05
    rng = np.random.default_rng(0)
    for _ in range(20):
        xdd = rng.normal(size=6)
        task = TaskAcceleration(xdd, J, np.zeros(6))
        assert np.linalg.norm(pull_to_joints(task, rule)) <= np.linalg.norm(xdd) / (2 * rule(J))
        assert np.linalg.norm(pull_to_joints(task, rule)) < np.linalg.norm(
            pull_to_joints(task, 0.01))
    q_ok = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])
    J_ok = kinematics.evaluate(q_ok, np.zeros(7)).ee_jacobian
    assert manipulability(J_ok) >= 0.02 and rule(J_ok) == 0.01
