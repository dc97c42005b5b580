"""Faults injected one by one (README's faults table): a full disk, a resumed sweep whose model
changed, incomplete runs in every analysis, signals at start-up, a control period below the
simulator's substep, a pickle that would run code, a training with no data."""

from __future__ import annotations

import errno
import json
import os
import pickle
import signal
import subprocess
import sys
import warnings
from collections import namedtuple
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra.core.global_hydra import GlobalHydra

from tamedpuma import paths
from tamedpuma.errors import CheckpointError, DiskFullError

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
_Usage = namedtuple("_Usage", "total used free")


def _full_below(monkeypatch, folder: Path, free: int = 1000) -> None:
    """The file system holding ``folder`` reports ``free`` bytes free (others: unchanged)."""
    real = paths.shutil.disk_usage

    def usage(p):
        if str(Path(p).resolve()).startswith(str(folder.resolve())):
            return _Usage(10**9, 10**9 - free, free)
        return real(p)
    monkeypatch.setattr(paths.shutil, "disk_usage", usage)


def _enospc(*_, **__):
    raise OSError(errno.ENOSPC, "No space left on device")


def _mcap_fails_at(monkeypatch, step: int, folder_name: str | None = None) -> None:
    """The MCAP writer fails (as foxglove reports it: a RuntimeError without errno) when it
    writes the chunk holding ``step`` in a run folder named ``folder_name`` (any if None)."""
    from tamedpuma.recording.mcap_writer import McapRecorder

    real = McapRecorder._log_pending

    def log_pending(self):
        if self._count >= step and folder_name in (None, self.path.parent.name):
            raise RuntimeError("FoxgloveError: MCAP error: I/O error from writing")
        return real(self)
    monkeypatch.setattr(McapRecorder, "_log_pending", log_pending)


def _sweep(tmp_path, monkeypatch, *overrides, multirun=True) -> int:
    from tamedpuma.app import sweep

    GlobalHydra.instance().clear()
    argv = (["-m"] if multirun else []) + [
        "method=joint_attractor", "scenario=free", "scenario.max_steps=6", "recorder=mcap",
        "recorder.flush_every=2", f"output_root={tmp_path}", *overrides]
    if multirun:
        argv += [f"hydra.sweep.dir={tmp_path}/sweep", "hydra.sweep.subdir=${seed}"]
    else:
        argv += [f"hydra.run.dir={tmp_path}/run"]
    monkeypatch.setattr(sys, "argv", ["tamedpuma.sweep", *argv])
    handler = signal.getsignal(signal.SIGTERM)
    try:
        sweep.main(argv)
    except SystemExit as exit_:
        return exit_.code
    finally:
        signal.signal(signal.SIGTERM, handler)
        GlobalHydra.instance().clear()
    return 0


# ------------------------------------------------------------------------------ 1. full disk


