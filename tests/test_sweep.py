"""``python -m tamedpuma.sweep`` as a user runs it: files, printed paths, one-line errors, kills."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tamedpuma.recording import read_mcap

REPO = Path(__file__).resolve().parents[1]


def _sweep(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "tamedpuma.sweep", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=timeout)


def test_one_episode_writes_its_files_and_says_where(tmp_path):
    proc = _sweep(f"output_root={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert f"run folder: {run_dir}" in proc.stdout
    for name in ("episode.mcap", "episode.rrd", "summary.json", ".hydra/config.yaml"):
        assert (run_dir / name).is_file(), name
        if not name.startswith("."):
            assert str(run_dir / name) in proc.stdout
    summary = json.loads((run_dir / "summary.json").read_text())
    log = read_mcap(run_dir / "episode.mcap")
    assert log.complete and log.n_steps == summary["steps"]
    # the default run is TamedPUMA (FPM) with the best model at hand, said on the console, and
    # it reaches the goal without collision (the README's first command)
    assert "method:" in log.config_yaml and "name: fpm" in log.config_yaml
    assert "model: " in proc.stdout and summary["model"]["model_sha256"][:12] in proc.stdout
    assert summary["success_whole_body"] and summary["min_clearance_m"] > 0
    assert f"replay: rerun {run_dir / 'episode.rrd'}" in proc.stdout


def test_a_learned_method_records_and_says_which_model_it_used(tmp_path):
    from tamedpuma.puma.store import file_sha256

    proc = _sweep(f"output_root={tmp_path}", "method=fpm", "recorder=mcap",
                  "scenario.max_steps=50")
    assert proc.returncode == 0, proc.stderr
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    summary = json.loads((run_dir / "summary.json").read_text())
    model = summary["model"]
    assert model["model_sha256"] == file_sha256(model["model_path"])
    assert model["model_name"] == "tomato" and model["model_data"] in ("synthetic", "real")
    log = read_mcap(run_dir / "episode.mcap")
    assert {k: log.info[k] for k in model} == model  # the same record in the MCAP metadata
    assert f"model: {model['model_origin']} {model['model_path']}" in proc.stdout


def _error_line(proc):
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert lines and lines[-1].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[-1]


@pytest.mark.parametrize("override, expected", [
    ("no_such_option=1", "no_such_option"),
    ("method=no_such_method", "no_such_method"),
    ("task=no_such_task", "no_such_task"),
    ("scenario.q0=[0,1", "malformed override"),
    ("robot.limit_margin=abc", "limit_margin"),
    ("scenario.q0=[0,0,0,2.5,0,0,0]", "outside joint 4's limits"),
    ("seed=range(1,3)", "needs a multirun: add -m"),  # a sweep without -m
    ("method=fpm,cpm", "needs a multirun: add -m"),
])
def test_user_mistakes_give_one_line_errors(tmp_path, override, expected):
    line = _error_line(_sweep(f"output_root={tmp_path}", override))
    assert expected in line


def test_unwritable_output_folder_is_a_one_line_error(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    line = _error_line(_sweep(f"output_root={blocker}/runs"))
    assert "not writable" in line


def test_a_run_folder_that_already_holds_a_run_is_a_one_line_error(tmp_path):
    run_dir = f"hydra.run.dir={tmp_path / 'run'}"
    first = _sweep("recorder=mcap", "scenario.max_steps=5", run_dir)
    assert first.returncode == 0, first.stderr
    before = (tmp_path / "run" / "episode.mcap").read_bytes()
    line = _error_line(_sweep("recorder=mcap", "scenario.max_steps=5", run_dir))
    assert "episode.mcap exists" in line and "hydra.run.dir" in line
    assert (tmp_path / "run" / "episode.mcap").read_bytes() == before  # not replaced


def test_start_just_past_a_limit_is_clamped_with_a_warning(tmp_path):
    proc = _sweep(f"output_root={tmp_path}", "recorder=none", "scenario.max_steps=5",
                  "scenario.q0=[0,-2.0944,0,-1,0,0,0]")
    assert proc.returncode == 0, proc.stderr
    assert "outside joint 2's limit" in proc.stdout + proc.stderr


def test_a_killed_run_leaves_a_readable_log_marked_incomplete(tmp_path):
    # a long episode (no success stop, 100,000 steps: minutes, where the default 2,000 can end
    # on a fast machine while the test still reads the first flush), killed after its first
    # flushes
    proc = subprocess.Popen(
        [sys.executable, "-m", "tamedpuma.sweep", f"output_root={tmp_path}",
         "stop_on_success=false", "scenario.max_steps=100000", "recorder.flush_every=20",
         "recorder.rerun=false"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    active = None
    while time.time() < deadline and active is None and proc.poll() is None:
        time.sleep(0.2)
        found = list(tmp_path.glob("*/episode.mcap.active"))
        try:  # the first flush (20 steps) readable: a loaded machine may take a while
            if found and read_mcap(found[0]).n_steps >= 20:
                active = found[0]
        except Exception:  # noqa: BLE001 - not readable yet: keep polling
            pass
    assert active is not None, "the run never wrote its log"
    assert proc.poll() is None, "the run ended before it could be killed"
    os.kill(proc.pid, signal.SIGTERM)
    proc.communicate(timeout=180)
    assert proc.returncode != 0
    run_dir = active.parent
    files = list(run_dir.glob("episode.mcap*"))
    assert len(files) == 1
    log = read_mcap(files[0])
    assert not log.complete
    assert 20 <= log.n_steps < 100000
    assert list(log.joints.index) == list(range(log.n_steps))


def _own_config_folder(tmp_path):
    """A user's config folder with one scenario of its own (the free scenario, renamed)."""
    folder = tmp_path / "my_conf"
    (folder / "scenario").mkdir(parents=True)
    (folder / "scenario" / "mine.yaml").write_text(
        "defaults:\n  - free\n  - _self_\nname: mine\nmax_steps: 3\n")
    return folder


