"""Circulation (``method.forcing.circulation``, :mod:`tamedpuma.methods._circulation`): PUMA's
push into an obstacle turned around it. The local minimum it is for, on the point robot with the
goal straight behind an obstacle, and the properties of the tangent specs on the iiwa."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from tamedpuma.episode import run_episode
from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._circulation import Circulation
from tamedpuma.methods._policy import LinearTaskPrimitive, PlanarTask
from tamedpuma.methods._tamed import ControlRate, Forcing, PumaController
from tamedpuma.methods.cpm import CpmController
from tamedpuma.methods.fpm import FpmController
from tamedpuma.types import Goal, Obstacles, Scenario
from tamedpuma.worlds.pointmass import PointKinematics, PointMassWorld, point_spec

SPEC = point_spec(speed_limit=50.0)


def _behind(offset: float) -> Scenario:
    """Start at the origin, goal 3 m along x, a 0.6 m sphere half way, ``offset`` [m] off the
    start-goal line (0: exactly on it, the saddle of every attractor-plus-barrier method)."""
    obstacles = Obstacles([[1.5, offset, 0.0]], [0.6], np.zeros((1, 3)))
    return Scenario(name="behind", task="point", q0=np.zeros(2), goal=Goal([3.0, 0.0, 0.0],
                    [0, 0, 0, 1]), obstacles=obstacles, dt=0.02, max_steps=1500,
                    goal_tolerance=0.05)


pytestmark = pytest.mark.usefixtures("point_scale_forcing")


def _controller(name: str, circulation: float):
    kin = PointKinematics(SPEC)
    puma = PumaController(PlanarTask(LinearTaskPrimitive(1.0, 2.0)), kin)
    fabric = Fabric(FabricGains.from_mapping(None), SPEC.q_min, SPEC.q_max)
    forcing = Forcing(mode="metric", circulation=circulation)
    if name == "fpm":
        return FpmController(puma, fabric, energy="execution", forcing=forcing)
    return CpmController(puma, fabric, beta=8.0, eps=1e-6, variant="paper", regulator_scale=1.0,
                         potential_scale=1.0, damping="matched",
                         rate=ControlRate(semi_implicit=True),
                         energy="execution", forcing=forcing)


@pytest.mark.parametrize("name", ["fpm", "cpm"])
def test_the_goal_straight_behind_an_obstacle_is_reached_round_it_only_with_circulation(name):
    """Without circulation the point rests against the obstacle (the saddle on the line behind
    it, where PUMA's push has no tangential part); with it the point goes round and reaches the
    goal, never touching the obstacle."""
    sc = _behind(0.0)
    stuck = run_episode(sc, _controller(name, 0.0), PointMassWorld(SPEC)).metrics
    assert not stuck.success_paper and stuck.final_position_error_m > 1.0
    m = run_episode(sc, _controller(name, 0.3), PointMassWorld(SPEC)).metrics
    assert m.success_paper and m.success_whole_body, (m.failure_paper, m.final_position_error_m)
    assert m.min_clearance_m > 0


@pytest.mark.parametrize("name", ["fpm", "cpm"])
@pytest.mark.parametrize("offset", [0.05, -0.2])
def test_circulation_still_goes_round_off_the_line(name, offset):
    m = run_episode(_behind(offset), _controller(name, 0.3), PointMassWorld(SPEC)).metrics
    assert m.success_paper and m.success_whole_body, (m.failure_paper, m.final_position_error_m)
    assert m.min_clearance_m > 0


@dataclass(frozen=True)
class _OneSphere:
    """A kinematic state with one body sphere of radius 0.1 m at the origin moved by the first
    three of 4 joints (J = [I | 0]), J̇q̇ = (0, 0, 0.05)."""

    sphere_centers: np.ndarray = field(default_factory=lambda: np.zeros((1, 3)))
    sphere_radii: np.ndarray = field(default_factory=lambda: np.array([0.1]))
    sphere_jacobians: np.ndarray = field(default_factory=lambda: np.eye(3, 4)[None])
    sphere_jdqd: np.ndarray = field(default_factory=lambda: np.array([[0.0, 0.0, 0.05]]))


def test_tangent_spec_gives_the_blocked_push_back_along_the_obstacle():
    """Obstacle straight below the sphere (clearance 0.02 m, d_a 0.1 m: s = 0.8), PUMA's free
    acceleration p = (0.3, 0, −1) m/s²: one spec, tangent +x (the push's tangential part), target
    p·t̂ + g s |p·n| − t̂·J̇q̇ = 0.3 + 0.8, weight w s; the axis is kept while the pair is near."""
    state, qd = _OneSphere(), np.zeros(4)
    below = np.array([[0.0, 0.0, -0.22]])
    circ = Circulation(0.1, 1.0, 100.0)
    qdd_free = np.array([0.3, 0.0, -1.05, 0.0])  # J q̈ + J̇q̇ = (0.3, 0, −1)
    specs = circ.specs(state, qd, qdd_free, below, np.array([0.1]))
    assert specs.rows == pytest.approx(np.array([[1.0, 0.0, 0.0, 0.0]]))
    s = 0.8 * (1.0 / np.hypot(0.3, 1.0))  # (1 − d/d_a) × head-on factor (c₀ = 0: −p̂·n)
    assert specs.targets == pytest.approx([0.3 + s * 1.0])
    assert specs.weights == pytest.approx([100.0 * s])
    assert circ.axes["arm"] == pytest.approx([0.0, 1.0, 0.0])  # b = n × t̂₀ = z × x
    # PUMA now pulls towards −x: the kept axis still says +x (no turning back at the line)
    specs = circ.specs(state, qd, np.array([-0.2, 0.0, -1.05, 0.0]), below, np.array([0.1]))
    assert specs.rows == pytest.approx(np.array([[1.0, 0.0, 0.0, 0.0]]))
    assert specs.targets == pytest.approx([-0.2 + 0.8 / np.hypot(0.2, 1.0)])
    # with an onset of 60° (c₀ = 0.5) a push 73° off head-on (p = (1, 0, −0.3)) does not count
    grazing = Circulation(0.1, 1.0, 100.0, cos_onset=0.5)
    assert grazing.specs(state, qd, np.array([1.0, 0.0, -0.35, 0.0]), below,
                         np.array([0.1])) is None


def test_free_space_and_pushes_away_leave_the_forcing_alone():
    """No spec when the pair is farther than d_a or PUMA's push leaves the obstacle; the axis is
    forgotten once every pair is clear."""
    state, qd = _OneSphere(), np.zeros(4)
    circ = Circulation(0.1, 1.0, 100.0)
    below, far = np.array([[0.0, 0.0, -0.22]]), np.array([[0.0, 0.0, -0.5]])
    assert circ.specs(state, qd, np.array([0.3, 0.0, -1.05, 0.0]), below, np.array([0.1]))
    assert circ.specs(state, qd, np.array([0.3, 0.0, 1.0, 0.0]), below, np.array([0.1])) is None
    assert "arm" in circ.axes
    assert circ.specs(state, qd, np.array([0.3, 0.0, -1.05, 0.0]), far, np.array([0.1])) is None
    assert circ.axes == {}
    assert circ.specs(state, qd, np.zeros(4), np.zeros((0, 3)), np.zeros(0)) is None


@pytest.mark.parametrize("bad", [{"circulation": -0.1}, {"stall_pull": -1.0}])
def test_bad_circulation_settings_are_refused(bad):
    with pytest.raises(ConfigError, match="circulation"):
        Forcing.from_mapping({"mode": "metric", **bad})


def test_the_fabrics_clearance_shortcut_gives_the_full_computation(kinematics):
    """``specs(..., min_clearance=av.min_clearance)`` (the avoidance fabric's clearance: the
    pair distances are not recomputed when every pair is beyond d_a) returns what the full
    computation returns, spec for spec and axis for axis, on the iiwa with obstacles from
    touching to far."""
    rng = np.random.default_rng(3)
    spec = kinematics.spec
    fabric = Fabric(FabricGains.from_mapping(None), spec.q_min, spec.q_max)
    seen = set()
    for _ in range(200):
        q = rng.uniform(spec.q_min, spec.q_max)
        qd, qdd = rng.normal(size=q.size), rng.normal(scale=3.0, size=q.size)
        state = kinematics.evaluate(q, qd)
        m = int(rng.integers(1, 4))
        idx = rng.integers(0, len(state.sphere_radii), m)
        radii = rng.uniform(0.03, 0.1, m)
        u = rng.normal(size=(m, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        gap = rng.uniform(-0.02, 0.3, m)
        centers = state.sphere_centers[idx] + u * (state.sphere_radii[idx] + radii + gap)[:, None]
        av = fabric.avoidance(state, q, qd, centers, radii, np.zeros((m, 3)))
        full, short = Circulation(0.1, 1.0, 100.0), Circulation(0.1, 1.0, 100.0)
        a = full.specs(state, qd, qdd, centers, radii, qdd.copy)
        b = short.specs(state, qd, qdd, centers, radii, qdd.copy,
                        av.min_clearance)
        seen.add((a is None, av.min_clearance > 0.1))
        assert (a is None) == (b is None)
        if a is not None:
            for x, y in ((a.rows, b.rows), (a.targets, b.targets), (a.weights, b.weights)):
                np.testing.assert_array_equal(x, y)
        assert full.axes.keys() == short.axes.keys()
    assert {(True, True), (False, False)} <= seen  # both sides of the shortcut were taken