def test_an_atomic_write_on_a_full_disk_leaves_no_partial_file(tmp_path, monkeypatch):
    target = tmp_path / "summary.json"
    target.write_text("old")
    real = Path.write_bytes

    def half_then_full(self, data):
        real(self, data[: len(data) // 2])
        _enospc()
    monkeypatch.setattr(Path, "write_bytes", half_then_full)
    with pytest.raises(DiskFullError) as err:
        paths.write_atomic(target, b"x" * 1000)
    assert err.value.needed == 1000 and str(target) in str(err.value)
    assert "about 1000 bytes needed" in str(err.value)
    assert target.read_text() == "old"  # the old file or the whole new one
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]


def test_a_full_output_folder_is_refused_before_anything_runs(tmp_path, monkeypatch):
    import builtins

    real_open = builtins.open

    def full_open(file, mode="r", *args, **kwargs):
        if ".write-test-" in str(file) and "w" in mode:
            handle = real_open(file, mode, *args, **kwargs)
            handle.write = _enospc
            return handle
        return real_open(file, mode, *args, **kwargs)
    monkeypatch.setattr(builtins, "open", full_open)
    problem = paths.writable_problem(tmp_path)
    assert problem.startswith(f"disk full: cannot write {tmp_path}"), problem
    assert not list(tmp_path.iterdir())  # the probe is removed


def test_a_single_run_on_a_full_disk_is_one_line_and_its_log_stays_incomplete(
        tmp_path, monkeypatch, capsys):
    from tamedpuma.recording import read_mcap

    _mcap_fails_at(monkeypatch, 4)
    _full_below(monkeypatch, tmp_path)
    code = _sweep(tmp_path, monkeypatch, multirun=False)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "Traceback" not in err[0]
    assert err[0].startswith(f"error: disk full: cannot write {tmp_path}/run/episode.mcap.active "
                             "(1000 bytes free, about ")
    assert err[0].endswith(" bytes needed)")
    run = tmp_path / "run"
    assert not (run / "summary.json").exists() and not (run / "episode.mcap").exists()
    log = read_mcap(run / "episode.mcap.active")  # readable up to its last flush, incomplete
    assert not log.complete and len(log.scalars) == 2


def test_a_full_disk_stops_a_sweep_with_its_counts(tmp_path, monkeypatch, capsys):
    _mcap_fails_at(monkeypatch, 4, folder_name="1")
    _full_below(monkeypatch, tmp_path)
    code = _sweep(tmp_path, monkeypatch, "seed=0,1,2")
    out, err = capsys.readouterr()
    assert code == 2
    assert "sweep: 2 runs: 1 executed and complete, 0 skipped (already complete), 1 failed" \
        in out, out
    assert f"failed: {tmp_path}/sweep/1: disk full" in out
    assert err.strip().splitlines()[-1].startswith(
        f"error: disk full: cannot write {tmp_path}/sweep/1/episode.mcap.active")
    assert "Traceback" not in err and "recorded in" not in err
    assert not (tmp_path / "sweep/2").exists()  # nothing after the full disk
    assert not list((tmp_path / "sweep/1").glob("failure.txt"))  # nothing half-written
    from tamedpuma.app.sweep import run_state

    assert run_state(tmp_path / "sweep/1") == "incomplete"  # a resume runs it again


def test_a_full_disk_while_hydra_saves_a_jobs_config_stops_the_sweep(tmp_path, monkeypatch,
                                                                      capsys):
    from tamedpuma.app import sweep

    real = sweep._WRITE_CONFIG

    def save(cfg, filename, output_dir):
        if Path(output_dir).parent.name == "1":
            (Path(output_dir) / filename).parent.mkdir(parents=True, exist_ok=True)
            (Path(output_dir) / filename).write_text("")  # a partial file
            _enospc()
        return real(cfg, filename, output_dir)
    monkeypatch.setattr(sweep, "_WRITE_CONFIG", save)
    code = _sweep(tmp_path, monkeypatch, "seed=0,1,2")
    out, err = capsys.readouterr()
    assert code == 2
    assert "sweep: 1 run: 1 executed and complete" in out
    assert err.strip().splitlines()[-1].startswith(
        f"error: disk full: cannot write {tmp_path}/sweep/1/.hydra/config.yaml")
    assert "Traceback" not in err
    assert not (tmp_path / "sweep/1/.hydra/config.yaml").exists()


def test_the_rerun_log_of_a_failed_write_keeps_its_active_name(tmp_path, monkeypatch):
    from tamedpuma.recording import RerunRecorder
    from tamedpuma.recording.rerun_writer import has_footer
    from tests.test_recording import _info, _record, _urdf

    rec = RerunRecorder(tmp_path / "episode.rrd")
    rec.open(_info(_urdf(tmp_path)))
    for k in range(3):
        rec.write(_record(k))
    monkeypatch.setattr("tamedpuma.recording.rerun_writer.has_footer", lambda p: False)
    _full_below(monkeypatch, tmp_path)
    with pytest.raises(DiskFullError, match="episode.rrd.active"):
        rec.close(complete=True, summary={})
    assert (tmp_path / "episode.rrd.active").is_file()
    assert not (tmp_path / "episode.rrd").exists()
    monkeypatch.undo()
    assert not has_footer(tmp_path / "missing.rrd")


def test_a_training_on_a_full_disk_leaves_no_tmp_file(tmp_path, monkeypatch):
    from tamedpuma.puma.checkpoint import save_atomic

    real = Path.write_bytes

    def full(self, data):
        real(self, data[:10])
        _enospc()
    monkeypatch.setattr(Path, "write_bytes", full)
    with pytest.raises(DiskFullError, match="train_state.pt"):
        save_atomic({"state": np.zeros(1000)}, tmp_path / "train_state.pt")
    assert list(tmp_path.iterdir()) == []


def test_a_rerun_flush_that_never_ends_is_a_full_disk_not_a_hang(tmp_path, monkeypatch):
    """Rerun's file sink that failed (a full disk) never acknowledges a flush, and closing its
    stream never returns (nor does rerun's exit-time shutdown): the recorder's flush gives up
    at once on a full disk, the close returns, and rerun's shutdown at exit is dropped."""
    import threading

    import rerun as rr

    from tamedpuma.recording import RerunRecorder
    from tamedpuma.recording import rerun_writer as rw
    from tests.test_recording import _info, _record, _urdf

    rec = RerunRecorder(tmp_path / "episode.rrd", batch=2)
    rec.open(_info(_urdf(tmp_path)))
    rec.write(_record(0))
    never = threading.Event()

    def timed_out(self, timeout_sec=1e38):
        never.wait(min(timeout_sec, 0.05))
        raise RuntimeError("Flush timed out - not all log messages were sent")
    monkeypatch.setattr(rr.RecordingStream, "flush", timed_out)
    monkeypatch.setattr(rr.RecordingStream, "disconnect", lambda self: never.wait(20))
    dropped = []
    monkeypatch.setattr(rr, "unregister_shutdown", lambda: dropped.append(True))
    monkeypatch.setattr(rw, "FLUSH_SLICE", 0.05)
    _full_below(monkeypatch, tmp_path)
    with pytest.raises(DiskFullError, match="episode.rrd.active"):
        rec.write(_record(1))  # the batch's flush
    rec.close(complete=False, summary={})  # returns, the stream left open
    assert dropped == [True] and rw._STUCK[-1] is not None
    assert (tmp_path / "episode.rrd.active").is_file() and not (tmp_path / "episode.rrd").exists()
    rw._STUCK.clear()
    never.set()


@pytest.mark.skipif(os.geteuid() != 0 or not sys.platform.startswith("linux"),
                    reason="mounts a small tmpfs: root on Linux")
@pytest.mark.parametrize("recorder", ["recorder.flush_every=20", "recorder.mcap=false"])
def test_a_single_run_on_a_real_small_tmpfs(tmp_path, recorder):
    """The real thing: a 300 KiB tmpfs as output_root (skipped where mounting fails), with
    both logs (the MCAP fills it) and with the Rerun log only (its file sink fails: a flush
    that waited on it held the run, past SIGTERM, for ever)."""
    mount = tmp_path / "small"
    mount.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=300k", "tmpfs", str(mount)],
                      capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "tamedpuma.sweep", "method=joint_attractor",
             "scenario.max_steps=3000", "stop_on_success=false", recorder,
             f"output_root={mount}", f"hydra.run.dir={mount}/run"],
            cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=300)
        lines = [x for x in proc.stderr.splitlines() if not x.startswith("pybullet build")]
        assert proc.returncode == 2, proc.stderr[-2000:]
        assert len(lines) == 1 and lines[0].startswith(f"error: disk full: cannot write {mount}")
        assert not (mount / "run/summary.json").exists()
        assert not (mount / "run/episode.mcap").exists()  # nothing left looking complete
        assert not (mount / "run/episode.rrd").exists()
        if "mcap=false" in recorder:
            assert (mount / "run/episode.rrd.active").is_file()
            return
        from tamedpuma.recording import read_mcap

        assert not read_mcap(mount / "run/episode.mcap.active").complete
    finally:
        subprocess.run(["umount", str(mount)], capture_output=True)


