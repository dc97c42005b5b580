"""A task from demonstrations alone: the formats users have (each bad case one line), the derived
goal/workspace/Δt, and the warning when a hand-set workspace misses the data."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tamedpuma.errors import DataError
from tamedpuma.puma import demo_formats, manifold, pipeline, task_from_demos
from tamedpuma.puma.training import Workspace
from tamedpuma.robot import rotations

REPO = Path(__file__).resolve().parents[1]


def _demo(rng, n=60, start=(0.5, 0.3, 0.6), goal=(0.6, -0.2, 0.2), angle0=0.8):
    """A smooth reach from ``start`` to ``goal`` with a rotation of ``angle0`` rad unwinding."""
    s = np.linspace(0.0, 1.0, n)
    w = 3 * s**2 - 2 * s**3
    start = np.asarray(start) + rng.normal(0, 0.03, 3)
    pos = start + w[:, None] * (np.asarray(goal) - start)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    q_goal = np.array([0.0, 1.0, 0.0, 0.0])
    rel = manifold.np_quat_exp(((1 - w) * angle0 / 2)[:, None] * axis)  # exp(θ/2 · axis)
    quat = rotations.quat_mul(rel, np.tile(q_goal, (n, 1)))
    t = np.arange(n) * 0.03
    return t, pos, quat


def _write_csv(path, t, pos, quat):
    rows = np.column_stack([t, pos, quat])
    np.savetxt(path, rows, delimiter=",", header=",".join(demo_formats.CSV_COLUMNS),
               comments="")


@pytest.fixture
def csv_folder(tmp_path):
    rng = np.random.default_rng(0)
    folder = tmp_path / "csv"
    folder.mkdir()
    for i in range(5):
        _write_csv(folder / f"demo_{i}.csv", *_demo(rng))
    return folder


def test_csv_npz_and_pickle_load_the_same_poses(tmp_path, csv_folder):
    raws = demo_formats.load_any(csv_folder)
    assert len(raws) == 5 and raws[0].quat is not None
    npz = tmp_path / "npz"
    npz.mkdir()
    rng = np.random.default_rng(0)
    for i in range(5):
        t, pos, quat = _demo(rng)
        np.savez(npz / f"d{i}.npz", t=t, position=pos, quaternion=quat)
    again = demo_formats.load_any(npz)
    for a, b in zip(raws, again):
        np.testing.assert_allclose(a.pos, b.pos, atol=1e-12)
        np.testing.assert_allclose(a.quat, b.quat, atol=1e-12)
        np.testing.assert_allclose(a.delta_t[1:], b.delta_t[1:], atol=1e-12)


def test_an_ee_path_from_a_recorded_run_is_a_demonstration(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.sweep", f"output_root={tmp_path}",
                           "recorder=mcap", "scenario.max_steps=30", "stop_on_success=false"],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    (mcap,) = tmp_path.glob("*/episode.mcap")
    from tamedpuma.recording import read_mcap

    log = read_mcap(mcap)
    (raw,) = demo_formats.load_any(mcap)
    np.testing.assert_allclose(raw.pos, log.ee[["x", "y", "z"]].to_numpy())
    assert len(raw.pos) == 30 and np.allclose(np.linalg.norm(raw.quat, axis=1), 1)
    assert len(demo_formats.load_any(tmp_path)) == 1  # a folder of run folders


def _bad(rng, case):
    t, pos, quat = _demo(rng)
    if case == "too short":
        return t[:5], pos[:5], quat[:5]
    if case == "NaN":
        pos[7, 1] = np.nan
    elif case == "not increasing":
        t[20] = t[19]
    elif case == "not unit length":
        quat[3] *= 1.1
    elif case == "millimetres":
        pos = pos * 1000
    elif case == "milliseconds":
        t = t * 1000 * 100
    return t, pos, quat


@pytest.mark.parametrize("fmt", ["csv", "npz"])
@pytest.mark.parametrize("case", ["too short", "NaN", "not increasing", "not unit length",
                                  "millimetres", "milliseconds"])
def test_each_bad_data_case_is_refused_with_one_line(tmp_path, fmt, case):
    rng = np.random.default_rng(1)
    t, pos, quat = _bad(rng, case)
    path = tmp_path / f"bad.{fmt}"
    if fmt == "csv":
        _write_csv(path, t, pos, quat)
    else:
        np.savez(path, t=t, position=pos, quaternion=quat)
    with pytest.raises(DataError) as err:
        demo_formats.load_any(path)
    text = str(err.value)
    assert "\n" not in text and str(path) in text
    assert case.split()[-1] in text or case in text


def test_mixed_units_in_one_folder_are_refused(tmp_path):
    rng = np.random.default_rng(2)
    for i, scale in enumerate((1.0, 1.0, 0.001)):  # the third in km: no, in metres/1000
        t, pos, quat = _demo(rng)
        np.savez(tmp_path / f"d{i}.npz", t=t, position=pos * scale, quaternion=quat)
    with pytest.raises(DataError, match="mixed units"):
        demo_formats.load_any(tmp_path)


def test_the_cli_prints_one_line_for_bad_data(tmp_path):
    rng = np.random.default_rng(3)
    _write_csv(tmp_path / "d.csv", *_bad(rng, "not increasing"))
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.train", "task=from_demos",
                           f"task.demos={tmp_path}", "puma=tiny", f"out_dir={tmp_path}/o"],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("error: ") and proc.stderr.count("\n") == 1
    assert "time is not increasing" in proc.stderr


def _all_within(raws, d: task_from_demos.DerivedTask):
    ws = d.workspace
    lo, hi = np.asarray(ws.low), np.asarray(ws.high)
    for r in raws:
        for rel, q_ref in ((r.pos - r.pos[-1], r.quat[-1]), (r.pos - d.goal_position,
                                                               np.array(d.goal_quaternion))):
            assert np.all(rel >= lo) and np.all(rel <= hi)
            assert rotations.orientation_error(r.quat, q_ref).max() <= ws.max_angle + 1e-9


def test_derived_workspace_contains_every_demonstration(csv_folder):
    raws = demo_formats.load_any(csv_folder)
    d = task_from_demos.derive(raws, margin=0.05, angle_margin=0.1)
    _all_within(raws, d)
    assert d.goal_rule == "mean" and d.dt == pytest.approx(0.03)
    np.testing.assert_allclose(d.goal_position, np.mean([r.pos[-1] for r in raws], axis=0))
    # the margin is stated and applied: shrinking the box by it leaves a demonstration on its face
    rel = np.concatenate([np.concatenate([r.pos - r.pos[-1], r.pos - d.goal_position])
                          for r in raws])
    np.testing.assert_allclose(rel.min(0) - 0.05, d.workspace.low)
    assert task_from_demos.demo_excursions(raws, d.workspace) == []


def test_spread_final_orientations_give_the_medoid_goal():
    rng = np.random.default_rng(4)
    raws = []
    for i, yaw in enumerate((0.0, 0.4, 2.0)):  # finals spread 2 rad (115 deg)
        t, pos, quat = _demo(rng)
        turn = np.array([0, 0, np.sin(yaw / 2), np.cos(yaw / 2)])
        quat = rotations.quat_mul(np.tile(turn, (len(quat), 1)), quat)
        raws.append(demo_formats.check_demo(t, pos, quat, f"d{i}"))
    d = task_from_demos.derive(raws)
    assert d.goal_rule == "medoid" and d.final_angle_spread == pytest.approx(2.0, abs=1e-6)
    assert rotations.orientation_error(np.array(d.goal_quaternion), raws[1].quat[-1]) < 1e-9
    _all_within(raws, d)


def _authors_folder(name: str) -> Path | None:
    """The authors' demonstration folder ``name`` where the project looks for their data
    (:func:`tamedpuma.puma.download.candidate_roots`), or None."""
    from tamedpuma.puma.download import candidate_roots

    return next((root / name for root in candidate_roots() if (root / name).is_dir()), None)


@pytest.mark.skipif(_authors_folder("pouring") is None,
                    reason="the authors' demonstrations are not here")
def test_derived_workspace_contains_the_real_unseen_demonstrations():
    folder = _authors_folder("pouring")
    raws = demo_formats.load_any(folder)
    d = task_from_demos.derive(raws)
    _all_within(raws, d)


def test_a_hand_set_box_that_misses_the_data_warns_or_refuses(csv_folder):
    raws = demo_formats.load_any(csv_folder)
    d = task_from_demos.derive(raws, margin=0.0)
    lo, hi = np.array(d.workspace.low), np.array(d.workspace.high)
    short = Workspace(tuple(lo), tuple(hi - np.array([0.0, 0.0, 0.1])), d.workspace.max_angle)
    task = {"name": "mine", "workspace_check": {"action": "warn", "scenarios": []}}
    said = []
    problems = pipeline.check_workspace(task, raws, short, log=said.append)
    assert problems and len(said) == len(problems)
    assert all(s.startswith("warning: workspace: demonstration") for s in said)
    worst = max(float(p.split(": ")[1].split(" m")[0]) for p in problems)
    assert worst == pytest.approx(0.1, abs=2e-3)  # names how far: the 0.1 m cut off
    from tamedpuma.errors import ConfigError

    with pytest.raises(ConfigError, match="leave the task workspace"):
        pipeline.check_workspace({**task, "workspace_check": {"action": "error", "scenarios": []}},
                                 raws, short, log=said.append)
    assert pipeline.check_workspace(task, raws, d.workspace, log=said.append) == []


def test_the_shipped_tasks_hold_their_scenario_starts():
    """tomato and pouring: every Table-1 start lies in the hand-set workspace (no warning)."""
    for name in ("tomato", "pouring"):
        from tamedpuma.app.config import load_group, workspace_starts

        task = load_group("task", name)
        starts = workspace_starts(task)
        assert len(starts) == 15
        for sname, p, q, gp, gq in starts:
            gp = task["goal_position"] if gp is None else gp  # None: the task's goal
            gq = task["goal_quaternion"] if gq is None else gq
            ws = pipeline.workspace_of(task, None)
            assert task_from_demos.start_excursions([(sname, p, q)], gp, gq, ws) == []


def test_training_from_a_csv_folder_writes_the_derivation(tmp_path, csv_folder):
    from tamedpuma.app import train

    out = tmp_path / "out"
    assert train.main(["task=from_demos", f"task.demos={csv_folder}", "task.name=mine",
                       "puma=tiny", f"out_dir={out}", "progress=false", "evaluate=false"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["derived"]["n_demos"] == 5 and report["dt"] == pytest.approx(0.03)
    from tamedpuma.puma import checkpoint

    _, meta = checkpoint.load(out / "puma.pt")
    assert meta.goal["position"] == report["derived"]["goal_position"]
    assert list(meta.workspace.low) == report["derived"]["workspace"]["position_low"]


def test_scenarios_from_demonstrations_start_near_a_demo_with_an_obstacle_on_its_path(
        csv_folder, kinematics):
    from tamedpuma.worlds import demo_scenarios as ds

    raws = demo_formats.load_any(csv_folder)
    goal = np.mean([r.pos[-1] for r in raws], axis=0)
    cfg = ds.DemoScenarioConfig(seed=3, start_noise=0.03, path_offset=0.03)
    home = [-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010]
    q0, centers, radii, i = ds.generate(raws, goal, kinematics, home, cfg)
    again = ds.generate(raws, goal, kinematics, home, cfg)
    np.testing.assert_array_equal(q0, again[0])  # seeded
    np.testing.assert_array_equal(centers, again[1])
    p0, quat0 = kinematics.ee_pose(q0)
    assert np.linalg.norm(p0 - raws[i].pos[0]) <= 0.03 + 1e-4  # near that demo's start
    assert rotations.orientation_error(quat0, raws[i].quat[0]) < 1e-3
    path = raws[i].pos - raws[i].pos[-1] + goal
    dist = np.linalg.norm(path[:, None] - centers[None], axis=-1).min(axis=0)
    assert np.all(dist <= 0.03 + 0.02)  # on or near the path (polyline sampling slack)
    gaps = np.linalg.norm(kinematics.sphere_centers(q0)[:, None] - centers[None], axis=-1)
    assert np.all(gaps - kinematics.spec.sphere_radii[:, None] - radii[None] >= 0.1 - 1e-9)
    assert np.all(np.linalg.norm(centers - goal, axis=1) - radii >= 0.1 - 1e-9)
    other = ds.generate(raws, goal, kinematics, home, ds.DemoScenarioConfig(seed=4))
    assert not np.allclose(other[1], centers)


@pytest.mark.parametrize("scenario", [["scenario=from_demos"],
                                      ["scenario=random", "scenario.random_seed=5"]])
def test_a_new_task_runs_with_obstacles_at_once(tmp_path, csv_folder, scenario):
    """task=from_demos with scenario=from_demos or scenario=random (starts near the
    demonstrations' starts, the derived goal and workspace): one sweep command, no config file."""
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.sweep", "task=from_demos",
                           f"task.demos={csv_folder}", "task.name=mine", *scenario,
                           "method=fabrics", "recorder=none", "scenario.max_steps=3",
                           f"output_root={tmp_path}"],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    (summary,) = tmp_path.glob("*/summary.json")
    s = json.loads(summary.read_text())
    assert s["task"] == "mine" and s["steps"] == 3 and np.isfinite(s["min_clearance_m"])


