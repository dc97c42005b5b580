"""Analysis from logs alone: path difference, per-run metrics and Table 1 from MCAP files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tamedpuma.analysis.path_difference import path_difference, resample_by_arc_length
from tamedpuma.analysis.runs import load_runs

REPO = Path(__file__).resolve().parents[1]


def _curve(n):
    s = np.linspace(0, 1, n) ** 2  # non-uniform speed along the path
    return np.stack([np.cos(3 * s), np.sin(3 * s), s], axis=1)


def test_resampling_is_equally_spaced_in_arc_length():
    r = resample_by_arc_length(_curve(400), 50)
    gaps = np.linalg.norm(np.diff(r, axis=0), axis=1)
    assert gaps.std() / gaps.mean() < 0.01
    np.testing.assert_allclose(r[[0, -1]], _curve(400)[[0, -1]])


def test_path_difference_ignores_speed_and_measures_offsets():
    a = _curve(300)
    assert path_difference(a, _curve(1000)) < 1e-3  # same path, other timing
    assert path_difference(a, a + [0.0, 0.0, 0.1]) == pytest.approx(0.1)
    assert path_difference(a, a[::-1]) > 0.1  # same points, opposite direction


def _sweep(*args):
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.sweep", "recorder=mcap",
                           "method=joint_attractor", *args],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr


def test_table1_is_rebuilt_from_the_logs_alone(tmp_path):
    _sweep(f"output_root={tmp_path}/runs", "scenario=free")
    _sweep(f"output_root={tmp_path}/runs", "scenario=default")
    for summary in (tmp_path / "runs").rglob("summary.json"):
        summary.unlink()  # the analysis must not need them
    runs, paths, times = load_runs(tmp_path / "runs")
    assert len(runs) == 2 and set(runs["n_obstacles"]) == {0, 2}
    assert runs["complete"].all() and runs["success_whole_body"].all()
    assert runs["success_paper"].all() and set(runs["method_label"]) == {"joint_attractor"}
    assert all(len(times[p]) == n for p, n in zip(runs["path"], runs["steps"]))
    proc = subprocess.run([sys.executable, "-m", "analysis.tables", str(tmp_path / "runs"),
                           "--out", str(tmp_path / "tables")], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    csv = pd.read_csv(tmp_path / "tables" / "runs.csv")
    assert len(csv) == 2
    table = (tmp_path / "tables" / "table1.md").read_text()
    assert "joint_attractor" in table and "1.00" in table


def test_table1_on_an_empty_folder_is_a_one_line_error(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "analysis.tables", str(tmp_path)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.startswith("error: ")


@pytest.mark.parametrize("command,needs", [
    ("tables", "readable run logs (episode.mcap)"), ("figures", "readable run logs (episode.mcap)"),
    ("random_suite", "readable run logs (episode.mcap)"),
    ("disturbance", "run summaries (summary.json)"), ("scaling", "run summaries (summary.json)"),
    ("report", None)])
def test_every_analysis_command_refuses_a_missing_or_empty_folder_in_one_line(
        tmp_path, capsys, command, needs):
    import importlib

    main = importlib.import_module(f"tamedpuma.analysis.{command}").main
    assert main([str(tmp_path / "missing")]) == 2
    assert capsys.readouterr().err == f"error: {tmp_path / 'missing'} is not a folder\n"
    if needs is None:  # the report of an empty folder says so in the report
        return
    assert main([str(tmp_path)]) == 2
    assert capsys.readouterr().err == f"error: no {needs} below {tmp_path}\n"


def test_the_logs_read_on_several_processes_give_the_same_frame(tmp_path):
    import shutil

    _sweep(f"output_root={tmp_path}/one", "scenario=default")
    (log,) = (tmp_path / "one").rglob("episode.mcap")
    for i in range(40):  # enough logs for the worker processes to be used
        (tmp_path / "runs" / f"run_{i:02d}").mkdir(parents=True)
        shutil.copy(log, tmp_path / "runs" / f"run_{i:02d}" / "episode.mcap")
    (tmp_path / "runs" / "run_07" / "episode.mcap").write_bytes(b"not an mcap file")
    one, paths_one, times_one = load_runs(tmp_path / "runs", jobs=1)
    two, paths_two, times_two = load_runs(tmp_path / "runs", jobs=2)
    pd.testing.assert_frame_equal(one, two)
    assert len(one) == 39 and one.attrs["skipped"] == two.attrs["skipped"] == [
        str(tmp_path / "runs" / "run_07" / "episode.mcap")]
    assert paths_one.keys() == paths_two.keys()
    for p in paths_one:
        np.testing.assert_array_equal(paths_one[p], paths_two[p])
        np.testing.assert_array_equal(times_one[p], times_two[p])
    # a researcher's plain script, no __main__ guard: the default reads in its own process
    script = tmp_path / "plain.py"
    script.write_text("from tamedpuma.analysis.runs import load_runs\n"
                      f"runs, _, _ = load_runs({str(tmp_path / 'runs')!r})\n"
                      "print(len(runs))\n")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "39", proc.stderr
