"""The live reference planner in the Fabrics benchmark: live vs cited figures in the Markdown, a
missing or failing reference Python, the workload handed to the reference script. The real
reference (the GPL `fabrics` package in its own venv) runs only with TAMEDPUMA_REFERENCE_PYTHON."""

from __future__ import annotations

import json
import os
import stat
import sys

import numpy as np
import pytest

from tamedpuma.app import bench_fabrics as bf


def _row(n, median):
    return {"n_obstacles": n, "median_ms": median, "p10_ms": median * 0.9,
            "p90_ms": median * 1.2, "mean_ms": median, "n_calls": 100, "first_call_ms": 1.0}


def _report(live=None, note=None, python=None):
    return {"date": "today", "results": [_row(n, 0.1) for n in (2, 10, 100, 1000)],
            "build_ms": 0.2, "kinematics_median_ms": 0.02, "reference_python": python,
            "reference_live": live or {}, "reference_note": note,
            "reference_cited": bf.cited_block(),
            "machine": {"cpu_model": "cpu", "cores": 2, "python": "3", "numpy": "2",
                        "blas": "blas"}}


def _table_row(text, n):
    (line,) = [li for li in text.splitlines() if li.startswith(f"| {n} |")]
    return [cell.strip() for cell in line.strip("|").split("|")]


LIVE = {str(n): {"build_s": b, "median_ms": m, "p10_ms": m * 0.9, "p90_ms": m * 1.1,
                 "n_calls": 100, "finite": True, "fabrics_version": "0.10.0",
                 "motion": {"steps": 300, "dt": 0.01, "ee_distance_start_m": 0.71,
                            "ee_distance_end_m": 0.02, "min_clearance_m": 0.1, "finite": True}}
        for n, b, m in ((2, 0.5, 0.3), (10, 1.5, 1.2))}


def test_markdown_marks_live_and_cited_reference_figures():
    text = bf.markdown_section(_report(LIVE, python="/ref/python"))
    for n, shown, ratio in ((2, "0.300", "3.0×"), (10, "1.200", "12×")):
        cells = _table_row(text, n)
        assert cells[6] == shown and cells[7] == ratio, cells  # live: no date
    for n, shown, ratio in ((100, "5.1", "51×"), (1000, "47.0", "470×")):
        cells = _table_row(text, n)
        assert cells[6] == f"{shown} (dated {bf.CITED_DATE}, {bf.CITED_SOURCE})", cells
        assert cells[7] == ratio
    prose = " ".join(text.split())
    assert "measured live in this run at 2 and 10 obstacles" in prose
    assert "its build: 0.5 s (2), 1.5 s (10)" in prose  # live builds
    assert "cited, not measured in this run, at 100 and 1000 obstacles" in prose
    assert "22 s (100), 31 min (1000)" in prose and bf.CITED_DATE in prose  # cited builds
    assert "0.710 → 0.020 m" in prose and "/ref/python" in prose
    assert "Reference note" not in prose


def test_markdown_without_a_reference_python_cites_every_count():
    text = bf.markdown_section(_report())
    for n in (2, 10, 100, 1000):
        assert f"(dated {bf.CITED_DATE}" in _table_row(text, n)[6]
    prose = " ".join(text.split())
    assert "measured live" not in prose and "No reference Python was given" in prose
    assert "cited, not measured in this run, at 2, 10, 100 and 1000 obstacles" in prose


def test_markdown_with_a_failed_reference_shows_its_note():
    text = bf.markdown_section(_report(note="reference failed: x exited with code 1: boom"))
    prose = " ".join(text.split())
    assert "Reference note: reference failed: x exited with code 1: boom." in prose
    assert "No reference Python was given" not in prose


def _script(path, text):
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return str(path)


@pytest.mark.parametrize("python, expected", [
    ("/bin/false", "exited with code 1"),
    ("/nonexistent/python", "reference not run: /nonexistent/python"),
    ("crash", "exited with code 1: ValueError: boom"),
])
def test_a_missing_or_failing_reference_is_a_one_line_note(tmp_path, python, expected):
    if python == "crash":
        python = _script(tmp_path / "crash", "#!/bin/sh\necho 'Traceback (most recent call last):'"
                         " >&2\necho '  File x' >&2\necho 'ValueError: boom' >&2\nexit 1\n")
    report = bf.run(counts=(0, 2), calls=5, reference_python=python, reference_counts=(2,))
    note = report["reference_note"]
    assert expected in note and "\n" not in note and "Traceback" not in note
    assert [r["n_obstacles"] for r in report["results"]] == [0, 2]  # ours still measured
    assert report["reference_live"] == {}
    text = bf.markdown_section(report)
    assert _table_row(text, 2)[6].startswith("0.23 (dated")  # no live figure: the citation
    paths = bf.write(report, tmp_path)
    assert json.loads(paths[0].read_text())["reference_note"] == note


def test_main_without_reference_writes_cited_figures(tmp_path, monkeypatch):
    monkeypatch.delenv(bf.REFERENCE_ENV, raising=False)
    assert bf.main(["--counts", "2", "--calls", "5", "--root", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "benchmarks" / "fabrics.json").read_text())
    assert report["reference_live"] == {} and report["reference_python"] is None
    assert f"0.23 (dated {bf.CITED_DATE}" in (tmp_path / "BENCHMARKS.md").read_text()


