"""The example method plugins, installed with ``pip install -e`` into a fresh environment
(examples/pink_cbf, and the one written from docs/extending.md's files), run through the
Table-1 command, the analysis and the replay like built-in methods; and pink_cbf's barriers'
mathematics (values and Jacobians against finite differences, the CBF condition after one
step)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "pink_cbf"

pytest.importorskip("pink")
pytest.importorskip("qpsolvers")


@pytest.fixture(scope="module")
def controller_module():
    sys.path.insert(0, str(EXAMPLE))
    try:
        from pink_cbf import controller
        yield controller
    finally:
        sys.path.remove(str(EXAMPLE))


def _configuration(kinematics, q):
    from pink import Configuration

    kinematics.evaluate(q, np.zeros(7))
    return Configuration(kinematics.model, kinematics.data, q, copy_data=False,
                         forward_kinematics=False)


def test_the_barriers_jacobians_match_finite_differences(controller_module, kinematics):
    q = np.array([0.3, 0.5, -0.2, -1.2, 0.4, 0.8, 0.1])
    ids, radii = kinematics.sphere_ids, kinematics.sphere_radii
    obstacle = controller_module.SphereObstacleBarrier(ids, radii, 5.0, 0.02, 10.0)
    obstacle.update([[0.4, 0.1, 0.6], [-0.3, 0.2, 0.9]], [0.1, 0.05], np.zeros((2, 3)))
    ground = controller_module.GroundBarrier(ids, radii, 5.0, 0.01)
    for barrier in (obstacle, ground):
        h0 = barrier.compute_barrier(_configuration(kinematics, q))
        jac = barrier.compute_jacobian(_configuration(kinematics, q))
        assert jac.shape == (len(h0), 7) and len(h0) > 0
        eps = 1e-6
        numeric = np.column_stack([
            (barrier.compute_barrier(_configuration(kinematics, q + eps * e)) - h0) / eps
            for e in np.eye(7)])
        np.testing.assert_allclose(jac, numeric, atol=1e-5)
    centers = kinematics.sphere_centers(q)
    d = np.linalg.norm(centers[:, None] - np.array([[0.4, 0.1, 0.6], [-0.3, 0.2, 0.9]]), axis=2)
    assert obstacle.min_clearance == pytest.approx((d - radii[:, None] - [0.1, 0.05]).min())


def test_a_moving_obstacle_tightens_the_barrier_rows(controller_module, kinematics):
    q = np.array([0.3, 0.5, -0.2, -1.2, 0.4, 0.8, 0.1])
    barrier = controller_module.SphereObstacleBarrier(kinematics.sphere_ids,
                                                      kinematics.sphere_radii, 5.0, 0.02, 10.0)
    centre = kinematics.sphere_centers(q)[-1] + [0.3, 0.0, 0.0]
    barrier.update([centre], [0.05], [[0.0, 0.0, 0.0]])
    _, still = barrier.compute_qp_inequalities(_configuration(kinematics, q), 0.02)
    barrier.update([centre], [0.05], [[-0.5, 0.0, 0.0]])  # coming at the hand
    _, coming = barrier.compute_qp_inequalities(_configuration(kinematics, q), 0.02)
    assert np.all(coming <= still) and np.any(coming < still - 0.1)


def test_one_step_keeps_the_cbf_condition(controller_module, kinematics):
    """Pushed straight at an obstacle, the QP's step keeps h(q + v Δt) ≥ (1 − γΔt) h(q) (to
    first order) and keeps the clearance above d_min."""
    from pink_cbf import PinkCbfSettings

    from tamedpuma.methods._policy import TaskAcceleration
    from tamedpuma.types import Goal, Observation, Obstacles, Scenario

    q0 = np.array([0.0, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
    hand = kinematics.ee_pose(q0)[0]
    obstacle = hand + np.array([0.16, 0.0, 0.0])

    class Push:  # a task pushing the hand along +x at 20 m/s²
        reference = None

        def acceleration(self, state, qd, *args):
            return TaskAcceleration(np.array([20.0, 0, 0, 0, 0, 0]), state.ee_jacobian,
                                    state.ee_jdqd)

    settings = PinkCbfSettings(d_min=0.02, barrier_gain=5.0)
    ctrl = controller_module.PinkCbf(kinematics, Push(), settings)
    scenario = Scenario("push", "t", q0, Goal(hand, [0, 0, 0, 1]),
                        Obstacles([obstacle], [0.05], np.zeros((1, 3))), 0.02, 10, 0.05)
    ctrl.reset(scenario)
    q, qd = q0.copy(), np.zeros(7)
    for step in range(40):
        obs = Observation(step * 0.02, step, q, qd, np.array([obstacle]), np.array([0.05]),
                          np.zeros((1, 3)), hand, np.array([0, 0, 0, 1.0]), np.zeros(3))
        command = ctrl.step(obs)
        h = command.scalars["min_clearance_m"] - settings.d_min
        qd = qd + 0.02 * command.qdd
        q = q + 0.02 * qd
        ctrl.step(obs.__class__(**{**obs.__dict__, "q": q}))
        h_next = ctrl.obstacles.min_clearance - settings.d_min
        assert h_next >= (1 - 5.0 * 0.02) * h - 1e-3
        assert command.scalars["qp_failures"] == 0
    assert ctrl.obstacles.min_clearance > settings.d_min - 1e-3


def extending_page_files(folder: Path) -> list[Path]:
    """Write the files of docs/extending.md's plugin example (fenced blocks whose first line
    is ``# file: PATH``) below ``folder``; the files written."""
    text = (ROOT / "docs" / "extending.md").read_text()
    written = []
    for block in re.findall(r"```[a-z]*\n(# file: [^\n]+\n.*?)```", text, flags=re.S):
        head, body = block.split("\n", 1)
        path = folder / head.removeprefix("# file: ").strip()
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(body)
        written.append(path)
    return written


