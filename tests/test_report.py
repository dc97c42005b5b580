"""Figures and report from a small recorded sweep: table values equal values computed
independently from the raw logged messages; incomplete sweeps are reported, not crashed on."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from tamedpuma.analysis.report import completeness
from tamedpuma.analysis.runs import load_runs
from tamedpuma.analysis.stats import bootstrap_ci
from tamedpuma.analysis.tables import path_differences, table1

REPO = Path(__file__).resolve().parents[1]
MAX_STEPS = 300
DT = 0.02


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """2 methods × 2 scenarios × with/without obstacles, ≤ 300 steps each (one sweep)."""
    out = tmp_path_factory.mktemp("report")
    proc = subprocess.run(
        [sys.executable, "-m", "tamedpuma.sweep", "-m", "method=joint_attractor,fabrics",
         "scenario=default,tomato/03", "without_obstacles=false,true", "recorder=mcap",
         f"scenario.max_steps={MAX_STEPS}", f"output_root={out}"],
        cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out


def _raw(path: Path) -> dict:
    """Per step, straight from the MCAP messages: t, end effector, goal, body spheres,
    obstacles, controller time (no tamedpuma reader involved)."""
    decoder = DecoderFactory()
    by_time: dict[int, dict] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            row = by_time.setdefault(message.log_time, {})
            if channel.topic == "/scalars":
                row.update(json.loads(message.data))
                continue
            msg = decoder.decoder_for(channel.message_encoding, schema)(message.data)
            if channel.topic == "/ee_pose":
                p = msg.pose.position
                row["ee"] = np.array([p.x, p.y, p.z])
            elif channel.topic == "/scene":
                for ent in msg.entities:
                    row[ent.id] = np.array([[s.pose.position.x, s.pose.position.y,
                                             s.pose.position.z, s.size.x / 2]
                                            for s in ent.spheres]).reshape(-1, 4)
    steps = [by_time[k] for k in sorted(by_time)]
    return {
        "t": np.array([s["t"] for s in steps]),
        "ee": np.array([s["ee"] for s in steps]),
        "goal": np.array([s["goal"][0, :3] for s in steps]),
        "body": [s["body_spheres"] for s in steps],
        "obstacles": [s["obstacles"] for s in steps],
        "ms": np.array([s["compute_time_ms"] for s in steps]),
    }


def _independent(path: Path) -> dict:
    """Paper success, time to success, min sphere clearance and mean controller time."""
    raw = _raw(path)
    err = np.linalg.norm(raw["ee"] - raw["goal"], axis=1)
    clear = np.array([
        (np.linalg.norm(b[:, None, :3] - o[None, :, :3], axis=2) - b[:, None, 3]
         - o[None, :, 3]).min() if len(o) else np.inf
        for b, o in zip(raw["body"], raw["obstacles"])])
    reached = np.flatnonzero(err <= 0.05)
    k = reached[0] if len(reached) else None
    success = (k is not None and raw["t"][k] < MAX_STEPS * DT
               and bool((clear[: k + 1] >= 0).all()))
    return {"success": success, "tts": raw["t"][k] if k is not None else np.nan,
            "min_clearance": clear.min(), "ms": raw["ms"], "ee": raw["ee"],
            "n_obstacles": len(raw["obstacles"][0])}


def _resampled(path: np.ndarray, n: int = 200) -> np.ndarray:
    s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    u = np.linspace(0, s[-1], n)
    return np.column_stack([np.interp(u, s, path[:, i]) for i in range(3)])


def test_tables_equal_values_computed_from_the_raw_logs(sweep):
    runs, paths, times = load_runs(sweep)
    assert len(runs) == 8 and runs["complete"].all()
    truth = {p: _independent(Path(p)) for p in runs["path"]}
    assert {v["success"] for v in truth.values()} == {True, False}  # a mixed sweep

    for r in runs.itertuples():  # per run
        ind = truth[r.path]
        assert r.success_paper == ind["success"]
        assert r.n_obstacles == ind["n_obstacles"]
        np.testing.assert_allclose(r.time_to_success_s, ind["tts"], equal_nan=True)
        if ind["n_obstacles"]:
            assert r.min_clearance_m == pytest.approx(ind["min_clearance"], abs=1e-6)

    table = table1(runs.assign(path_difference_m=path_differences(runs, paths)), times)
    for method in ("joint_attractor", "fabrics"):  # per method, on the runs with obstacles
        mine = [v for p, v in truth.items()
                if v["n_obstacles"] and runs.set_index("path").loc[p, "method"] == method]
        row = table[table["method"] == method].iloc[0]
        assert row["runs"] == len(mine) == 2
        assert row["success (paper)"] == f"{np.mean([v['success'] for v in mine]):.2f}"
        ms = np.concatenate([v["ms"] for v in mine])
        assert row["computation [ms] mean ± std (all steps)"] == \
            f"{ms.mean():.2f} ± {ms.std():.2f}"
        tts = [v["tts"] for v in mine if v["success"]]
        if len(tts) == 1:
            assert row["time-to-success [s]"] == f"{tts[0]:.2f} (1 run)"
        elif tts:
            assert row["time-to-success [s]"].startswith(f"{np.mean(tts):.2f} ± ")

    # path difference to a reference method's obstacle-free run of the same scenario
    diff = path_differences(runs, paths, reference="joint_attractor")
    for idx, r in runs[runs["n_obstacles"] == 0].iterrows():
        ref = runs[(runs["n_obstacles"] == 0) & (runs["method"] == "joint_attractor")
                   & (runs["scenario"] == r["scenario"])]["path"].iloc[0]
        expected = np.linalg.norm(_resampled(truth[r["path"]]["ee"])
                                  - _resampled(truth[ref]["ee"]), axis=1).mean()
        assert diff[idx] == pytest.approx(expected, abs=1e-9)


def test_figures_and_report_are_written(sweep, tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "analysis.report", str(sweep), "--out", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    text = (out / "report.md").read_text()
    for name in ("paths_tomato", "clearance_psi_tomato", "success_timing"):
        png = out / "figures" / f"{name}.png"
        assert png.stat().st_size > 10_000 and (out / "figures" / f"{name}.pdf").is_file()
        assert f"figures/{name}.png" in text
    assert "## Table 1" in text and "- complete" in text
    runs, _, _ = load_runs(sweep)
    failing = runs[~runs["success_paper"] | ~runs["success_whole_body"]]
    assert len(failing) >= 1
    for p in failing["path"]:
        assert f"python -m tamedpuma.replay {Path(p).parent}" in text


def test_an_incomplete_sweep_is_reported_not_crashed_on(sweep, tmp_path):
    broken = tmp_path / "broken"
    shutil.copytree(sweep, broken)
    jobs = sorted(next((broken / "multirun").iterdir()).glob("[0-9]*_*"))
    shutil.rmtree(jobs[-1])  # missing job
    (jobs[0] / "episode.mcap").unlink()  # failed job: no log
    log = jobs[1] / "episode.mcap"  # killed job: truncated .active log
    data = log.read_bytes()
    log.unlink()
    (jobs[1] / "episode.mcap.active").write_bytes(data[: len(data) // 2])

    runs, _, _ = load_runs(broken)
    (sweep_entry,) = completeness(broken, runs)
    assert sweep_entry["expected"] == 8 and sweep_entry["present"] == 7
    assert sweep_entry["missing"] == [7]
    assert sweep_entry["no_log"] == [jobs[0]] and sweep_entry["truncated"] == [jobs[1]]
    proc = subprocess.run([sys.executable, "-m", "analysis.report", str(broken),
                           "--no-figures"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    text = (broken / "report.md").read_text()
    assert "missing jobs: 7" in text and jobs[0].name in text and jobs[1].name in text

    empty = tmp_path / "empty"
    empty.mkdir()
    proc = subprocess.run([sys.executable, "-m", "analysis.report", str(empty)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "No readable run" in (empty / "report.md").read_text()


def test_bootstrap_interval():
    rng = np.random.default_rng(1)
    x = rng.normal(3.0, 1.0, 400)
    iv = bootstrap_ci(x)
    assert iv.low < 3.0 < iv.high and iv.value == pytest.approx(x.mean())
    half = (iv.high - iv.low) / 2  # ≈ 1.96 σ/√n
    assert half == pytest.approx(1.96 / np.sqrt(400), rel=0.15)
    assert bootstrap_ci(np.ones(5)).low == 1.0 and bootstrap_ci([]).n == 0
    wide = bootstrap_ci(x[:25])
    assert wide.high - wide.low > 2 * (iv.high - iv.low)  # shrinks like 1/√n
    assert str(bootstrap_ci(pd.Series([0.0, 1.0]))).startswith("0.50 [")
