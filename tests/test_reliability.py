"""Fault injection and bad input: each test is a row of the table in docs/faults.md. A sweep
survives its worst run; killed runs and trainings leave what they wrote and resume; analysis
counts what it could not score."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra.core.global_hydra import GlobalHydra

from tamedpuma.errors import ConfigError
from tamedpuma.types import Command

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _ctrl_c_deliverable() -> None:
    """Popen preexec: SIGINT back to its default. A test run started in the background of a
    non-interactive shell (``pytest &``, CI scripts) inherits SIGINT *ignored*; Python then
    installs no KeyboardInterrupt handler in the child and a Ctrl-C test waits forever."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _strict_json(path: Path) -> dict:
    def refuse(name):
        raise ValueError(f"{path} holds {name}: not JSON")
    return json.loads(path.read_text(), parse_constant=refuse)


class _Faulty:
    """Wraps a controller; by the scenario's seed: 3 = user error at reset, 7 = exception at
    step 2, 11 = NaN command from step 2."""

    def __init__(self, inner):
        self.inner, self.fault = inner, None

    def reset(self, scenario):
        if scenario.seed == 3:
            raise ConfigError("injected user error (seed 3)")
        self.fault = {7: "exception", 11: "nan"}.get(scenario.seed)
        self.inner.reset(scenario)

    def step(self, obs):
        command = self.inner.step(obs)
        if obs.step >= 2 and self.fault == "exception":
            raise RuntimeError("injected exception (seed 7)")
        if obs.step >= 2 and self.fault == "nan":
            return Command(qdd=np.full_like(command.qdd, np.nan), scalars=command.scalars)
        return command


def _multirun(tmp_path, monkeypatch, *overrides) -> int:
    from tamedpuma.app import sweep

    GlobalHydra.instance().clear()
    argv = ["-m", "method=joint_attractor", "scenario=free", "scenario.max_steps=6",
            "recorder=mcap", f"output_root={tmp_path}", f"hydra.sweep.dir={tmp_path}/sweep",
            "hydra.sweep.subdir=${seed}", *overrides]
    monkeypatch.setattr(sys, "argv", ["tamedpuma.sweep", *argv])
    with pytest.raises(SystemExit) as exit_:
        sweep.main(argv)
    GlobalHydra.instance().clear()
    return exit_.value.code


def test_a_20_run_sweep_with_3_injected_failures_completes_the_other_17(tmp_path, monkeypatch,
                                                                         capsys):
    from tamedpuma import methods

    real_make = methods.make
    with monkeypatch.context() as patch:
        patch.setattr(methods, "make", lambda name, cfg, kin: _Faulty(real_make(name, cfg, kin)))
        code = _multirun(tmp_path, patch, "seed=range(0,20)")
    out = capsys.readouterr()
    assert code == 1
    assert "sweep: 20 runs: 17 executed and complete, 0 skipped (already complete), 3 failed" \
        in out.out
    summaries = {int(p.parent.name): _strict_json(p)
                 for p in (tmp_path / "sweep").glob("*/summary.json")}
    assert sorted(summaries) == list(range(20))
    assert summaries[3]["status"] == "failed" and summaries[3]["failure"] == "user_error"
    assert "injected user error" in summaries[3]["reason"]
    assert summaries[7]["status"] == "failed" and summaries[7]["failure"] == "exception"
    assert "RuntimeError" in (tmp_path / "sweep/7/failure.txt").read_text()
    assert summaries[11]["stop_reason"] == "nonfinite_command"
    good = [s for k, s in summaries.items() if k not in (3, 7, 11)]
    assert len(good) == 17 and all(s["status"] == "complete" and s["steps"] == 6 for s in good)
    for seed in (3, 7, 11):
        assert f"/sweep/{seed}:" in out.out  # each failure listed at the end

    # the same sweep again (no faults): only the two failed runs run again
    code = _multirun(tmp_path, monkeypatch, "seed=range(0,20)")
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "sweep: 20 runs: 2 executed and complete, 18 skipped (already complete), 0 failed" \
        in out.out
    assert _strict_json(tmp_path / "sweep/7/summary.json")["status"] == "complete"
    assert (tmp_path / "sweep/7/previous_attempt/failure.txt").is_file()


