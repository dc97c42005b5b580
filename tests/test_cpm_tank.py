"""CPM's energy tank (``method.tank``, :class:`tamedpuma.methods.cpm.EnergyTank`): FPM's law
where the tank pays for it, CPM's dissipative law where it cannot. Properties of the coefficient,
and the case it is for on the point robot: a wall with the goal behind it (going round climbs ψ)."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.episode import run_episode
from tamedpuma.errors import ConfigError
from tamedpuma.fabrics import Fabric, FabricGains
from tamedpuma.methods._policy import LinearTaskPrimitive, PlanarTask
from tamedpuma.methods._tamed import ControlRate, Forcing, PumaController
from tamedpuma.methods.cpm import CpmController, EnergyTank
from tamedpuma.methods.fpm import FpmController
from tamedpuma.types import Goal, Obstacles, Scenario
from tamedpuma.worlds.pointmass import PointKinematics, PointMassWorld, point_spec

SPEC = point_spec(speed_limit=50.0)
BETA = 8.0


def test_the_tank_never_lets_the_total_energy_rise():
    """For random states: W = H + T falls at least at β‖q̇‖² (``P(c) + ΔT/Δt ≤ −β‖q̇‖²``), c lies
    between CPM's and FPM's coefficients, the level stays in [0, size]."""
    rng = np.random.default_rng(0)
    dt = 0.02
    for refill in (0.0, 0.5, 1.0):
        tank = EnergyTank(1.0, refill)
        for _ in range(2000):
            qn = float(rng.uniform(1e-4, 4.0))
            power_zero = float(rng.normal(0.0, 3.0))
            beta = float(rng.uniform(0.1, 2.0))
            # CPM's matched coefficient: the largest c ≤ 0 with P(c) ≤ −β‖q̇‖²
            c_cpm = min(0.0, -(power_zero + beta * qn) / qn)
            c_fpm = float(rng.normal(0.0, 2.0))
            size = float(rng.uniform(0.0, 3.0))
            level = float(rng.uniform(0.0, size))
            c, after = tank.coefficient(c_cpm, c_fpm, power_zero, qn, beta, level, size, dt)
            assert min(c_cpm, c_fpm) - 1e-12 <= c <= max(c_cpm, c_fpm) + 1e-12
            assert c >= c_cpm - 1e-12
            assert -1e-12 <= after <= size + 1e-12
            power = power_zero + c * qn
            assert power + (after - level) / dt <= -beta * qn + 1e-9 * (1 + abs(power_zero))


def test_an_empty_tank_is_cpm_and_a_full_one_pays_fpm_s_law():
    tank = EnergyTank(1.0)
    # FPM's law injects 2 rad²/s³ beyond what β asks to dissipate: an empty tank leaves CPM's c
    assert tank.coefficient(-3.0, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0, 0.02) == (-2.0, 0.0)
    c, level = tank.coefficient(-2.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.02)
    assert c == 0.0 and level == pytest.approx(1.0 - 2.0 * 0.02)
    # part of the deficit: c between the two, the tank emptied
    c, level = tank.coefficient(-2.0, 0.0, 1.0, 1.0, 1.0, 0.02, 1.0, 0.02)
    assert c == pytest.approx(-1.0) and level == 0.0


@pytest.mark.parametrize("bad", [(-1.0, 0.0), (1.0, 1.5), (1.0, -0.1)])
def test_bad_tank_settings_are_refused(bad):
    with pytest.raises(ConfigError, match="tank"):
        EnergyTank(*bad)


def _wall() -> Scenario:
    """Start at the origin, goal 3 m along x behind a wall of three 0.35 m spheres at x = 1.5
    (centres 0.56 m apart, the wall 0.1 m off the start-goal line): going round it means moving
    sideways, away from the goal, so ψ = ‖x − x_g‖² climbs on the way."""
    ys = np.array([-0.56, 0.0, 0.56]) + 0.1
    obstacles = Obstacles([[1.5, y, 0.0] for y in ys], [0.35] * 3, np.zeros((3, 3)))
    return Scenario(name="wall", task="point", q0=np.zeros(2), goal=Goal([3.0, 0.0, 0.0],
                    [0, 0, 0, 1]), obstacles=obstacles, dt=0.02, max_steps=3000,
                    goal_tolerance=0.05)


pytestmark = pytest.mark.usefixtures("point_scale_forcing")


def _controller(name: str, tank: float = 0.0):
    kin = PointKinematics(SPEC)
    puma = PumaController(PlanarTask(LinearTaskPrimitive(1.0, 2.0)), kin)
    fabric = Fabric(FabricGains.from_mapping(None), SPEC.q_min, SPEC.q_max)
    forcing = Forcing(mode="metric", circulation=0.3)
    if name == "fpm":
        return FpmController(puma, fabric, alpha_min=-20.0, energy="execution", forcing=forcing)
    return CpmController(puma, fabric, beta=BETA, eps=1e-6, variant="paper", regulator_scale=1.0,
                         potential_scale=1.0, damping="matched",
                         rate=ControlRate(semi_implicit=True),
                         alpha_min=-20.0, energy="execution", forcing=forcing,
                         tank=EnergyTank(tank, refill=0.0, clearance=np.inf))


def test_with_a_tank_cpm_goes_round_a_wall_where_plain_cpm_stalls(scalar_log):
    """FPM goes round the wall; plain CPM stops in front of it (its regulator brakes every motion
    that climbs ψ); with a tank of κ = 1 (as much energy as ψ holds at the start) CPM goes round
    as FPM does, with W = H + T non-increasing at every step; a tank of κ = 0.2 runs dry first."""
    sc = _wall()
    assert run_episode(sc, _controller("fpm"), PointMassWorld(SPEC)).metrics.success_paper
    plain = run_episode(sc, _controller("cpm"), PointMassWorld(SPEC)).metrics
    assert not plain.success_paper and plain.final_position_error_m > 1.5
    small = run_episode(sc, _controller("cpm", 0.2), PointMassWorld(SPEC)).metrics
    assert not small.success_paper
    full = run_episode(sc, _controller("cpm", 1.0), PointMassWorld(SPEC), [scalar_log]).metrics
    assert full.success_paper and full.min_clearance_m > 0
    w = np.array([r["energy_total"] + r["tank"] for r in scalar_log.rows])
    tank = np.array([r["tank"] for r in scalar_log.rows])
    assert tank[0] == pytest.approx(9.0)  # κ k_ψ ψ(q₀) = 1 · ‖(3, 0)‖²
    assert tank.min() < 0.5 * tank[0]  # it paid for the detour
    assert np.all(np.diff(w) <= 1e-3 * w[0])


def test_the_tank_pays_only_near_an_obstacle_when_it_has_a_clearance():
    """With a clearance the tank is engaged only within that clearance of an obstacle: far from
    obstacles CPM is CPM, to the bit (ψ never rises there)."""
    tank = EnergyTank(1.0, 0.5, clearance=0.03)
    assert tank.engaged(0.02) and not tank.engaged(0.05)
    sc = _wall()
    free = Scenario(name="free", task="point", q0=sc.q0, goal=sc.goal,
                    obstacles=Obstacles.empty(), dt=sc.dt, max_steps=sc.max_steps,
                    goal_tolerance=sc.goal_tolerance)
    plain = run_episode(free, _controller("cpm"), PointMassWorld(SPEC))
    gated = _controller("cpm", 1.0)
    gated.tank = EnergyTank(1.0, 0.5, clearance=0.3)
    tanked = run_episode(free, gated, PointMassWorld(SPEC))
    np.testing.assert_array_equal(tanked.q, plain.q)
