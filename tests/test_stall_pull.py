"""The stall pull (``method.forcing.stall_pull``, :mod:`tamedpuma.methods._stall`): a goal
attractor on PUMA's position rows once neither the hand's distance to the goal nor PUMA's
potential makes progress, let go once the potential is below its value at the stall. The
monitor's rule on synthetic distances, and the local minimum it is for on the point robot: CPM
held against an obstacle by a primitive whose potential has its minimum there."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tamedpuma.episode import run_episode
from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._policy import PlanarTask, TaskAcceleration
from tamedpuma.methods._stall import PULL_LENGTH_M, StallMonitor, StallPull
from tamedpuma.methods._tamed import ControlRate, Forcing, PumaController
from tamedpuma.methods.cpm import CpmController
from tamedpuma.methods.fpm import FpmController
from tamedpuma.types import Goal, Obstacles, Scenario
from tamedpuma.worlds.pointmass import PointKinematics, PointMassWorld, point_spec

SPEC = point_spec(speed_limit=50.0)
GOAL = np.array([1.0, 0.0, 0.0])
PULL = StallPull(gain=1.5, window=2.0, progress=0.005, psi_progress=0.1, radius=0.045, ramp=1.0,
                 release=0.05, hold_radius=0.0)  # without the hold near the goal


def _feed(monitor, times, distances, psi=lambda: 1.0):
    """The monitor's output at each (t, d), the hand on the x axis d [m] short of GOAL; psi: a
    constant ψ, or a sequence of ψ one per step."""
    psis = [psi] * len(times) if callable(psi) else [lambda v=v: v for v in psi]
    return [monitor.acceleration(t, GOAL - [d, 0.0, 0.0], GOAL, f)
            for t, d, f in zip(times, distances, psis, strict=True)]


def test_the_pull_arms_only_after_a_window_without_progress_and_ramps_in():
    m = StallMonitor(PULL)
    t = np.arange(0.0, 4.01, 0.5)
    out = _feed(m, t, np.full(len(t), 0.3))
    armed_at = 2.0  # the window after the first (best) distance
    for ti, a in zip(t, out, strict=True):
        if ti < armed_at:
            assert a is None
        else:  # a(t) g e / max(d, ℓ), along the goal direction
            ramp = min(1.0, (ti - armed_at) / PULL.ramp)
            assert a == pytest.approx([ramp * 1.5 * 0.3 / 0.3, 0.0, 0.0])
    assert m.armed


def test_steady_progress_or_a_hand_at_the_goal_never_arms_it():
    t = np.round(np.arange(0.0, 10.0, 0.1), 6)
    slow = StallMonitor(PULL)  # 1 cm per second: the 5 mm progress is made every 0.5 s
    assert all(a is None for a in _feed(slow, t, 0.5 - 0.01 * t))
    # PUMA's own motion first leads away from the goal while its potential keeps falling
    away = StallMonitor(PULL)
    assert all(a is None for a in _feed(away, t, 0.5 + 0.03 * t, psi=np.exp(-0.1 * t)))
    near = StallMonitor(PULL)  # resting inside the radius
    assert all(a is None for a in _feed(near, t, np.full(len(t), 0.04)))
    # neither measure improves: armed after the window
    still = StallMonitor(PULL)
    out = _feed(still, t, np.full(len(t), 0.5), psi=np.full(len(t), 2.0))
    assert [a is None for a in out] == list(t < 2.0)


def test_a_creeping_hand_arms_the_pull_only_with_a_progress_fraction():
    """4 mm/s from 0.5 m (8 mm per window, above the 5 mm of ``progress``; the goal 2 min
    away) with ψ flat: it never arms on the absolute progress alone; with a fraction of 5 % of
    the distance (25 mm per window there) it arms after the window. A hand that closes the
    distance exponentially with a 3 s time constant (49 % per window) never arms it."""
    t = np.round(np.arange(0.0, 10.0, 0.1), 6)
    psi = np.full(len(t), 2.0)
    creep = 0.5 - 0.004 * t
    assert all(a is None for a in _feed(StallMonitor(PULL), t, creep, psi=psi))
    fraction = replace(PULL, progress_fraction=0.05)
    out = _feed(StallMonitor(fraction), t, creep, psi=psi)
    assert [a is None for a in out] == list(t < 2.0)
    approach = 0.045 + 0.5 * np.exp(-t / 3.0)
    assert all(a is None for a in _feed(StallMonitor(fraction), t, approach, psi=psi))


def test_the_potential_is_evaluated_at_most_every_sample_period():
    calls = []

    def psi():
        calls.append(1)
        return 1.0

    m = StallMonitor(PULL)
    for t in np.round(np.arange(0.0, 1.0, 0.02), 6):  # 50 control steps of 20 ms
        m.acceleration(t, GOAL - [0.5, 0, 0], GOAL, psi)
    assert len(calls) == 10


def test_within_the_length_the_pull_falls_linearly_to_the_goal():
    m = StallMonitor(PULL)
    _feed(m, [0.0, 2.0, 3.0], [0.08, 0.08, 0.08])
    a = m.acceleration(3.5, GOAL - [0.08, 0.0, 0.0], GOAL, lambda: 1.0)
    assert a == pytest.approx([1.5 * 0.08 / PULL_LENGTH_M, 0.0, 0.0])


def test_it_lets_go_on_puma_potential_not_on_distance_and_watches_afresh():
    """Armed with ψ = 1: the hand coming 10 cm closer while ψ rises (going round the ridge)
    keeps it; ψ below 0.95 lets go, and only a new window without progress re-arms it."""
    m = StallMonitor(PULL)
    _feed(m, [0.0, 2.0], [0.5, 0.5], psi=lambda: 1.0)
    assert m.armed and m.psi_armed == 1.0
    assert m.acceleration(3.0, GOAL - [0.4, 0.0, 0.0], GOAL, lambda: 1.3) is not None
    assert m.acceleration(4.0, GOAL - [0.3, 0.0, 0.0], GOAL, lambda: 0.96) is not None
    assert m.acceleration(5.0, GOAL - [0.3, 0.0, 0.0], GOAL, lambda: 0.94) is None
    assert not m.armed and m.best == pytest.approx(0.3)
    assert _feed(m, [6.0, 6.9], [0.3, 0.3], psi=lambda: 0.94) == [None, None]
    assert m.acceleration(7.0, GOAL - [0.3, 0.0, 0.0], GOAL, lambda: 0.94) is not None


def test_the_arming_stands_while_the_configuration_pull_serves_it_and_counts_from_its_end():
    """Armed with ψ = 1: while the configuration pull serves the arming (searches its route or
    acts), ψ falling to 0.5 does not let go; from its end the release counts from ψ there
    (0.5): 0.48 keeps it, 0.47 lets go."""
    m = StallMonitor(PULL)
    _feed(m, [0.0, 2.0], [0.5, 0.5], psi=lambda: 1.0)
    assert m.armed and m.psi_armed == 1.0
    m.hold(True)
    assert m.acceleration(2.5, GOAL - [0.4, 0.0, 0.0], GOAL, lambda: 0.5) is not None
    m.hold(False)  # the configuration pull ended: the release counts from ψ = 0.5
    assert m.psi_armed == 0.5
    assert m.acceleration(3.0, GOAL - [0.4, 0.0, 0.0], GOAL, lambda: 0.48) is not None
    assert m.acceleration(3.5, GOAL - [0.4, 0.0, 0.0], GOAL, lambda: 0.47) is None
    m.hold(False)  # not held: nothing changes
    assert not m.armed and m.psi_armed == 0.5


def test_near_the_goal_only_distance_is_progress_and_the_pull_holds():
    """Within hold_radius a falling ψ (the orientation converging) does not count as progress,
    and the pull armed there is not let go on ψ, nor inside the radius."""
    near = StallPull(gain=1.5, window=2.0, progress=0.005, psi_progress=0.1, radius=0.045,
                     ramp=1.0, release=0.05, hold_radius=0.15)
    t = np.round(np.arange(0.0, 6.0, 0.1), 6)
    falling = np.exp(-0.5 * t)  # ψ falls 10 % well within every window
    # 8 cm short, ψ falling: without the hold never armed, with it armed after the window
    off = _feed(StallMonitor(PULL), t, np.full(len(t), 0.08), psi=falling)
    assert all(a is None for a in off)
    on = _feed(StallMonitor(near), t, np.full(len(t), 0.08), psi=falling)
    assert [a is None for a in on] == list(t < 2.0)
    # armed near the goal, ψ then drops far below its value at arming: still held ...
    m = StallMonitor(near)
    psi = np.where(t < 3.0, 1.0, 0.1)
    d = np.where(t < 4.0, 0.08, 0.06)
    out = _feed(m, t, d, psi=psi)
    assert all(a is not None for a, ti in zip(out, t, strict=True) if ti >= 2.0)
    # ... and inside the radius too (the attractor vanishes at the goal)
    assert m.acceleration(6.0, GOAL - [0.04, 0, 0], GOAL, lambda: 0.1) is not None
    assert m.armed
    # farther than hold_radius the rules are unchanged: progress on ψ keeps it disarmed
    far = _feed(StallMonitor(near), t, np.full(len(t), 0.3), psi=falling)
    assert all(a is None for a in far)


def test_a_pull_armed_near_the_goal_never_lets_go_and_vanishes_at_the_goal():
    """A pull armed within hold_radius stays armed inside the goal radius, and its acceleration
    falls to zero at the goal (a rest point)."""
    keep = StallPull(gain=1.5, window=2.0, radius=0.045, ramp=0.0, hold_radius=0.15)
    m = StallMonitor(keep)
    t = np.round(np.arange(0.0, 2.6, 0.1), 6)
    out = _feed(m, t, np.full(len(t), 0.08), psi=np.exp(-0.5 * t))
    assert out[-1] is not None and m.armed
    inside = [m.acceleration(3.0 + k, GOAL - [r, 0, 0], GOAL, lambda: 0.1)
              for k, r in enumerate([0.04, 0.01, 0.0])]
    assert m.armed
    assert np.linalg.norm(inside[0]) == pytest.approx(1.5 * 0.04 / 0.1)
    assert np.linalg.norm(inside[1]) < np.linalg.norm(inside[0])
    assert inside[2] == pytest.approx(np.zeros(3))
    # armed far from the goal (outside hold_radius) it is still let go on ψ
    far = StallMonitor(keep)
    _feed(far, t, np.full(len(t), 0.3), psi=np.ones(len(t)))
    assert far.armed
    assert far.acceleration(3.0, GOAL - [0.3, 0, 0], GOAL, lambda: 0.5) is None


def test_applied_adds_to_the_position_rows_only():
    m = StallMonitor(StallPull(gain=2.0, window=1.0, ramp=0.0))
    task = TaskAcceleration(np.arange(6.0), np.eye(6, 7), np.zeros(6))
    assert m.applied(0.0, GOAL - [0.5, 0, 0], GOAL, task, lambda: 1.0) is task
    out = m.applied(1.0, GOAL - [0.5, 0, 0], GOAL, task, lambda: 1.0)
    assert out.xdd == pytest.approx([0.0 + 2.0, 1, 2, 3, 4, 5])
    assert task.xdd == pytest.approx(np.arange(6.0))  # not modified in place


class _Anisotropic:
    """A primitive with the potential ψ = eᵀKe, K = diag(1, 5): ``ẍ = −Ke − 2ẋ``. Its
    restriction to the near side of the obstacle below has a minimum (the y error costs 5×
    the x error), where the barrier holds it; the Euclidean attractor has none there."""

    K = np.diag([1.0, 5.0])

    def acceleration(self, x, xd, goal):
        return -self.K @ (np.asarray(x) - goal) - 2.0 * np.asarray(xd)

    def potential(self, x, goal):
        e = np.asarray(x) - goal
        return float(e @ self.K @ e), 2.0 * self.K @ e


def _scenario() -> Scenario:
    obstacles = Obstacles([[1.5, 0.15, 0.0]], [0.5], np.zeros((1, 3)))
    return Scenario(name="held", task="point", q0=np.zeros(2),
                    goal=Goal([3.0, 0.0, 0.0], [0, 0, 0, 1]), obstacles=obstacles, dt=0.02,
                    max_steps=2000, goal_tolerance=0.05)


def _controller(name: str, pull: float):
    kin = PointKinematics(SPEC)
    puma = PumaController(PlanarTask(_Anisotropic()), kin)
    fabric = Fabric(FabricGains.from_mapping(None), SPEC.q_min, SPEC.q_max)
    forcing = Forcing(mode="metric", stall_pull=pull)
    if name == "fpm":
        return FpmController(puma, fabric, forcing=forcing)
    return CpmController(puma, fabric, beta=8.0, eps=1e-6, variant="paper", regulator_scale=1.0,
                         potential_scale=1.0, damping="matched",
                         rate=ControlRate(semi_implicit=True), forcing=forcing)


def test_cpm_held_at_its_potentials_minimum_on_an_obstacle_reaches_the_goal_with_the_pull():
    """Without the pull CPM rests against the obstacle, over 2 m short; with it the point goes
    round and reaches the goal, never touching the obstacle."""
    stuck = run_episode(_scenario(), _controller("cpm", 0.0), PointMassWorld(SPEC)).metrics
    assert not stuck.success_paper and stuck.final_position_error_m > 2.0
    m = run_episode(_scenario(), _controller("cpm", 1.5), PointMassWorld(SPEC)).metrics
    assert m.success_paper and m.success_whole_body, (m.failure_paper, m.final_position_error_m)
    assert m.min_clearance_m > 0


def test_a_run_that_keeps_approaching_is_unchanged_by_the_pull():
    """FPM goes round this obstacle by itself: the pull never arms and the path is the same,
    step for step."""
    runs = [run_episode(_scenario(), _controller("fpm", pull), PointMassWorld(SPEC))
            for pull in (0.0, 1.5)]
    assert runs[0].metrics.success_paper
    np.testing.assert_array_equal(runs[0].ee_position, runs[1].ee_position)


@pytest.mark.parametrize("bad", [{"stall_pull": -1.0}, {"stall_window": 2.0}])
def test_bad_stall_settings_are_refused(bad):
    with pytest.raises(ConfigError, match="stall"):
        Forcing.from_mapping({"mode": "metric", **bad})


def test_an_armed_pull_is_stuck_once_it_has_not_brought_the_hand_nearer_for_a_window():
    """Armed at 8 cm after a 2 s stall: while the pull brings the hand nearer by more than
    ``progress`` per window it is not stuck; held at 6 cm (from 4 s), it is stuck a window
    later."""
    near = StallPull(gain=1.5, window=2.0, progress=0.005, psi_progress=0.1, radius=0.045,
                     ramp=1.0, release=0.05, hold_radius=0.15)
    t = np.round(np.arange(0.0, 9.0, 0.1), 6)
    d = np.where(t < 2.0, 0.08, np.maximum(0.06, 0.08 - 0.01 * (t - 2.0)))  # 6 cm at 4 s
    m = StallMonitor(near)
    stuck = []
    for ti, di in zip(t, d, strict=True):
        m.acceleration(ti, GOAL - [di, 0.0, 0.0], GOAL, lambda: 1.0)
        stuck.append(m.stuck(ti))
    stuck = np.array(stuck)
    assert m.armed and not stuck[t < 5.0].any() and stuck[t >= 6.0].all()
    assert not StallMonitor(near).stuck(10.0)  # never armed