def test_a_pybullet_disconnect_is_that_runs_failure_and_a_full_disk_stops_the_sweep(
        tmp_path, monkeypatch, capsys):
    import pybullet as pb

    from tamedpuma.recording.mcap_writer import McapRecorder
    from tamedpuma.worlds.bullet import Simulator

    real_step, real_write = Simulator.step, McapRecorder.write

    def step(self, qdd):
        if self._scenario.seed == 0 and self._scenario is not None:
            pb.disconnect(self._client)
        return real_step(self, qdd)

    def write(self, record):
        if record.step == 3 and self.path.parent.name == "1":
            raise OSError(28, "No space left on device")
        return real_write(self, record)

    with monkeypatch.context() as patch:
        patch.setattr(Simulator, "step", step)
        patch.setattr(McapRecorder, "write", write)
        code = _multirun(tmp_path, patch, "seed=0,1,2")
    out = capsys.readouterr()
    assert code == 2  # every later run would fail alike on a full disk: the sweep stops there
    assert "2 runs: 0 executed and complete, 0 skipped (already complete), 2 failed" in out.out
    assert "physics server" in _strict_json(tmp_path / "sweep/0/summary.json")["reason"].lower()
    assert out.err.strip().splitlines()[-1].startswith("error: disk full: cannot write ")
    assert not (tmp_path / "sweep/1/summary.json").exists()  # incomplete: a resume reruns it
    assert not (tmp_path / "sweep/2").exists()


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float) -> None:
    """Until ``path`` exists, ``proc`` ends or ``timeout`` [s] passes."""
    deadline = time.monotonic() + timeout
    while not path.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)


def _start_sweep(tmp_path, *extra):
    cmd = [sys.executable, "-m", "tamedpuma.sweep", "-m", "method=joint_attractor", "seed=0,1",
           "scenario.max_steps=100000", "stop_on_success=false", "recorder=mcap",
           f"output_root={tmp_path}", f"hydra.sweep.dir={tmp_path}/sweep",
           "hydra.sweep.subdir=${seed}", *extra]
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=ENV, preexec_fn=_ctrl_c_deliverable,
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    active = tmp_path / "sweep/0/episode.mcap.active"
    _wait_for(active, proc, 60)
    assert active.exists(), proc.communicate()[1] if proc.poll() is not None else "timeout"
    time.sleep(0.5)  # some steps written
    return proc


@pytest.mark.parametrize("sig,status", [(signal.SIGTERM, 143), (signal.SIGINT, 130),
                                        (signal.SIGKILL, -9)],
                         ids=["SIGTERM", "Ctrl-C", "SIGKILL"])
def test_a_killed_worker_leaves_its_partial_log_and_the_sweep_resumes(tmp_path, sig, status):
    proc = _start_sweep(tmp_path)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status
    lines = [x for x in err.splitlines() if x.strip() and not x.startswith("pybullet build")]
    if sig != signal.SIGKILL:
        assert lines[-1].startswith("interrupted: partial log (incomplete) in "), err
        assert "Traceback" not in err
        assert "/sweep/0/episode.mcap" in lines[-1]
    logs = list((tmp_path / "sweep/0").glob("episode.mcap*"))
    assert logs, "the partial log is kept"
    from tamedpuma.recording import read_mcap

    partial = read_mcap(logs[0])
    assert not partial.complete and len(partial.scalars) > 0
    # the same sweep, shorter: the interrupted run is run again, its partial log kept aside
    again = subprocess.run(
        [sys.executable, "-m", "tamedpuma.sweep", "-m", "method=joint_attractor", "seed=0,1",
         "scenario.max_steps=5", "recorder=mcap", f"output_root={tmp_path}",
         f"hydra.sweep.dir={tmp_path}/sweep", "hydra.sweep.subdir=${seed}"],
        cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    assert "sweep: 2 runs: 2 executed and complete" in again.stdout
    assert list((tmp_path / "sweep/0/previous_attempt").glob("episode.mcap*"))
    assert _strict_json(tmp_path / "sweep/0/summary.json")["steps"] == 5
    from tamedpuma.analysis.runs import find_logs

    runs = find_logs(tmp_path / "sweep")  # the set-aside attempt is kept, but is not a run
    assert len(runs) == 2 and all(read_mcap(p).complete for p in runs), runs


def _workers_of(sweep_dir: Path) -> list[int]:
    """Pids of live processes whose working directory is ``sweep_dir``'s parent and whose
    command line is a loky worker (Linux /proc)."""
    pids = []
    for proc in Path("/proc").iterdir():
        try:
            cmd = (proc / "cmdline").read_bytes().decode(errors="replace")
            if "loky" in cmd and Path(os.readlink(proc / "cwd")) == sweep_dir.parent:
                pids.append(int(proc.name))
        except (OSError, ValueError):
            continue
    return pids


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and prctl: Linux")
def test_a_sigkilled_parallel_sweep_leaves_no_worker_behind(tmp_path):
    """SIGKILL of the main process of a joblib sweep: its loky workers get SIGTERM from the
    kernel (parent-death signal), close every log (MCAP and Rerun) as incomplete and exit; the
    semaphores loky's resource tracker removes after it are not reported one by one."""
    proc = _start_sweep(tmp_path, "hydra/launcher=cores", "hydra.launcher.n_jobs=2",
                        "recorder=default")
    assert _workers_of(tmp_path / "sweep"), "the sweep runs in loky workers"
    _wait_for(tmp_path / "sweep/1/episode.mcap.active", proc, 60)
    time.sleep(0.5)
    proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=60)
    deadline = time.monotonic() + 30
    while _workers_of(tmp_path / "sweep") and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _workers_of(tmp_path / "sweep")
    from tamedpuma.recording import read_mcap

    for run in ("0", "1"):
        folder = tmp_path / "sweep" / run
        assert not list(folder.glob("*.active")), sorted(p.name for p in folder.iterdir())
        partial = read_mcap(folder / "episode.mcap")
        assert not partial.complete and len(partial.scalars) > 0
        assert (folder / "episode.rrd").is_file()
    assert "leaked" not in err, err[-2000:]