def test_the_extending_pages_method_is_under_100_lines(tmp_path):
    files = extending_page_files(tmp_path)
    assert {p.name for p in files} == {"pyproject.toml", "__init__.py", "pinv_puma.yaml"}
    assert sum(len(p.read_text().splitlines()) for p in files) < 100


@pytest.fixture(scope="module")
def fresh_env(tmp_path_factory):
    """A new venv that reuses this one's packages (a .pth, as .ci/run's second venv does)
    with the example plugins installed editable: nothing of the package changes."""
    venv = tmp_path_factory.mktemp("plugin") / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()"
                           "['purelib'])"], check=True, capture_output=True, text=True)
    here = sysconfig.get_paths()["purelib"]
    Path(site.stdout.strip(), "_tamedpuma_deps.pth").write_text(
        f"import site; site.addsitedir({here!r})\n")
    page = tmp_path_factory.mktemp("page")
    extending_page_files(page)
    for folder in (EXAMPLE, page / "pinv_puma"):
        subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "-e",
                        str(folder)], check=True, capture_output=True)
    return python


def _run(python, *args, cwd):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.run([str(python), *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)


@pytest.mark.slow
def test_the_plugins_run_through_table1_the_analysis_and_the_replay(fresh_env, tmp_path):
    out = tmp_path / "runs"
    done = _run(fresh_env, "-m", "tamedpuma.sweep", "-m", "+experiment=table1",
                "method=pink_cbf,pinv_puma", "case=tomato_03,pouring_03",
                "without_obstacles=false",
                "scenario.max_steps=40", "hydra/launcher=basic",
                "hydra.callbacks.table1.build_models=false", f"output_root={out}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    summaries = [json.loads(p.read_text()) for p in sorted(out.rglob("summary.json"))]
    assert sorted((s["method"], s["task"], s["status"]) for s in summaries) == [
        (m, t, "complete") for m in ("pink_cbf", "pinv_puma") for t in ("pouring", "tomato")]
    assert all(s["model"]["model_sha256"] and s["steps"] == 40 for s in summaries)
    table = (out / "table1" / "table1.md").read_text()
    assert "| pink_cbf" in table and "| pinv_puma" in table
    run_dir = next(out.rglob("summary.json")).parent
    replay = _run(fresh_env, "-m", "tamedpuma.replay", str(run_dir), "--build",
                  "--reference", "none", cwd=tmp_path)
    assert replay.returncode == 0, replay.stderr[-2000:]
    assert "episode.rrd" in replay.stdout


@pytest.mark.slow
def test_the_plugin_runs_through_the_randomized_suite_and_its_analysis(fresh_env, tmp_path):
    out = tmp_path / "runs"
    done = _run(fresh_env, "-m", "tamedpuma.sweep", "-m", "+experiment=random",
                "method=pink_cbf", "task=tomato", "scenario.start_kind=near_table1",
                "scenario.random_seed=2000", "without_obstacles=false", "scenario.max_steps=40",
                f"output_root={out}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    (path,) = out.rglob("summary.json")
    summary = json.loads(path.read_text())
    assert (summary["method"], summary["suite"]) == ("pink_cbf", {"name": "random", "version": 2})
    table = _run(fresh_env, "-m", "tamedpuma.analysis.random_suite", str(out / "random"),
                 cwd=tmp_path)
    assert table.returncode == 0, table.stderr[-2000:]
    assert "| pink_cbf" in (out / "random" / "random_suite.md").read_text()


@pytest.mark.slow
def test_a_plugin_mistake_is_one_line_in_the_fresh_environment(fresh_env, tmp_path):
    done = _run(fresh_env, "-m", "tamedpuma.sweep", "method=pink_cbf",
                "method.barrier_gain=-1", f"output_root={tmp_path}", cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "error: method: barrier_gain must be > 0, got -1.0"]
