"""The control loop end to end: PyBullet -> recorders -> files -> readers, in process."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from mcap.reader import make_reader

from tamedpuma.app.config import load_group, start_options, typed_scenario
from tamedpuma.app.schema import method_settings
from tamedpuma.episode import run_episode
from tamedpuma.methods import make
from tamedpuma.recording import McapRecorder, RerunRecorder, RunInfo, read_mcap, read_rrd_joints
from tamedpuma.worlds.bullet import Simulator
from tamedpuma.worlds.scenarios import scenario_from_config


def _scenario(robot_spec, **changes):
    cfg = load_group("scenario", "default")
    task = load_group("task", "tomato")
    cfg["goal"].update(position=task["goal_position"], quaternion=task["goal_quaternion"])
    cfg.update(changes)
    return scenario_from_config(typed_scenario(cfg), robot_spec, task="tomato", **start_options())


def _run(robot_spec, kinematics, scenario, recorders=(), info=None):
    controller = make("joint_attractor", method_settings(load_group("method", "joint_attractor")),
                      kinematics)
    with Simulator(robot_spec) as sim:
        return run_episode(scenario, controller, sim, recorders, info)


def _info(robot_spec, scenario):
    return RunInfo(run_id="test", method="joint_attractor", task="tomato",
                   scenario_name=scenario.name, seed=0, config_yaml="seed: 0\n",
                   urdf_path=robot_spec.urdf_path, joint_names=robot_spec.joint_names,
                   link_names=robot_spec.link_names, body_sphere_radii=robot_spec.sphere_radii,
                   dt=scenario.dt)


@pytest.fixture(scope="module")
def recorded(robot_spec, kinematics, tmp_path_factory):
    out = tmp_path_factory.mktemp("episode")
    scenario = _scenario(robot_spec)
    recorders = [McapRecorder(out / "episode.mcap"), RerunRecorder(out / "episode.rrd")]
    result = _run(robot_spec, kinematics, scenario, recorders, _info(robot_spec, scenario))
    return out, result


def test_joint_attractor_reaches_the_goal(recorded):
    _, result = recorded
    assert result.stop_reason == "converged"
    assert result.metrics.success and result.metrics.final_position_error_m <= 0.05
    assert result.metrics.joint_limit_violation_steps == 0


def test_mcap_reads_back_the_simulators_joint_values(recorded):
    out, result = recorded
    log = read_mcap(out / "episode.mcap")
    assert log.complete
    assert log.n_steps == len(result.q) == result.metrics.steps
    q = log.joints[[f"q_{i}" for i in range(7)]].to_numpy()
    np.testing.assert_array_equal(q, result.q)
    np.testing.assert_array_equal(log.ee[["x", "y", "z"]].to_numpy(), result.ee_position)
    assert log.summary["steps"] == result.metrics.steps
    assert "lbr_iiwa_link_7" in log.urdf and log.config_yaml == "seed: 0\n"
    assert {"compute_time_ms", "clearance_m", "joint_error_rad"} <= set(log.scalars.columns)
    np.testing.assert_allclose(log.scalars["compute_time_ms"], result.compute_ms)
    np.testing.assert_allclose(log.scalars["compute_cpu_time_ms"], result.compute_cpu_ms)
    assert log.summary["compute_cpu_ms_max"] == pytest.approx(result.compute_cpu_ms.max())


def test_mcap_has_the_foxglove_schemas(recorded):
    out, _ = recorded
    with open(out / "episode.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    names = {s.name for s in summary.schemas.values()}
    assert {"foxglove.JointStates", "foxglove.FrameTransforms", "foxglove.SceneUpdate",
            "foxglove.PoseInFrame"} <= names


def test_rrd_reads_back_the_same_steps_and_joint_values(recorded, robot_spec):
    out, result = recorded
    joints = read_rrd_joints(out / "episode.rrd")
    assert len(joints) == len(result.q)
    np.testing.assert_allclose(joints[list(robot_spec.joint_names)].to_numpy(), result.q,
                               rtol=0, atol=1e-12)


def test_rerun_verify_accepts_the_rrd(recorded):
    import shutil

    out, _ = recorded
    exe = shutil.which("rerun")
    if exe is None:
        pytest.skip("the rerun command is not on PATH")
    proc = subprocess.run([exe, "rrd", "verify", str(out / "episode.rrd")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_two_runs_of_the_same_config_are_identical(robot_spec, kinematics):
    scenario = _scenario(robot_spec, max_steps=120)
    a = _run(robot_spec, kinematics, scenario)
    b = _run(robot_spec, kinematics, scenario)
    assert np.array_equal(a.q, b.q) and len(a.q) > 50


class _Waits:
    """The joint attractor, but step 3 sleeps 30 ms (the thread off the CPU, as when the
    operating system runs another process) and step 5 spins 8 ms on the CPU."""

    def __init__(self, inner):
        self.inner, self.k = inner, 0

    def reset(self, scenario):
        self.inner.reset(scenario)

    def step(self, obs):
        import time

        if self.k == 3:
            time.sleep(0.030)
        elif self.k == 5:
            end = time.thread_time() + 0.008
            while time.thread_time() < end:
                pass
        self.k += 1
        return self.inner.step(obs)


def test_the_step_s_cpu_time_leaves_out_the_time_the_thread_waits(robot_spec, kinematics):
    scenario = _scenario(robot_spec, max_steps=10)
    inner = make("joint_attractor", method_settings(load_group("method", "joint_attractor")),
                 kinematics)
    with Simulator(robot_spec) as sim:
        result = run_episode(scenario, _Waits(inner), sim)
    wall, cpu = result.compute_ms, result.compute_cpu_ms
    assert len(cpu) == len(wall) == result.metrics.steps
    assert wall[3] >= 30.0 and cpu[3] < 5.0  # waiting costs wall time, not CPU time
    assert cpu[5] >= 8.0 and wall[5] >= 8.0   # work costs both
    assert np.all(cpu <= wall + 0.05)
    assert result.metrics.compute_cpu_ms_max == pytest.approx(cpu.max())
    assert result.metrics.compute_ms_max >= 30.0


class _Cycle:
    def __init__(self):
        self.me = self


class _MakesCycles:
    """The joint attractor, leaving 2000 reference cycles behind at every step (a controller
    that would trigger Python's collector many times over an episode), noting whether the
    collector was enabled while it stepped and how many of its cycles were still there."""

    def __init__(self, inner):
        self.inner, self.enabled, self.alive, self.refs = inner, [], [], []

    def reset(self, scenario):
        self.inner.reset(scenario)

    def step(self, obs):
        import gc
        import weakref

        for _ in range(2000):
            self.refs.append(weakref.ref(_Cycle()))
        self.enabled.append(gc.isenabled())
        self.alive.append(sum(r() is not None for r in self.refs))
        return self.inner.step(obs)


def test_the_collector_does_not_run_inside_the_loop(robot_spec, kinematics):
    """No garbage collection (young or full) starts between the first and the last step, the
    collector is as it was after the episode, and the cycles the controller left are collected
    then."""
    import gc

    scenario = _scenario(robot_spec, max_steps=30)
    inner = make("joint_attractor", method_settings(load_group("method", "joint_attractor")),
                 kinematics)
    controller = _MakesCycles(inner)
    starts = []

    def seen(phase, info):
        if phase == "start" and controller.enabled and len(controller.enabled) < 30:
            starts.append(info["generation"])

    gc.callbacks.append(seen)
    try:
        with Simulator(robot_spec) as sim:
            result = run_episode(scenario, controller, sim)
    finally:
        gc.callbacks.remove(seen)
    assert result.metrics.steps == 30 and controller.enabled == [False] * 30
    assert starts == [] and gc.isenabled()
    assert controller.alive == [2000 * (k + 1) for k in range(30)]  # none collected inside
    gc.collect()
    assert not any(r() is not None for r in controller.refs)  # all collected after it
    gc.disable()
    try:  # a caller that runs with the collector off keeps it off
        with Simulator(robot_spec) as sim:
            run_episode(scenario, _MakesCycles(inner), sim)
        assert not gc.isenabled()
    finally:
        gc.enable()