_WORKER_SIGTERM = """
import multiprocessing, os, signal, sys
multiprocessing.current_process().name = "LokyProcess-1"   # as in a launcher's worker
from tamedpuma.app import sweep
sweep._die_with_launcher()
try:   # the worker loop of a launcher catches everything a job raises
    try:
        {where}
    finally:
        print("unwound", flush=True)
except BaseException as exc:
    print("caught", type(exc).__name__, flush=True)
    sweep._exit_if_terminated()
print("worker still alive")
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="launcher workers: Linux")
@pytest.mark.parametrize("run_open", [False, True], ids=["setting-up", "mid-run"])
def test_a_sigterm_anywhere_in_a_workers_job_ends_the_worker(run_open):
    """SIGTERM reaching a loky worker while its job is still setting up: raised into the worker
    loop, the SystemExit would be sent back as a result and the worker would wait for work for
    ever. With no run open the worker leaves at once; mid-run, SystemExit unwinds the run (its
    logs close) and the worker leaves after."""
    where = ("sweep._RUN_OPEN.append(True); " if run_open else "") + \
        "os.kill(os.getpid(), signal.SIGTERM)"
    proc = subprocess.run([sys.executable, "-c", _WORKER_SIGTERM.format(where=where)],
                          env=ENV, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 143, (proc.stdout, proc.stderr)
    assert "worker still alive" not in proc.stdout
    if run_open:
        assert proc.stdout.split() == ["unwound", "caught", "SystemExit"], proc.stdout
    else:
        assert proc.stdout == "", proc.stdout


def test_analysis_lists_and_excludes_incomplete_truncated_and_failed_runs(tmp_path, capsys):
    from tamedpuma.analysis import tables

    proc = subprocess.run(
        [sys.executable, "-m", "tamedpuma.sweep", "-m", "method=joint_attractor", "seed=0,1",
         "scenario.max_steps=300", "stop_on_success=false", "recorder=default",
         "recorder.flush_every=20", f"output_root={tmp_path}",
         f"hydra.sweep.dir={tmp_path}/runs", "hydra.sweep.subdir=${seed}"],
        cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    runs = tmp_path / "runs"
    # a truncated copy of run 1 (MCAP and RRD cut in half), and a failed run's folder
    shutil.copytree(runs / "1", runs / "1_truncated")
    for name in ("episode.mcap", "episode.rrd"):
        path = runs / "1_truncated" / name
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    (runs / "2").mkdir()
    (runs / "2/summary.json").write_text(json.dumps({"status": "failed", "reason": "boom"}))
    (runs / "3").mkdir()
    (runs / "3/episode.mcap").write_bytes(b"not an mcap file")

    assert tables.main([str(runs)]) == 0
    out = capsys.readouterr().out
    assert "runs: 2 complete, 1 incomplete (excluded from the rates), 1 failed, 1 unreadable" \
        in out
    assert "incomplete: " in out and "1_truncated" in out and "failed: " in out
    assert tables.main([str(runs), "--include-incomplete"]) == 0
    assert "1 incomplete (included in the rates)" in capsys.readouterr().out

    from tamedpuma.errors import TamedPumaError
    from tamedpuma.recording import read_rrd_scalars

    try:  # a truncated .rrd: readable up to the cut, or one clear error
        read_rrd_scalars(runs / "1_truncated/episode.rrd")
    except TamedPumaError as exc:
        assert str(exc)


# ----------------------------------------------------------------------------- training


def _train(out_dir, *extra, timeout=120):
    return subprocess.run(
        [sys.executable, "-m", "tamedpuma.train", "puma=tiny", f"out_dir={out_dir}",
         "progress=false", "evaluate=false", *extra],
        cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=timeout)


def _one_line_error(proc) -> str:
    lines = [x for x in proc.stderr.splitlines() if not x.startswith("pybullet build")]
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), \
        proc.stderr
    return lines[0]


def test_a_second_training_into_the_same_folder_refuses_to_overwrite(tmp_path):
    (tmp_path / "puma.pt").write_bytes(b"a good model")
    line = _one_line_error(_train(tmp_path))
    assert "puma.pt exists: pass overwrite=true" in line
    assert (tmp_path / "puma.pt").read_bytes() == b"a good model"


def test_an_unwritable_output_is_refused_before_training(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    line = _one_line_error(_train(blocker / "sub"))
    assert "is not writable" in line


@pytest.mark.parametrize("override", ["puma.train.iterations=0", "puma.train.lr=abc",
                                      "+puma.train.iteration=5", "save_every=-1"])
def test_bad_training_settings_are_refused_up_front(tmp_path, override):
    line = _one_line_error(_train(tmp_path, override))
    assert override.lstrip("+").split("=")[0].split(".")[-1] in line
    assert not list(tmp_path.iterdir())


def test_a_killed_training_resumes_from_its_last_save(tmp_path):
    settings = ("puma.train.iterations=20", "save_every=4", "seed=3")
    full = _train(tmp_path / "full", *settings)
    assert full.returncode == 0, full.stderr
    cmd = [sys.executable, "-m", "tamedpuma.train", "puma=tiny", f"out_dir={tmp_path / 'cut'}",
           "progress=false", "evaluate=false", *settings]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=ENV, preexec_fn=_ctrl_c_deliverable,
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    state = tmp_path / "cut/train_state.pt"
    _wait_for(state, proc, 120)
    proc.kill()
    proc.communicate()
    assert state.exists() and not (tmp_path / "cut/puma.pt").exists()
    resumed = _train(tmp_path / "cut", *settings)
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming from iteration " in resumed.stderr
    assert not state.exists()  # removed once the checkpoint is written
    a = torch.load(tmp_path / "full/puma.pt", weights_only=False)["state_dict"]
    b = torch.load(tmp_path / "cut/puma.pt", weights_only=False)["state_dict"]
    assert a.keys() == b.keys()
    assert all(torch.equal(a[k], b[k]) for k in a), "resumed training differs from uninterrupted"


@pytest.mark.parametrize("sig,status", [(signal.SIGTERM, 143), (signal.SIGINT, 130)],
                         ids=["SIGTERM", "Ctrl-C"])
def test_an_interrupted_training_says_where_its_resumable_state_is(tmp_path, sig, status):
    cmd = [sys.executable, "-m", "tamedpuma.train", "puma=tiny", f"out_dir={tmp_path}",
           "progress=false", "evaluate=false", "puma.train.iterations=100000", "save_every=2"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=ENV, preexec_fn=_ctrl_c_deliverable,
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    state = tmp_path / "train_state.pt"
    _wait_for(state, proc, 120)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == (
        f"interrupted: the training's last save is {state} (every 2 iterations); run the same "
        "command again to resume from it")


@pytest.mark.parametrize("group", ["scenario", "task", "method", "robot"])
def test_an_unknown_option_lists_every_option_of_its_group(group, capsys):
    """``scenario=nope`` (and task, method, robot): one line, status 2, naming every option of
    the group, nested ones included (``tomato/00`` ... ``pouring/14``, ``random``)."""
    from tamedpuma.app import sweep
    from tamedpuma.app.config import CONF_DIR

    GlobalHydra.instance().clear()
    with pytest.raises(SystemExit) as exit_:
        sweep.main([f"{group}=nope"])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in err and err.startswith("error: ")
    listed = err.split(f"Available options in '{group}': ")[1].split(", ")
    folder = CONF_DIR / group
    every = {p.relative_to(folder).with_suffix("").as_posix() for p in folder.rglob("*.yaml")}
    if group == "method":  # an installed method plugin's config folder adds its own
        from tamedpuma import methods

        every |= set(methods.plugins())
    assert listed == sorted(every)
    if group == "scenario":
        assert {"tomato/00", "tomato/14", "pouring/00", "pouring/14", "random",
                "from_demos"} <= set(listed)


def test_an_unknown_training_option_lists_every_option_and_a_wrong_type_says_why(capsys):
    from tamedpuma.app import train

    GlobalHydra.instance().clear()
    assert train.main(["puma=nope"]) == 2
    err = capsys.readouterr().err.strip()
    from tamedpuma.app.config import CONF_DIR

    every = ", ".join(sorted(p.stem for p in (CONF_DIR / "puma").glob("*.yaml")))
    assert err == ("error: In 'train': Could not find 'puma/nope' Available options in 'puma': "
                   + every)
    assert "position, small, tiny" in every
    assert train.main(["puma.train.lr=abc"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "puma.train.lr=abc" in err and "could not be converted" in err


def test_the_end_of_sweep_counts_hold_when_jobs_run_in_other_processes(tmp_path):
    """Hydra's joblib launcher (``hydra/launcher=cores``) runs the jobs in worker processes: the
    main process still reports every run, from the outcomes the jobs wrote into the sweep
    folder; a run with a broken checkpoint (a user error) is that run's failure."""
    conf = tmp_path / "conf" / "method"
    conf.mkdir(parents=True)
    (tmp_path / "empty.pt").write_bytes(b"")
    (conf / "broken.yaml").write_text("defaults:\n  - fpm\n  - _self_\n"
                                      f"checkpoint: {tmp_path / 'empty.pt'}\n")
    cmd = [sys.executable, "-m", "tamedpuma.sweep", "-m", "--config-dir", str(tmp_path / "conf"),
           "hydra/launcher=cores", "hydra.launcher.n_jobs=2", "method=joint_attractor,broken",
           "scenario=free", "scenario.max_steps=6", "recorder=mcap", "seed=0,1",
           f"output_root={tmp_path}", f"hydra.sweep.dir={tmp_path}/sweep",
           "hydra.sweep.subdir=${hydra.job.num}"]
    proc = subprocess.run(cmd, cwd=tmp_path, env=ENV, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert ("sweep: 4 runs: 2 executed and complete, 0 skipped (already complete), 2 failed"
            in proc.stdout), proc.stdout[-2000:]
    failed = [ln for ln in proc.stdout.splitlines() if ln.startswith("  failed: ")]
    assert len(failed) == 2 and all("empty.pt: empty file (0 bytes)" in ln for ln in failed)
    again = subprocess.run(cmd, cwd=tmp_path, env=ENV, capture_output=True, text=True,
                           timeout=300)
    assert "sweep: 4 runs: 0 executed and complete, 2 skipped (already complete), 2 failed" \
        in again.stdout, again.stdout[-2000:]


def test_the_command_frame_turns_errors_and_ctrl_c_into_one_line(capsys):
    """train, lasa and body_model run inside cli.command: --help prints the doc; a user error is
    one line and status 2; Ctrl-C one line and status 130; any other exception is a bug and
    keeps its traceback."""
    from tamedpuma.app.cli import command

    def body(argv):
        raise {"user": ConfigError("bad value x"), "ctrl-c": KeyboardInterrupt(),
               "bug": RuntimeError("a bug")}[argv[0]]

    main = command("the doc")(body)
    assert main(["--help"]) == 0 and capsys.readouterr().out == "the doc\n"
    assert main(["user"]) == 2 and capsys.readouterr().err == "error: bad value x\n"
    assert main(["ctrl-c"]) == 130 and capsys.readouterr().err == "interrupted (Ctrl-C)\n"
    with pytest.raises(RuntimeError, match="a bug"):
        main(["bug"])
