"""PUMA, FPM and CPM on the 2-D point robot, with an analytic stable primitive and its compatible
potential (ψ = ‖x − x_g‖²): the paper's theory checked numerically, fast."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.analysis.path_difference import path_difference
from tamedpuma.episode import run_episode
from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._policy import LinearTaskPrimitive, PlanarTask
from tamedpuma.methods._tamed import ControlRate
from tamedpuma.methods.cpm import CpmController
from tamedpuma.methods.fpm import FpmController
from tamedpuma.methods.puma import PumaController
from tamedpuma.worlds.pointmass import (
    PointKinematics,
    PointMassWorld,
    point_scenario,
    point_spec,
)

#: CpmController's settings as these tests always used them (the paper's literal law)
CPM = {"beta": 0.5, "eps": 1e-6, "variant": "paper", "regulator_scale": 1.0,
       "potential_scale": 1.0, "damping": "constant", "rate": ControlRate(semi_implicit=True)}
SPEC = point_spec(speed_limit=50.0)  # no velocity clipping: the theory's continuous system


def _fabric():
    return Fabric(FabricGains.from_mapping(None), SPEC.q_min, SPEC.q_max)


def _controllers():
    kin = PointKinematics(SPEC)
    puma = PumaController(PlanarTask(LinearTaskPrimitive(1.0, 2.0)), kin)
    return {"puma": puma, "fpm": FpmController(puma, _fabric()),
            # β above the critical damping 2√(2·k_ψ/m_b) ≈ 6.3 of ψ = ‖e‖² on the base metric 0.2:
            # otherwise ψ may overshoot (H still decreases, ψ alone need not)
            "cpm": CpmController(puma, _fabric(), **{**CPM, "beta": 8.0})}


def _run(name, obstacles=True, dt=0.02, steps=1500, stop=True):
    sc = point_scenario(obstacles=obstacles, max_steps=steps, dt=dt)
    return run_episode(sc, _controllers()[name], PointMassWorld(SPEC), stop_on_success=stop)


@pytest.mark.parametrize("name", ["fpm", "cpm"])
def test_without_obstacles_fpm_and_cpm_follow_puma(name):
    ref = _run("puma", obstacles=False)
    run = _run(name, obstacles=False)
    assert run.metrics.success
    assert path_difference(run.ee_position, ref.ee_position) <= 0.02


@pytest.mark.parametrize("name", ["fpm", "cpm"])
def test_with_obstacles_fpm_and_cpm_reach_the_goal_without_collision(name):
    blocked = _run("puma")
    assert blocked.metrics.collided  # the straight-line policy runs through an obstacle
    run = _run(name)
    assert run.metrics.success and not run.metrics.collided
    assert run.metrics.min_clearance_m > 0


def _scalars(controller, scenario, world):
    """Step a controller and collect its scalars (no recorder needed)."""
    obs = world.reset(scenario)
    controller.reset(scenario)
    rows = []
    for _ in range(scenario.max_steps):
        cmd = controller.step(obs)
        rows.append({**cmd.scalars, "qd": obs.qd.copy()})
        obs = world.step(cmd.qdd)
    return rows


def test_cpm_total_energy_decreases_at_the_damping_rate():
    """H = H_{L_e} + ψ obeys dH/dt = −β q̇ᵀMq̇: the integrated change matches within a few %."""
    dt = 0.001
    sc = point_scenario(obstacles=True, max_steps=6000, dt=dt)
    rows = _scalars(_controllers()["cpm"], sc, PointMassWorld(SPEC))
    energy = np.array([r["energy_total"] for r in rows])
    dissipation = np.array([r["dissipation"] for r in rows])
    # never increases, up to the discretisation of the stiff barrier near the obstacles
    assert np.all(np.diff(energy) <= 1e-3 * energy[0])
    predicted = -np.sum(0.5 * (dissipation[1:] + dissipation[:-1])) * dt
    actual = energy[-1] - energy[0]
    assert actual == pytest.approx(predicted, rel=0.05)
    assert actual < -0.5 * energy[0]  # most of the energy is gone


def test_cpm_potential_is_non_increasing_without_obstacles():
    rows = _scalars(_controllers()["cpm"], point_scenario(obstacles=False, max_steps=800),
                    PointMassWorld(SPEC))
    psi = np.array([r["psi"] for r in rows])
    assert np.all(np.diff(psi) <= 1e-6 * psi[0])  # up to numerical tolerance near the goal
    assert psi[-1] < 1e-6 * psi[0]


def test_cpm_original_variant_follows_the_authors_law():
    """variant original: q̈ = h + f_θ^C − 0.05 (q̇ᵀ∂ψ / (q̇ᵀMq̇ + ε)) q̇, no energization, β = 0."""
    from tamedpuma.methods._tamed import avoidance_at

    kin = PointKinematics(SPEC)
    puma = PumaController(PlanarTask(LinearTaskPrimitive(1.0, 2.0)), kin)
    original = CpmController(puma, _fabric(), **{**CPM, "beta": 0.0, "variant": "original",
                                                     "regulator_scale": 0.05})
    sc = point_scenario(obstacles=False, max_steps=50)
    a = run_episode(sc, original, PointMassWorld(SPEC), stop_on_success=False)
    b = run_episode(sc, _controllers()["cpm"], PointMassWorld(SPEC), stop_on_success=False)
    assert not np.allclose(a.q, b.q)
    world = PointMassWorld(SPEC)
    obs = world.reset(sc)
    original.reset(sc)
    for _ in range(10):
        command = original.step(obs)
        state, av = avoidance_at(kin, original.fabric, obs)
        qdd_c, _ = puma.joint_acceleration(state, obs)
        _, dpsi = puma.task.potential(state, obs.goal_position, obs.goal_quaternion)
        qd = obs.qd
        r = -0.05 * (qd @ dpsi) / (qd @ av.M @ qd + CPM["eps"])
        np.testing.assert_allclose(command.qdd, av.acceleration() + qdd_c + r * qd, atol=1e-9)
        assert command.scalars["alpha"] == 0.0 and command.scalars["beta"] == 0.0
        obs = world.step(command.qdd)


def test_cpm_matched_damping_follows_puma_and_still_dissipates():
    """β(q, q̇) = max(β, r − α): CPM reproduces PUMA's path where that motion loses energy, and
    H = H_{L_e} + ψ still falls at the logged rate β(q, q̇) q̇ᵀMq̇ ≥ β q̇ᵀMq̇."""
    kin = PointKinematics(SPEC)
    puma = PumaController(PlanarTask(LinearTaskPrimitive(1.0, 2.0)), kin)
    matched = CpmController(puma, _fabric(), **{**CPM, "beta": 0.5, "potential_scale": 5.0,
                                                    "damping": "matched"})
    ref = _run("puma", obstacles=False)
    run = run_episode(point_scenario(obstacles=False), matched, PointMassWorld(SPEC))
    assert run.metrics.success
    assert path_difference(run.ee_position, ref.ee_position) <= 0.02
    dt = 0.001
    sc = point_scenario(obstacles=True, max_steps=6000, dt=dt)
    matched = CpmController(puma, _fabric(), **{**CPM, "beta": 0.5, "potential_scale": 5.0,
                                                  "damping": "matched"})
    rows = _scalars(matched, sc, PointMassWorld(SPEC))
    energy = np.array([r["energy_total"] for r in rows])
    dissipation = np.array([r["dissipation"] for r in rows])
    # the matched law itself: β = max(β_min, r − α), r = −q̇ᵀ∂ψ/(q̇ᵀMq̇ + ε) (logged: ψ rate
    # q̇ᵀ∂ψ, dissipation β q̇ᵀMq̇, α)
    checked = 0
    for r in rows:
        qmq = r["dissipation"] / r["beta"]
        if qmq > 1e-6:
            reg = -r["psi_rate"] / (qmq + CPM["eps"])
            assert r["beta"] == pytest.approx(max(0.5, reg - r["alpha"]), rel=1e-6, abs=1e-9)
            checked += 1
    assert checked > len(rows) // 2
    predicted = -np.sum(0.5 * (dissipation[1:] + dissipation[:-1])) * dt
    assert energy[-1] - energy[0] == pytest.approx(predicted, rel=0.05)


@pytest.mark.parametrize("semi_implicit", [True, False])
def test_cpm_stiff_damping_never_reverses_the_velocity(semi_implicit):
    """β Δt = 4 (β = 200 /s at 50 Hz): the explicit step q̇ += Δt(… − β q̇) overshoots and flips
    q̇ every step; the semi-implicit step (the default) only slows the arm down."""
    kin = PointKinematics(SPEC)
    puma = PumaController(PlanarTask(LinearTaskPrimitive(1.0, 2.0)), kin)
    cpm = CpmController(puma, _fabric(), **{**CPM, "beta": 200.0,
                                              "rate": ControlRate(semi_implicit=semi_implicit)})
    rows = _scalars(cpm, point_scenario(obstacles=False, max_steps=60, dt=0.02),
                    PointMassWorld(SPEC))
    qd = np.array([r["qd"] for r in rows])[1:]
    reversals = int(np.sum(np.einsum("ij,ij->i", qd[1:], qd[:-1]) < 0))
    psi = np.array([r["psi"] for r in rows])
    if semi_implicit:
        assert reversals == 0 and np.all(np.diff(psi) <= 1e-9 * psi[0]) and psi[-1] < psi[0]
    else:
        assert reversals > 10


def test_goal_velocity_is_fed_to_the_primitive_as_a_relative_velocity():
    """goal_velocity: feedforward: the primitive sees ẋ − v_g (ẍ = −k e − d(ẋ − v_g)), so the
    point converges onto a moving goal; ignore: it lags behind it by d v_g / k."""
    from tamedpuma.types import Goal

    kin = PointKinematics(SPEC)
    vg = np.array([0.05, 0.0, 0.0])
    sc = point_scenario(obstacles=False, max_steps=1500)
    from dataclasses import replace

    sc = replace(sc, goal=Goal(sc.goal.position, sc.goal.quaternion, vg))
    errors = {}
    for feed in (True, False):
        puma = PumaController(PlanarTask(LinearTaskPrimitive(1.0, 2.0)), kin,
                              feed_goal_velocity=feed)
        run = run_episode(sc, puma, PointMassWorld(SPEC), stop_on_success=False)
        goal_end = sc.goal.at(run.t[-1])
        errors[feed] = float(np.linalg.norm(run.ee_position[-1, :2] - goal_end[:2]))
    assert errors[True] < 1e-3
    assert errors[False] == pytest.approx(2.0 * 0.05 / 1.0, rel=0.05)