# ----------------------------------------------------------- 2. a resumed sweep, model changed


def test_a_resume_after_the_model_changed_is_refused_naming_both(tmp_path, monkeypatch, capsys):
    args = ("method=fpm", "seed=0,1")
    assert _sweep(tmp_path, monkeypatch, *args) == 0
    capsys.readouterr()
    kept = tmp_path / "sweep/0/summary.json"
    summary = json.loads(kept.read_text())
    now = summary["model"]["model_sha256"]
    assert summary["code_revision"]
    summary["model"]["model_sha256"] = "0" * 64  # the model this run was made with before
    summary["code_revision"] = "an-older-revision"
    kept.write_text(json.dumps(summary))
    (tmp_path / "sweep/1/summary.json").unlink()  # one run left to do
    assert _sweep(tmp_path, monkeypatch, *args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: resume refused: ") and "000000000000" in err[-1]
    assert now[:12] in err[-1]
    assert not (tmp_path / "sweep/1/summary.json").exists()  # nothing ran
    # the same model, another code revision: a warning, and the sweep goes on
    summary["model"]["model_sha256"] = now
    kept.write_text(json.dumps(summary))
    assert _sweep(tmp_path, monkeypatch, *args) == 0
    err = capsys.readouterr().err
    assert "warning: 1 of the 1 kept complete runs were made at code revision " \
           "an-older-revision" in err


def test_a_resume_with_another_checkpoint_is_refused_before_any_job_runs(tmp_path, monkeypatch,
                                                                        capsys):
    """The kept run's own config still picks its model; the job that would run now picks
    another (``method.checkpoint`` changed between the attempts): refused at the first job,
    before it runs, naming both sha256."""
    shipped = ROOT / "tamedpuma/puma/shipped"
    args = ("method=puma", "seed=0,1", "scenario.max_steps=6")
    first = f"method.checkpoint={shipped / 'tomato/puma.pt'}"
    assert _sweep(tmp_path, monkeypatch, *args, first) == 0
    kept = json.loads((tmp_path / "sweep/1/summary.json").read_text())["model"]["model_sha256"]
    for run in (tmp_path / "sweep/0").iterdir():  # the first job is left to do
        if run.is_file():
            run.unlink()
    capsys.readouterr()
    other = f"method.checkpoint={shipped / 'pouring/puma.pt'}"
    assert _sweep(tmp_path, monkeypatch, *args, other) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"error: resume refused: {tmp_path / 'sweep/1'} kept a run of "
                              f"model sha256 {kept[:12]}, the job {tmp_path / 'sweep/0'} picks "
                              "sha256 ")
    assert "one sweep mixes no models" in err[-1]
    assert not (tmp_path / "sweep/0/summary.json").exists()  # nothing ran
    assert _sweep(tmp_path, monkeypatch, *args, first) == 0  # the same model: it goes on


