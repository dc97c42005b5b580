"""The compiled fabric kernels (``fabric.kernel=numba``, tamedpuma.fabrics.compiled) against the
numpy reference (fused.py): the same acceleration, diagnostics, metric, forces and barrier rows
to rounding, clamped pairs and the ground leaf included; non-finite input still refused. Skipped
when numba is not installed (the optional ``fast`` extra)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import Fabric, FabricError, FabricGains, compiled, quaternion_to_rotation

Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])
GOAL_P = np.array([0.58, -0.214, 0.115])
GOAL_R = quaternion_to_rotation([-0.5459, 0.5806, -0.4112, 0.4426])


def test_kernel_option_is_checked():
    with pytest.raises(ConfigError, match="fabric.kernel must be one of"):
        FabricGains(kernel="fortran")
    assert FabricGains.from_mapping({"kernel": "numpy"}).kernel == "numpy"


def test_numba_kernel_without_numba_is_a_config_error(monkeypatch):
    monkeypatch.setattr(compiled, "AVAILABLE", False)
    with pytest.raises(ConfigError, match=r"needs numba: pip install 'tamedpuma\[fast\]'"):
        FabricGains(kernel="numba")


def test_auto_is_compiled_exactly_where_numba_is_installed(robot_spec, monkeypatch):
    assert FabricGains().kernel == "auto"
    fabric = Fabric(FabricGains(), robot_spec.q_min, robot_spec.q_max)
    assert fabric.compiled is compiled.AVAILABLE
    monkeypatch.setattr(compiled, "AVAILABLE", False)
    assert Fabric(FabricGains(), robot_spec.q_min, robot_spec.q_max).compiled is False


@pytest.mark.parametrize("method", ["fabrics", "fpm", "cpm"])
def test_the_episode_start_compiles_what_the_steps_call(method, tmp_path):
    """After the controller's reset (Fabric.prepare_at_start) a whole episode's steps add no
    compiled version to any fabric kernel: nothing compiles inside a step."""
    pytest.importorskip("numba")
    from tamedpuma.app.compose import compose
    from tamedpuma.app.sweep import build
    from tamedpuma.episode import run_episode
    from tamedpuma.worlds.bullet import Simulator

    cfg = compose("sweep", [f"method={method}", "+experiment=table1", "case=tomato_03",
                            "without_obstacles=false", "recorder=none"])
    built = build(cfg)
    scenario = dataclasses.replace(built.scenario, max_steps=100)
    kernels = compiled.kernels()
    names = ("pair_rows", "near_pair_rows", "kernel", "goal_rows", "systems_solve")
    steps = []
    step = built.controller.step

    def counted(obs):
        before = {k: len(getattr(kernels, k).signatures) for k in names}
        command = step(obs)
        steps.append({k: len(getattr(kernels, k).signatures) - before[k] for k in names})
        return command

    built.controller.step = counted
    with Simulator(built.spec, built.sim_config, built.disturbance) as sim:
        run_episode(scenario, built.controller, sim, (), None, stop_on_success=True)
    assert steps and all(not any(d.values()) for d in steps), steps[:3]


def _close(a, b, what, rtol=1e-9):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = 1.0 + np.abs(a).max() if a.size else 1.0
    assert a.shape == b.shape, what
    assert np.all(np.isfinite(a) == np.isfinite(b)), what
    assert np.abs(np.nan_to_num(a) - np.nan_to_num(b)).max(initial=0.0) <= rtol * scale, what


@pytest.mark.parametrize("ground,activation", [(False, np.inf), (True, np.inf), (False, 3.0)])
def test_compiled_kernels_match_the_numpy_reference(kinematics, robot_spec, ground, activation):
    pytest.importorskip("numba")
    gains = FabricGains(ground_enabled=ground, ground_height=0.3 if ground else 0.0,
                        obstacle_activation=activation, kernel="numpy")
    ref = Fabric(gains, robot_spec.q_min, robot_spec.q_max)
    assert ref.compiled is False
    fast = Fabric(dataclasses.replace(gains, kernel="numba"), robot_spec.q_min, robot_spec.q_max)
    rng = np.random.default_rng(11)
    seen_clamped = False
    for n_obs in (0, 1, 2, 7, 60, 400):  # 400 obstacles: the split (many-row) layout
        for trial in range(4):
            q = np.clip(Q0 + rng.normal(scale=0.4, size=7), robot_spec.q_min, robot_spec.q_max)
            if trial == 3:
                q[1] = robot_spec.q_max[1]  # on a joint limit: a clamped limit row
            qd = rng.normal(scale=1.0, size=7)
            st = kinematics.evaluate(q, qd)
            centers = rng.uniform([-0.8, -0.8, 0.0], [0.8, 0.8, 1.2], size=(n_obs, 3))
            if n_obs and trial % 2:  # an obstacle inside a body sphere: a clamped pair
                centers[0] = st.sphere_centers[2] + 0.01
            obs = (centers, rng.uniform(0.02, 0.1, size=n_obs),
                   rng.normal(scale=0.3, size=(n_obs, 3)))
            for _ in range(2):  # twice: reused buffers give the same answer
                a, da = ref.evaluate(st, q, qd, *obs, GOAL_P, GOAL_R)
                b, db = fast.evaluate(st, q, qd, *obs, GOAL_P, GOAL_R)
                _close(a, b, f"q̈ at {n_obs} obstacles")
                for key, value in da.as_scalars().items():
                    _close(value, db.as_scalars()[key], key)
                ra = ref.avoidance(st, q, qd, *obs)
                rb = fast.avoidance(st, q, qd, *obs)
                for name in ("M", "forces", "energy", "min_clearance", "ground_clearance",
                             "barrier_rows", "barrier_x", "barrier_jdqd"):
                    _close(getattr(ra, name), getattr(rb, name), name)
                assert (ra.n_clamped, ra.n_limit_clamped) == (rb.n_clamped, rb.n_limit_clamped)
                seen_clamped |= ra.n_clamped > 0 and ra.n_limit_clamped > 0
    assert seen_clamped  # the clamped branches were exercised


def test_compiled_kernels_refuse_non_finite_input(kinematics, robot_spec):
    pytest.importorskip("numba")
    fast = Fabric(FabricGains(kernel="numba"), robot_spec.q_min, robot_spec.q_max)
    qd = np.full(7, 0.1)
    st = kinematics.evaluate(Q0, qd)
    obs = (np.array([[0.4, 0.0, 0.5], [np.nan, 0.0, 0.5]]), np.array([0.05, 0.05]),
           np.zeros((2, 3)))
    with pytest.raises(FabricError, match="not finite"):
        fast.evaluate(st, Q0, qd, *obs, GOAL_P, GOAL_R)