def test_the_goal_pose_check_finds_solutions_and_judges_their_clearance(kinematics):
    from tamedpuma.worlds.goal_pose import goal_pose_spheres, pose_clear

    q = np.array([0.3, 0.5, -0.2, -1.4, 0.1, 0.9, 0.2])  # a reachable pose, above the ground
    position, quaternion = kinematics.ee_pose(q)
    spheres = goal_pose_spheres(kinematics, position, quaternion, seed=0)
    assert len(spheres) >= 2
    radii = kinematics.spec.sphere_radii
    hand = spheres[:, -1]  # the hand's sphere sits where the pose puts it, in every solution
    assert np.allclose(hand, hand[0], atol=1e-3)
    assert pose_clear(spheres, radii, np.zeros((0, 3)), np.zeros(0), 0.02)
    assert not pose_clear(spheres[:0], radii, [[2.0, 2.0, 2.0]], [0.05], 0.02)
    far = position + np.array([0.0, 0.0, 1.5])
    assert pose_clear(spheres, radii, [far], [0.05], 0.02)
    assert not pose_clear(spheres, radii, [hand[0]], [0.05], 0.02)  # on the hand: blocked
    gaps = np.linalg.norm(spheres - far, axis=-1) - radii - 0.05
    assert not pose_clear(spheres, radii, [far], [0.05], float(gaps.min(axis=1).max()) + 1e-6)