def _frame(**columns) -> pd.DataFrame:
    n = len(next(iter(columns.values())))
    base = {"method": ["fpm"] * n, "method_label": ["fpm"] * n, "task": ["tomato"] * n,
            "complete": [True] * n}
    return pd.DataFrame({**base, **columns})


def test_the_analyses_refuse_to_pool_two_models_in_one_row_unless_asked():
    from tamedpuma.analysis.runs import mixed_models, models_problem

    one = _frame(model_sha256=["a" * 64] * 3)
    two = _frame(model_sha256=["a" * 64, "b" * 64, "b" * 64])
    assert mixed_models(one) == [] and models_problem(one) is None
    lines = mixed_models(two)
    assert lines == [f"fpm on tomato: runs of 2 models: sha256 {'b' * 12} (2 runs), "
                     f"sha256 {'a' * 12} (1 run)"]
    assert "--mixed-models" in models_problem(two)
    assert models_problem(two, allow_mixed=True) is None
    other_task = two.assign(task=["tomato", "pouring", "pouring"])
    assert mixed_models(other_task) == []  # a row per task: one model each


# ------------------------------------------------------ 3. incomplete runs: one rule everywhere


def test_one_rule_excludes_incomplete_runs_from_every_analysis(tmp_path, monkeypatch, capsys):
    import shutil

    from tamedpuma.analysis import random_suite, report
    from tamedpuma.analysis.runs import split_incomplete

    frame = _frame(complete=[True, False, True])
    frame.attrs["failed"] = [("x", "boom")]
    scored, incomplete = split_incomplete(frame)
    assert len(scored) == 2 and len(incomplete) == 1 and scored.attrs["failed"]
    assert len(split_incomplete(frame, include=True)[0]) == 3

    assert _sweep(tmp_path, monkeypatch, "seed=0,1", "scenario=default",
                  "scenario.max_steps=40", "stop_on_success=false") == 0
    runs = tmp_path / "sweep"
    shutil.copytree(runs / "1", runs / "1_killed")
    log = runs / "1_killed/episode.mcap"
    log.rename(log.with_name("episode.mcap.active"))
    active = runs / "1_killed/episode.mcap.active"
    active.write_bytes(active.read_bytes()[: active.stat().st_size // 2])
    capsys.readouterr()

    assert report.main([str(runs), "--no-figures"]) == 0
    text = (runs / "report.md").read_text()
    assert "1 incomplete run (killed, interrupted or truncated: listed above) is not scored" \
        in text
    failing = text.split("## Failing runs", 1)[1]
    assert "1_killed" not in failing  # not a failure of class "time"
    assert random_suite.main([str(runs)]) == 0
    out = capsys.readouterr().out
    assert "3 runs read (1 incomplete, not scored)" in out and "incomplete: " in out
    table = pd.read_csv(runs / "random_suite.csv")
    assert table["scenarios"].sum() == 2


# ----------------------------------------------------------------- 5. signals at start-up


def test_ctrl_c_and_sigterm_while_checking_the_config_are_one_line(tmp_path, monkeypatch,
                                                                   capsys):
    from tamedpuma.app import sweep

    def ctrl_c(*_):
        raise KeyboardInterrupt
    monkeypatch.setattr(sweep, "precheck_overrides", ctrl_c)
    assert _sweep(tmp_path, monkeypatch) == 130
    assert capsys.readouterr().err == (
        "interrupted (Ctrl-C) while checking the configuration: nothing was run\n")

    def sigterm(*_):
        os.kill(os.getpid(), signal.SIGTERM)
        signal.pause()  # the handler raises before this returns
    monkeypatch.setattr(sweep, "precheck_overrides", sigterm)
    assert _sweep(tmp_path, monkeypatch) == 143
    assert capsys.readouterr().err == (
        "interrupted (SIGTERM) while checking the configuration: nothing was run\n")
    assert sweep._partial_log_line(tmp_path) == (
        f"interrupted before the run's logs were opened: nothing recorded in {tmp_path}")

    def swallowed(*_):  # OmegaConf turned the SIGTERM's SystemExit into a config error
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            signal.pause()
        except SystemExit:
            return "method.null_space.target: 'NoneType' object has no attribute '_invalid'"
    monkeypatch.setattr(sweep, "precheck_overrides", swallowed)
    assert _sweep(tmp_path, monkeypatch) == 143
    assert capsys.readouterr().err == (
        "interrupted (SIGTERM) while checking the configuration: nothing was run\n")


@pytest.mark.parametrize("interrupt,status,name", [(KeyboardInterrupt, 130, "Ctrl-C"),
                                                   (lambda: SystemExit(143), 143, "SIGTERM")])
def test_an_interrupt_after_the_config_check_outside_a_run_is_one_line(
        tmp_path, monkeypatch, capsys, interrupt, status, name):
    """Between the config check and a run (Hydra composing, creating the sweep folder) or
    between runs: one line, not a silent exit."""
    from tamedpuma.app import sweep

    def hydra_setup():
        raise interrupt()
    monkeypatch.setattr(sweep, "_hydra_main", hydra_setup)
    assert _sweep(tmp_path, monkeypatch) == status
    assert capsys.readouterr().err == (
        f"interrupted ({name}) outside a run: the complete runs are kept; the same command "
        "goes on from there\n")


@pytest.mark.parametrize("sig,status,name", [(signal.SIGINT, 130, "Ctrl-C"),
                                             (signal.SIGTERM, 143, "SIGTERM")])
def test_a_signal_while_an_entry_point_loads_is_one_line(sig, status, name):
    """Ctrl-C while ``python -m tamedpuma.sweep`` imports torch, pinocchio and Hydra printed
    the import chain (30 lines); SIGTERM ended it without a word. Every entry point loads
    inside :func:`tamedpuma.startup.starting`."""
    code = ("import os, signal, time\n"
            "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "from tamedpuma.startup import starting\n"
            "with starting():\n"
            f"    os.kill(os.getpid(), {int(sig)})\n"
            "    time.sleep(30)\n")
    proc = subprocess.run([sys.executable, "-c", code], env=ENV, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == status
    assert proc.stderr == f"interrupted ({name}) while starting: nothing was run\n"
    for shim in ("sweep", "train", "replay", "models", "bench", "bench_fabrics", "body_model",
                 "lasa"):
        text = (ROOT / "tamedpuma" / f"{shim}.py").read_text()
        assert f"with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback\n" \
            f"    from tamedpuma.app.{shim} import main\n" in text, shim


# ------------------------------------------------------------ 6. dt below the substep


@pytest.mark.parametrize("dt", ["1e-10", "0.0005"])
def test_a_control_period_below_the_substep_is_refused_at_the_config_check(dt):
    from tamedpuma.app.cli import precheck_overrides

    problem = precheck_overrides("sweep", [f"scenario.dt={dt}"])
    assert problem == (f"scenario.dt must be at least sim.substep = 0.001 s (one physics step "
                       f"per control period), got {float(dt):g}"), problem


@pytest.mark.parametrize("argv", [["-m", "--cfg", "job"], ["--cfg=job", "--info"],
                                  ["--multirun", "-c", "all", "method=fpm"]])
def test_two_run_modes_at_once_are_one_line_before_hydra(argv):
    from tamedpuma.app.cli import precheck_overrides

    problem = precheck_overrides("sweep", argv)
    assert problem is not None, argv
    assert problem.startswith("use one of --cfg, --info, --multirun"), problem
    assert precheck_overrides("sweep", ["--cfg", "job"]) is None


# ---------------------------------------------------------- 7. a pickle that would run code


class _RunsCode:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.mark.parametrize("form", ["protocol0", "protocol2", "protocol5", "torch-zip"])
def test_a_pickle_that_would_run_code_is_refused_as_such(tmp_path, form):
    import torch

    from tamedpuma.puma import checkpoint

    marker, path = tmp_path / "ran", tmp_path / "evil.pt"
    if form == "torch-zip":
        torch.save({"a": _RunsCode(marker)}, path)
    else:
        path.write_bytes(pickle.dumps(_RunsCode(marker), protocol=int(form[-1])))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning printed before the error
        with pytest.raises(CheckpointError) as err:
            checkpoint.load(path)
    assert f"checkpoint {path}: refused: loading it would run code (it names " \
           f"{os.system.__module__}.system)" == str(err.value)
    assert not marker.exists()


# ----------------------------------------------------------------------- training's edges


def test_a_task_from_demonstrations_without_demos_names_task_demos(tmp_path):
    out = tmp_path / "never"
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.train", "task=from_demos",
                           "task.name=mine", f"out_dir={out}"], cwd=tmp_path, env=ENV,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith(
        "error: missing config key task.demos (")
    assert not out.exists()  # a failed training leaves no empty folder


# -------------------------------------------------------------------------------- rough edges


@pytest.fixture(scope="module")
def small_sweep(tmp_path_factory):
    """Two complete runs (MCAP only) and a killed copy of the second one."""
    import shutil

    root = tmp_path_factory.mktemp("edges")
    proc = subprocess.run(
        [sys.executable, "-m", "tamedpuma.sweep", "-m", "method=joint_attractor",
         "scenario=default", "scenario.max_steps=40", "stop_on_success=false", "recorder=mcap",
         "recorder.flush_every=10", "seed=0,1", f"output_root={root}",
         f"hydra.sweep.dir={root}/sweep", "hydra.sweep.subdir=${seed}"],
        cwd=root, env=ENV, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    sweep = root / "sweep"
    shutil.copytree(sweep / "1", sweep / "1_killed")
    log = sweep / "1_killed/episode.mcap"
    data = log.read_bytes()
    log.unlink()
    (sweep / "1_killed/episode.mcap.active").write_bytes(data[: len(data) // 2])
    return sweep, proc.stdout


def test_a_plain_sweep_prints_done_of_total_and_the_time_the_goal_was_reached(small_sweep):
    _, out = small_sweep
    import re

    progress = [m.group(0) for ln in out.splitlines() if (m := re.match(r"\[\d+/\d+\]", ln))]
    assert progress == ["[1/2]", "[2/2]"], out
    assert "sweep: 2 runs: 2 executed and complete" in out
    line = next(ln for ln in out.splitlines() if ln.startswith("joint_attractor on "))
    assert "no success [time] (episode 40 steps, " in line  # no reach: no settle time


def _replay(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tamedpuma.replay", *map(str, args)],
                          env=ENV, capture_output=True, text=True, timeout=120)


def test_replay_names_the_runs_of_a_folder_and_an_incomplete_log(small_sweep):
    sweep, _ = small_sweep
    proc = _replay(sweep, "--build")
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        f"error: {sweep} is a folder of 3 runs, not one run: replay one of them (0, 1, "
        f"1_killed), e.g. python -m tamedpuma.replay {sweep / '0'}")
    proc = _replay(sweep / "1_killed", "--build")
    assert proc.returncode == 0, proc.stderr
    assert f"incomplete run: {sweep / '1_killed/episode.mcap.active'} ends at step " \
        in proc.stdout
    assert "incomplete" not in _replay(sweep / "0", "--build").stdout


def test_replay_checks_the_reference_method_and_says_when_none_is_found(small_sweep):
    sweep, _ = small_sweep
    proc = _replay(sweep / "0", "--build", "--reference", "nosuch")
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: --reference nosuch: no such method; choose one of ")
    assert "fpm" in proc.stderr and "\n" not in proc.stderr.strip()
    proc = _replay(sweep / "0", "--build", "--reference", "fabrics")
    assert proc.returncode == 0
    assert "reference path: none (no obstacle-free fabrics run" in proc.stdout


def test_replay_web_binds_the_viewer_to_host(tmp_path, monkeypatch):
    from tamedpuma.app import replay

    started = []

    class Viewer:
        def __init__(self, cmd, **_):
            started.append(cmd)
            self.returncode = None

        def wait(self):
            if self.returncode is None:
                self.returncode = -15
                raise KeyboardInterrupt
            return self.returncode

        def terminate(self):
            pass
    rrd = tmp_path / "episode.rrd"
    rrd.write_bytes(b"")
    monkeypatch.setattr(replay.subprocess, "Popen", Viewer)
    files = replay.Replay(rrd=rrd, mcap=None, overlay=None, rebuilt=False, reference_run=None)
    assert replay.serve_web(files, "127.0.0.1", 9090, 0) == 0
    cmd = started[0]
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1"
    assert cmd[cmd.index("--web-viewer-port") + 1] == "9090"
    assert cmd[-1].startswith("http://127.0.0.1:") and cmd[-1].endswith("/episode.rrd")


def test_shell_completion_completes_method_options_for_python_m(capsys, monkeypatch):
    from tamedpuma.app.cli import shell_completion

    with pytest.raises(SystemExit) as exit_:
        shell_completion(["--shell-completion"], "tamedpuma.sweep")
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --shell-completion needs one of install=SHELL") \
        and err.count("\n") == 1
    env = {**ENV, "COMP_LINE": "python -m tamedpuma.sweep method=f", "COMP_POINT": "34"}
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.sweep", "-sc", "query=bash"],
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.stdout.split() == ["method=fabrics", "method=fpm", "method=fpm_literal"], (
        proc.stderr[-2000:])
    script = subprocess.run([sys.executable, "-m", "tamedpuma.sweep", "-sc", "install=bash"],
                            env=ENV, capture_output=True, text=True, timeout=120).stdout
    if not Path("/bin/bash").exists():
        return
    python = sys.executable  # the user's python: the one that has tamedpuma, whatever PATH says
    test = (script + f'\nCOMP_LINE="{python} -m tamedpuma.sweep method=f"\n'
            f"COMP_WORDS=({python} -m tamedpuma.sweep method=f); COMP_CWORD=3\n"
            '_tamedpuma_sweep_completion; printf "%s\\n" "${COMPREPLY[@]}"\n')
    proc = subprocess.run(["/bin/bash", "-c", test], env=ENV, capture_output=True, text=True,
                          timeout=120)
    assert proc.stdout.split() == ["method=fabrics", "method=fpm", "method=fpm_literal"], (
        proc.stderr[-2000:])


def test_runs_of_a_far_goal_or_a_model_of_another_task_are_warned(tmp_path, monkeypatch,
                                                                  capsys):
    code = _sweep(tmp_path, monkeypatch, "scenario.goal.position=[50,0,0.5]", multirun=False)
    out, err = capsys.readouterr()
    assert code == 0
    assert "[0/?]" not in out  # a single run prints no sweep progress
    assert "warning: the goal (50.00, 0.00, 0.50) m is 50.00 m from the robot's base, beyond " \
           "the arm's reach" in err
    pouring = ROOT / "tamedpuma/puma/shipped/pouring/puma.pt"
    code = _sweep(tmp_path / "b", monkeypatch, "method=fpm", f"method.checkpoint={pouring}",
                  "scenario=default", multirun=False)
    err = capsys.readouterr().err
    assert f"warning: the model {pouring} was trained on task pouring, this run is task " \
           "tomato" in err
    assert "beyond the arm's reach" not in err


def test_the_analyses_help_names_the_installed_module():
    from tamedpuma.analysis import report, tables
    from tamedpuma.analysis.runs import runs_parser

    for module in (tables, report):
        name = module.__name__
        parser = runs_parser(module.__doc__)
        assert parser.prog == f"python -m {name}"
        assert "python -m analysis." not in parser.format_help()


def test_the_replay_layout_plots_against_time_and_names_joint_speeds():
    from tamedpuma.recording.rerun_writer import MAX_LEGEND, replay_blueprint

    blueprint = replay_blueprint(["clearance_m"], [f"j{i}" for i in range(7)])
    assert str(blueprint.time_panel.timeline) == "time"
    assert MAX_LEGEND >= 8  # seven joints and the speed limit keep their legend
    layout = json.loads((ROOT / "docs/foxglove_layout.json").read_text())
    speed = layout["configById"]["Plot!speed"]["paths"]
    assert [p["label"] for p in speed] == [f"joint {i}" for i in range(1, 8)]


def test_a_paths_figure_without_a_puma_run_does_not_name_one(small_sweep, tmp_path,
                                                             monkeypatch):
    from matplotlib.figure import Figure

    from tamedpuma.analysis import report

    titles = []
    real = Figure.suptitle
    monkeypatch.setattr(Figure, "suptitle",
                        lambda self, t, **kw: titles.append(t) or real(self, t, **kw))
    sweep, _ = small_sweep
    assert report.main([str(sweep), "--out", str(tmp_path)]) == 0
    paths_titles = [t for t in titles if "end-effector paths" in t]
    assert paths_titles and not any("PUMA" in t for t in paths_titles)