@pytest.mark.parametrize("how", ["--config-dir", "-cd", "--config-dir=", "searchpath"])
def test_a_users_config_folder_is_found_the_hydra_way(tmp_path, how):
    folder = _own_config_folder(tmp_path)
    if how == "searchpath":
        args = [f"hydra.searchpath=[file://{folder}]"]
    elif how.endswith("="):
        args = [f"{how}{folder}"]
    else:
        args = [how, str(folder)]
    proc = _sweep(*args, "scenario=mine", "recorder=none", f"output_root={tmp_path / 'runs'}")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(next((tmp_path / "runs").glob("*/summary.json")).read_text())
    assert summary["scenario"] == "mine" and summary["steps"] == 3


def test_a_missing_config_folder_or_option_is_a_one_line_error(tmp_path):
    line = _error_line(_sweep("--config-dir", str(tmp_path / "nowhere"), "scenario=mine"))
    assert "config folder not found" in line
    folder = _own_config_folder(tmp_path)
    line = _error_line(_sweep("--config-dir", str(folder), "scenario=theirs"))
    assert "scenario/theirs" in line


def test_the_sweep_validates_one_job_per_override_and_still_stops_a_bad_one_early(tmp_path):
    """Hydra composes jobs before the first run to stop a sweep that cannot run; composing the
    first job that holds each override finds the same one-override failures (the bad value is
    the sweep's last job here) in far fewer composes."""
    from itertools import product

    from tamedpuma.app.sweep import representative_jobs

    batch = [[f"case={c}", f"method={m}", f"without_obstacles={w}", "+experiment=table1"]
             for c, m, w in product([f"tomato_{i:02d}" for i in range(15)],
                                    ["puma", "fpm", "cpm", "fabrics"], ["false", "true"])]
    jobs = representative_jobs(batch)
    assert {o for job in jobs for o in job} == {o for job in batch for o in job}
    assert len(jobs) <= 15 + 4 + 2 and jobs[0] == batch[0]
    (tmp_path / "conf" / "experiment").mkdir(parents=True)
    (tmp_path / "conf" / "experiment" / "bad.yaml").write_text(
        "# @package _global_\nhydra:\n  sweeper:\n    params:\n"
        "      method: fabrics,fpm,nonexistent\n")
    proc = _sweep("-m", "--config-dir", str(tmp_path / "conf"), "+experiment=bad", "recorder=none",
                  f"hydra.sweep.dir={tmp_path / 'out'}")
    assert proc.returncode != 0 and "method/nonexistent" in proc.stderr
    assert not list((tmp_path / "out").glob("*/summary.json"))  # stopped before any run
