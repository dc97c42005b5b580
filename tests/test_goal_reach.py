"""Whether a goal pose can be held clear of the obstacles (tamedpuma/analysis/goal_reach.py) and
the command that splits a sweep's convergence by it (tamedpuma/app/goal_reach.py)."""

import csv
import json

import numpy as np
import pytest
from omegaconf import OmegaConf

from tamedpuma.analysis.goal_reach import goal_pose_gap, reach_table, scenario_key
from tamedpuma.app import goal_reach
from tamedpuma.app.compose import compose
from tamedpuma.app.sweep import world_of


def _random(task: str, kind: str, seed: int, *extra: str):
    return compose("sweep", ["+experiment=random", f"task={task}", f"scenario.start_kind={kind}",
                             f"scenario.random_seed={seed}", "method=fabrics", "recorder=none",
                             *extra])


@pytest.fixture(scope="module")
def pouring():
    """A scenario of the randomized suite whose goal pose no configuration holds clear (pouring,
    near a Table-1 start, seed 2081: the wrist and forearm of every IK solution of the tilted
    pose reach into the sphere 10.5 cm from the goal point) and one whose pose is clear (2084)."""
    return {seed: world_of(_random("pouring", "near_table1", seed)) for seed in (2081, 2084)}


def _gap(world, centers=None, radii=None, count=40):
    _, kin, sc = world
    return goal_pose_gap(kin, sc.goal.position, sc.goal.quaternion,
                         sc.obstacles.centers if centers is None else centers,
                         sc.obstacles.radii if radii is None else radii, count=count)


def test_the_goal_point_clear_is_not_the_goal_pose_clear(pouring):
    """The generator keeps the obstacle 10 cm from the goal point in both scenarios; in 2081
    every IK solution of the pose found puts a body sphere inside it, in 2084 one is clear."""
    for seed in (2081, 2084):
        _, _, sc = pouring[seed]
        surface = np.linalg.norm(sc.obstacles.centers - sc.goal.position, axis=1) \
            - sc.obstacles.radii
        assert surface.min() >= 0.1
    assert _gap(pouring[2081]) < 0.0
    assert _gap(pouring[2084]) > 0.0


def test_the_gap_is_the_clearance_of_the_best_solution(pouring):
    """No obstacle: inf. An obstacle on the goal point: negative for every solution, by at least
    its radius less the hand's own sphere offset. Moving the blocking obstacle away raises the
    gap by as much where it is the nearest thing (a rigid shift of the obstacle along the line
    to the solution's nearest sphere changes no IK solution)."""
    world = pouring[2084]
    _, kin, sc = world
    assert _gap(world, np.zeros((0, 3)), np.zeros(0)) == np.inf
    on_goal = _gap(world, sc.goal.position[None], np.array([0.05]))
    assert on_goal < -0.05
    far = _gap(world, np.array([[5.0, 5.0, 5.0]]), np.array([0.1]))
    near = _gap(world, np.array([[4.0, 4.0, 5.0]]), np.array([0.1]))
    assert far > near > 3.0


def test_blocked_and_clear_runs_are_counted_per_method():
    gaps = {("pouring", "a", 1): -0.02, ("pouring", "b", 1): 0.05, ("pouring", "c", 1): None}
    rows = [{"method": "fpm", "task": "pouring", "scenario": s, "n_obstacles": 1,
             "converged_paper": c} for s, c in (("a", True), ("b", True), ("c", False))]
    rows.append({"method": "cpm", "method_label": "cpm-eps", "task": "pouring",
                 "scenario": "b", "n_obstacles": 1, "converged_paper": False})
    table = {r["method"]: r for r in reach_table(rows, gaps)}
    assert table["fpm"] == {"method": "fpm", "clear_runs": 1, "clear_converged": 1,
                            "blocked_runs": 1, "blocked_converged": 1,
                            "unsolved_runs": 1, "unsolved_converged": 0}
    assert table["cpm-eps"]["clear_runs"] == 1 and table["cpm-eps"]["clear_converged"] == 0
    assert scenario_key({"task": "t", "scenario": "s"}) == ("t", "s", 0)


def _fake_run(folder, cfg, scenario, converged, n_obstacles=1):
    (folder / ".hydra").mkdir(parents=True)
    OmegaConf.save(cfg, folder / ".hydra" / "config.yaml")
    (folder / "summary.json").write_text(json.dumps({
        "status": "complete", "method": "fabrics", "task": "pouring", "scenario": scenario,
        "n_obstacles": n_obstacles, "converged_paper": converged}))


def test_the_command_writes_the_scenarios_and_splits_the_runs(tmp_path, capsys):
    for seed, converged in ((2081, False), (2084, True)):
        _fake_run(tmp_path / f"s{seed}", _random("pouring", "near_table1", seed),
                  f"random_pouring_near_table1_{seed}", converged)
    assert goal_reach.main([str(tmp_path), "--solutions", "40"]) == 0
    out = capsys.readouterr().out
    assert "2 scenarios: goal pose clear 1, blocked (every IK solution found inside an " \
        "obstacle) 1, no IK solution above the ground found 0" in out
    assert "| fabrics | 1 / 1 | 0 / 1 | 0 / 0 |" in out
    with (tmp_path / "goal_reach.csv").open() as f:
        rows = {r["scenario"]: r for r in csv.DictReader(f)}
    assert rows["random_pouring_near_table1_2081"]["verdict"] == "blocked"
    assert rows["random_pouring_near_table1_2084"]["verdict"] == "clear"
    assert float(rows["random_pouring_near_table1_2081"]["gap_m"]) < 0.0


@pytest.mark.parametrize("make", ["missing", "empty"])
def test_the_command_refuses_a_folder_without_runs(tmp_path, capsys, make):
    target = tmp_path / "nothing" if make == "missing" else tmp_path
    assert goal_reach.main([str(target)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1