def test_scenarios_from_demonstrations_leave_the_goal_pose_reachable(csv_folder, kinematics):
    """Obstacles drawn near the goal's end of the path block the goal pose unless the generator
    is given the goal orientation to check; with it, a clear solution is always left."""
    from tamedpuma.worlds import demo_scenarios as ds
    from tamedpuma.worlds.goal_pose import goal_pose_spheres, pose_clear

    raws = demo_formats.load_any(csv_folder)
    goal = np.mean([r.pos[-1] for r in raws], axis=0)
    goal_q = raws[0].quat[-1]
    home = [-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010]
    radii = kinematics.spec.sphere_radii
    blocked = 0
    for seed in range(4):
        cfg = ds.DemoScenarioConfig(seed=seed, path_fraction=(0.4, 0.95), min_clearance=0.03)
        spheres = goal_pose_spheres(kinematics, goal, goal_q, seed)
        _, centers, r, _ = ds.generate(raws, goal, kinematics, home, cfg)  # unchecked
        blocked += not pose_clear(spheres, radii, centers, r, cfg.goal_pose_clearance)
        _, centers, r, _ = ds.generate(raws, goal, kinematics, home, cfg, goal_q)
        assert pose_clear(spheres, radii, centers, r, cfg.goal_pose_clearance)
    assert blocked >= 1  # the draws the check turns away do occur here