FAKE = """import json, shutil, sys
src = sys.argv[sys.argv.index("--input") + 1]
shutil.copy(src, {copy!r})
print("noise the package prints")
for c in json.load(open(src))["counts"]:
    print(json.dumps({{"n_obstacles": c["n_obstacles"], "build_s": 0.5, "median_ms": 2.0,
                      "p10_ms": 1.5, "p90_ms": 2.5, "n_calls": c["n_calls"], "finite": True}}))
"""


def test_the_reference_gets_the_states_and_obstacles_we_time(tmp_path, monkeypatch):
    copy = tmp_path / "handed.json"
    fake = tmp_path / "fake_reference.py"  # stands in for reference_fabrics.py under its Python
    fake.write_text(FAKE.format(copy=str(copy)))
    python = _script(tmp_path / "fakepython",
                     f'#!/bin/sh\nshift\nexec "{sys.executable}" "{fake}" "$@"\n')
    timed = {}
    original = bf.time_counts

    def spy(*args, workload=None, **kwargs):
        timed["workload"] = workload
        return original(*args, workload=workload, **kwargs)

    monkeypatch.setattr(bf, "time_counts", spy)
    report = bf.run(counts=(2, 10, 3), calls=5, reference_python=python,
                    reference_counts=(2, 10, 7), seed=3)
    handed = json.loads(copy.read_text())
    workload = timed["workload"]
    assert len(handed["states"]) == len(workload.states) == bf.N_STATES
    for state, (q, qd) in zip(handed["states"], workload.states):
        assert np.array_equal(state["q"], q) and np.array_equal(state["qd"], qd)
    assert [c["n_obstacles"] for c in handed["counts"]] == [2, 10]  # 3: ours only; 7: untimed
    for c in handed["counts"]:
        centers, radii, _ = workload.obstacles[c["n_obstacles"]]
        assert np.array_equal(c["centers"], centers) and np.array_equal(c["radii"], radii)
        assert c["n_calls"] == 5
    assert handed["goal_position"] == bf.GOAL_POSITION.tolist()
    assert [s["radius"] for s in handed["spheres"]] == [0.09, 0.09, 0.09, 0.09, 0.07]
    assert set(report["reference_live"]) == {"2", "10"}
    assert report["reference_note"] == "reference counts [7] skipped: not among the timed counts"
    text = bf.markdown_section(report)
    assert _table_row(text, 2)[6] == "2.000"  # live, no date
    assert _table_row(text, 3)[6] == "—"  # 3 obstacles: neither a live nor a cited figure


def test_reference_result_lines_are_picked_from_noisy_output():
    out = 'Setting exection energy\n{"n_obstacles": 2, "median_ms": 1.0}\n[1, 2]\n{"x": 1}\n'
    assert bf._parse_lines(out) == {"2": {"median_ms": 1.0}}


@pytest.mark.skipif(not os.environ.get(bf.REFERENCE_ENV),
                    reason=f"set {bf.REFERENCE_ENV} to a Python with the `fabrics` package")
def test_the_real_reference_planner_is_finite_and_reaches_toward_the_goal():
    from tamedpuma.app.config import default_kinematics

    kin = default_kinematics()
    workload = bf.make_workload(kin, (2,))
    payload = bf.reference_payload(workload, kin.spec, (2,), calls=50, motion_steps=300,
                                   episode_steps=300)
    live, note = bf.run_reference(os.environ[bf.REFERENCE_ENV], payload, timeout=300)
    assert note is None, note
    row = live["2"]
    assert row["finite"] and row["n_calls"] == 50 and row["p10_ms"] <= row["p90_ms"]
    motion = row["motion"]
    assert motion["finite"]
    assert motion["ee_distance_end_m"] < 0.5 * motion["ee_distance_start_m"]
    assert motion["min_clearance_m"] > 0
    # driving the robot in PyBullet (.ci/run installs pybullet beside the package): every
    # period timed, and the simulated hand goes to the goal
    episode = row["episode"]
    assert "skipped" not in episode, episode
    assert episode["finite"] and episode["steps"] == 300
    assert 0 < episode["median_ms"] <= episode["p99_ms"] <= episode["max_ms"]
    assert episode["ee_distance_end_m"] < 0.2 * episode["ee_distance_start_m"]


def test_the_reference_episode_is_set_up_as_a_default_run_s_world():
    from tamedpuma.app.config import default_kinematics
    from tamedpuma.worlds.settings import SimConfig

    kin = default_kinematics()
    payload = bf.reference_payload(bf.make_workload(kin, (2,)), kin.spec, (2,), calls=5,
                                   episode_steps=7)
    episode = payload["episode"]
    from tamedpuma.app.compose import compose

    assert episode["steps"] == 7 and episode["dt"] == compose("sweep").scenario.dt
    assert episode["substep"] == SimConfig().substep
    assert episode["max_joint_force"] == SimConfig().max_joint_force
    assert episode["joint_names"] == list(kin.spec.joint_names)
    assert episode["qd_max"] == list(kin.spec.qd_max)
    assert "episode" not in bf.reference_payload(bf.make_workload(kin, (2,)), kin.spec, (2,),
                                                 calls=5)
