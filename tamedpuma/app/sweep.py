"""``python -m tamedpuma.sweep [overrides]``: run configured episodes into ``runs/``.

One episode by default (``conf/sweep.yaml``); Hydra's multirun sweeps the groups, e.g.::

    python -m tamedpuma.sweep -m method=joint_attractor,fabrics task=tomato,pouring

Each run folder holds ``episode.mcap`` (Foxglove), ``episode.rrd`` (Rerun), ``summary.json`` and
Hydra's ``.hydra/`` (the resolved config and the overrides). The entry point is the only place
that imports Hydra; a user mistake (unknown option, malformed override, a value out of range,
unwritable output folder) prints one line ``error: ...`` on stderr and exits with status 2.

Inside a multirun (``-m``) a run's failure is that run's alone: a user error (e.g. a missing
checkpoint) or an exception is written to the run folder's ``summary.json`` (``"status":
"failed"``, the reason, and ``failure.txt`` with the traceback) and the sweep goes on; a
controller returning NaN/inf ends its episode with ``stop_reason: nonfinite_command``. At the end
the sweep prints how many runs completed, were skipped or failed, and exits with status 1 if any
failed. Re-running a sweep into existing folders (fixed ``hydra.sweep.subdir``, e.g. Table 1)
skips every run whose ``summary.json`` says complete and reruns the missing, incomplete and failed
ones (an interrupted attempt's files are kept in ``previous_attempt/``); it refuses to start when
a kept run's config now picks another trained model (both sha256 named: one sweep mixes no
models) and warns about kept runs of another code revision (:func:`resume_check`).

A full disk is not one run's failure: every later run would fail alike, so the sweep stops with
its counts so far and one line naming the file, the bytes free and the bytes needed (status 2);
the logs written so far keep their ``.active`` names (readable, incomplete).
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import json
import logging
import math
import multiprocessing
import os
import shutil
import signal
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.plugins.sweeper import Sweeper
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from tamedpuma import termination
from tamedpuma.app import callbacks, config_text
from tamedpuma.app.cli import fail, precheck_overrides, shell_completion, with_plugin_configs
from tamedpuma.app.config import CONF_DIR
from tamedpuma.app.provenance import machine
from tamedpuma.errors import ConfigError, DiskFullError, TamedPumaError
from tamedpuma.paths import SET_ASIDE, free_bytes, no_space, write_atomic
from tamedpuma.runlog import SUMMARY_SCHEMA_VERSION

log = logging.getLogger("tamedpuma.sweep")
_VALIDATE_EVERY_JOB = Sweeper.validate_batch_is_legal  # Hydra's (see representative_jobs)


@dataclass(frozen=True)
class Built:
    """Everything one episode needs, built from the config before anything runs."""

    run: object          # the typed config (tamedpuma.app.schema.RunConfig)
    spec: object
    scenario: object
    controller: object
    sim_config: object
    disturbance: object
    model: object = None  # the trained model the method uses (store.ModelChoice) or None


def build(cfg: DictConfig) -> Built:
    """Config -> typed config (:func:`tamedpuma.app.schema.run_config`: types, unknown keys and
    ranges checked) -> robot, scenario, controller, simulator settings. Any invalid value becomes
    a :class:`ConfigError` with a one-line message."""
    from tamedpuma import methods
    from tamedpuma.app.schema import method_settings, run_config
    from tamedpuma.puma import store

    run = run_config(cfg)
    try:
        spec, kinematics, scenario = _world(cfg, run)
        settings = with_robot_null_space(method_settings(run.method), run.robot.null_space)
        model = store.resolve_for_method(run.method.name, settings)
        if model is not None:  # the method loads exactly the file that is recorded
            settings = dataclasses.replace(settings, checkpoint=str(model.path))
        controller = methods.make(run.method.name, settings, kinematics)
        sim_config, disturbance = run.sim, run.disturbance
        for line in run_warnings(run.task.name, scenario, kinematics, model):
            print(f"warning: {line}", file=sys.stderr)
    except TamedPumaError:
        raise
    except (ValueError, TypeError, KeyError) as exc:
        raise ConfigError(f"invalid configuration: {type(exc).__name__}: {exc}") from exc
    return Built(run, spec, scenario, controller, sim_config, disturbance, model)


def _world(cfg: DictConfig, run) -> tuple:
    """(robot spec, kinematics, scenario) of the typed run config ``run`` (``cfg``: the same,
    untyped, for a clutter's reference run)."""
    from tamedpuma.app.config import table1_starts
    from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config
    from tamedpuma.worlds import demo_scenarios
    from tamedpuma.worlds.scenarios import build_scenario

    spec = robot_spec_from_config(run.robot)
    kinematics = Kinematics(spec)
    # derived goal, generated scenario; a task without Table-1 starts: its demonstrations'
    world, demo_starts = demo_scenarios.apply(run, kinematics)

    def reference():  # clutter.keep_clear=path: the collision-free run to keep clear of
        from tamedpuma.app.reference import reference_motion

        return reference_motion(cfg, build)

    def starts(task: str) -> list:  # scenario=random, start_kind=near_table1
        return table1_starts(task) or demo_starts

    return spec, kinematics, build_scenario(world, spec, kinematics, reference, starts)


def world_of(cfg: DictConfig) -> tuple:
    """(robot spec, kinematics, scenario) a run of ``cfg`` builds, without its controller (the
    analyses that judge a scenario apart from the method). Config errors as :func:`build`."""
    from tamedpuma.app.schema import run_config

    run = run_config(cfg)
    try:
        return _world(cfg, run)
    except TamedPumaError:
        raise
    except (ValueError, TypeError, KeyError) as exc:
        raise ConfigError(f"invalid configuration: {type(exc).__name__}: {exc}") from exc


def with_robot_null_space(settings, robot_null_space):
    """``settings`` with the robot config's "elbow up" link and target in place of the method's
    (iiwa) ones, where both have one (``robot.null_space``, ``method.null_space``)."""
    own = getattr(settings, "null_space", None)
    if robot_null_space is None or not dataclasses.is_dataclass(own):
        return settings
    return dataclasses.replace(settings, null_space=dataclasses.replace(
        own, link=robot_null_space.link, target=list(robot_null_space.target)))


def run_warnings(task: str, scenario, kinematics, model) -> list[str]:
    """What makes a run pointless although its config is valid: a goal beyond the arm's reach
    (:func:`tamedpuma.worlds.scenarios.reach_problem`), a model trained on another task than
    the run's (its folder's manifest or report names the task)."""
    from tamedpuma.puma import store
    from tamedpuma.worlds.scenarios import reach_problem

    out = [p for p in [reach_problem(scenario, kinematics)] if p]
    if model is not None:
        manifest = store.read_manifest(Path(model.path).parent) or {}
        trained = manifest.get("task")
        if not isinstance(trained, str):
            trained = ((manifest.get("config") or {}).get("task") or {}).get("name")
        if isinstance(trained, str) and trained != task:
            out.append(f"the model {model.path} was trained on task {trained}, this run is "
                       f"task {task}")
    return out


EPISODE_FILES = ("episode.mcap", "episode.rrd", "summary.json", "failure.txt")


def _finite_json(value):
    """``value`` with every NaN/±inf float replaced by None (strict JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_json(v) for v in value]
    return value


def write_summary(run_dir: Path, summary: dict) -> Path:
    """``run_dir/summary.json``: strict JSON (non-finite numbers as null), written atomically
    (a full disk leaves no partial file and raises :class:`DiskFullError`)."""
    text = json.dumps(_finite_json(summary), indent=2, allow_nan=False) + "\n"
    return write_atomic(run_dir / "summary.json", text.encode())


def run_one(cfg: DictConfig, run_dir: Path) -> dict:
    """Config -> scenario -> controller -> simulator -> recorders -> files. Returns the summary."""
    from tamedpuma.episode import RestTest, run_episode
    from tamedpuma.recording import make_recorders, recorder_files
    from tamedpuma.records import RunInfo
    from tamedpuma.worlds.bullet import Simulator

    t_start = time.perf_counter()
    built = build(cfg)
    t_built = time.perf_counter()
    run, spec, scenario = built.run, built.spec, built.scenario
    kinds = [k for k in ("mcap", "rerun") if getattr(run.recorder, k)]
    recorders = make_recorders(kinds, run_dir, flush_every=run.recorder.flush_every)
    files = recorder_files(kinds, run_dir)
    info = RunInfo(run_id=run_dir.name, method=run.method.name, task=run.task.name,
                   scenario_name=scenario.name, seed=run.seed,
                   config_yaml=config_text.to_yaml(cfg, resolve=True), urdf_path=spec.urdf_path,
                   joint_names=spec.joint_names, link_names=spec.link_names,
                   body_sphere_radii=spec.sphere_radii, dt=scenario.dt,
                   velocity_limits=spec.qd_max,
                   model=built.model.metadata() if built.model else {})
    with Simulator(spec, built.sim_config, built.disturbance) as sim:
        try:
            result = run_episode(scenario, built.controller, sim, recorders, info,
                                 stop_on_success=run.stop_on_success,
                                 settle_time=run.settle_time,
                                 rest=RestTest(run.rest_window, run.rest_distance, run.rest_angle))
        except DiskFullError as exc:  # the bytes a whole log needs at the rate written so far
            raise exc.for_steps(scenario.max_steps) from exc
    t_episode = time.perf_counter()
    summary = {"status": "complete", "run_dir": str(run_dir), "method": run.method.name,
               "method_label": run.method.label or run.method.name, "task": run.task.name,
               "scenario": scenario.name, "seed": run.seed,
               "n_obstacles": len(scenario.obstacles),
               "disturbance": built.disturbance.name or built.disturbance.kind,
               "control": built.sim_config.control,
               "stop_reason": result.stop_reason, **result.metrics.as_dict(),
               "files": {k: str(v) for k, v in files.items()},
               "model": built.model.metadata() if built.model else None,
               "code_revision": code_revision(),
               "schema_version": SUMMARY_SCHEMA_VERSION,
               "suite": ({"name": run.suite.name, "version": run.suite.version}
                         if run.suite.name else None),
               "machine": machine(),
               # every step's controller time [ms] (pooled statistics across runs): wall, and
               # its thread's CPU time (the step's own work, without preemption)
               "step_compute_ms": [round(float(v), 5) for v in result.compute_ms],
               "step_compute_cpu_ms": [round(float(v), 5) for v in result.compute_cpu_ms],
               # where this process's time went [s, wall]: building config, model, scenario and
               # controller; the simulator's set-up and the episode with its recorders, and of
               # it the simulator's steps (physics and observation) (informational: not part
               # of any result, varies with the machine's load)
               "wall_s": {"build": round(t_built - t_start, 4),
                          "episode": round(t_episode - t_built, 4),
                          "simulator": round(result.simulator_s, 4)}}
    write_summary(run_dir, summary)
    return summary


@functools.cache
def code_revision() -> str:
    """The code revision this process runs (``git describe``, else the package version)."""
    from tamedpuma.app.models import code_revision as describe

    return describe()


def _kept_model(run_dir: Path, models: dict):
    """The model the kept run ``run_dir``'s config picks now (None: no model, or a config
    the current schema no longer reads); ``models`` caches it by the method config."""
    try:
        return _model_for(OmegaConf.load(run_dir / ".hydra" / "config.yaml"), models)
    except Exception:  # noqa: BLE001 - unreadable or no longer valid: not comparable
        return None


def _model_for(cfg: DictConfig, models: dict):
    """The trained model a run of ``cfg`` loads (None: its method loads none); ``models``
    caches it by the method config. Raises for a config the schema does not read."""
    from tamedpuma.app.schema import method_settings, run_config
    from tamedpuma.puma import store

    key = json.dumps(OmegaConf.to_container(cfg.method, resolve=True), sort_keys=True,
                     default=str)
    if key not in models:
        method = run_config(cfg).method
        models[key] = store.resolve_for_method(method.name, method_settings(method))
    return models[key]


_KEPT = {}  # sweep folder -> {(method label, task): {sha256: run folder}} of its complete runs
_JOB_MODELS = {}  # the models jobs load, by method config (see _model_for)


def _kept_models(sweep_dir: Path) -> dict:
    """The models of the complete runs in ``sweep_dir`` by (method label, task), read once per
    sweep (at its first job: the runs a resume keeps)."""
    key = str(sweep_dir)
    if key not in _KEPT:
        kept = _KEPT[key] = {}
        for path in sorted(sweep_dir.glob("*/summary.json")):
            try:
                summary = json.loads(path.read_text())
                sha = summary["model"]["model_sha256"]
            except (OSError, ValueError, KeyError, TypeError):
                continue
            if summary.get("status", "complete") == "complete" and sha:
                group = (summary.get("method_label"), summary.get("task"))
                kept.setdefault(group, {}).setdefault(sha, path.parent)
    return _KEPT[key]


def model_mix(cfg: DictConfig, run_dir: Path) -> str | None:
    """The refusal of a job whose method loads another model than the complete runs of the
    same method label and task that its sweep folder keeps (a resume with another
    ``method.checkpoint``, or after a ``models build`` for a config :func:`resume_check` does
    not see), else None: its table row would pool two models."""
    kept = _kept_models(run_dir.parent).get((method_label(cfg.method), cfg.task.name))
    if not kept:
        return None
    try:
        new = _model_for(cfg, _JOB_MODELS)
    except Exception:  # noqa: BLE001 - the run itself reports a config it cannot build
        return None
    other = next(((sha, d) for sha, d in kept.items() if new is not None and sha != new.sha256),
                 None)
    if other is None:
        return None
    return (f"resume refused: {other[1]} kept a run of model sha256 {other[0][:12]}, "
            f"the job {run_dir} picks sha256 {new.sha256[:12]} ({new.path}); one sweep "
            "mixes no models: resume into a new folder (hydra.sweep.dir=...) or move the kept "
            "runs away")


def resume_check(sweep_dir: Path) -> tuple[str | None, list[str]]:
    """Before a sweep runs into ``sweep_dir``, compare the complete runs it will keep with
    what the same configs use now: ``(refusal, warnings)``. A kept run whose method would
    now load another trained model (a ``models build`` finished in between) refuses the
    resume, naming both sha256: its table row would pool two models. Runs of another code
    revision are a warning (the revision of every run is in its ``summary.json``)."""
    models, revisions, kept = {}, {}, 0
    for path in sorted(Path(sweep_dir).glob("*/summary.json")):
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(summary, dict) or summary.get("status", "complete") != "complete":
            continue
        kept += 1
        old = (summary.get("model") or {}).get("model_sha256")
        new = _kept_model(path.parent, models) if old else None
        if new is not None and new.sha256 != old:
            return (f"resume refused: {path.parent} kept a run of model sha256 {old[:12]}, "
                    f"its config now picks sha256 {new.sha256[:12]} ({new.path}); one sweep "
                    "mixes no models: resume into a new folder (hydra.sweep.dir=...) or move "
                    "the kept runs away", [])
        rev = summary.get("code_revision")
        if rev:
            revisions[rev] = revisions.get(rev, 0) + 1
    now = code_revision()
    warnings = [f"warning: {n} of the {kept} kept complete runs were made at code revision "
                f"{rev}, this is {now}" for rev, n in revisions.items() if rev != now]
    return None, warnings


def method_label(method_cfg) -> str:
    """The name a method's runs carry in tables: ``label`` if the method config sets one (e.g.
    ``cpm_literal``), else its ``name``."""
    return str(method_cfg.get("label") or method_cfg.name)


def run_state(run_dir: Path) -> str:
    """'complete' (its summary.json says so), 'failed', 'incomplete' (files but no complete
    summary: killed or interrupted) or 'missing'."""
    path = run_dir / "summary.json"
    if path.is_file():
        try:
            status = json.loads(path.read_text()).get("status", "complete")
        except (OSError, ValueError):
            return "incomplete"
        return "complete" if status == "complete" else "failed"
    if any((run_dir / name).exists() or (run_dir / f"{name}.active").exists()
           for name in EPISODE_FILES):
        return "incomplete"
    return "missing"


def _set_aside(run_dir: Path) -> None:
    """Move an earlier attempt's files into ``run_dir/previous_attempt/`` (replacing an older
    one), so a rerun writes fresh files and nothing recorded is deleted."""
    old = [p for name in EPISODE_FILES for p in (run_dir / name, run_dir / f"{name}.active")
           if p.exists()]
    if not old:
        return
    keep = run_dir / SET_ASIDE
    shutil.rmtree(keep, ignore_errors=True)
    keep.mkdir()
    for p in old:
        p.replace(keep / p.name)


def record_failure(cfg: DictConfig, run_dir: Path, exc: BaseException) -> dict:
    """Write a failed run's ``summary.json`` (status, reason) and ``failure.txt`` (traceback)."""
    user_error = isinstance(exc, TamedPumaError)
    reason = " ".join(str(exc).split()) or type(exc).__name__
    summary = {"status": "failed", "failure": "user_error" if user_error else "exception",
               "error_type": type(exc).__name__, "reason": reason, "run_dir": str(run_dir),
               "method": OmegaConf.select(cfg, "method.name", default=None),
               "method_label": OmegaConf.select(cfg, "method.label", default=None)
               or OmegaConf.select(cfg, "method.name", default=None),
               "task": OmegaConf.select(cfg, "task.name", default=None),
               "scenario": OmegaConf.select(cfg, "scenario.name", default=None),
               "seed": OmegaConf.select(cfg, "seed", default=None)}
    summary["recorded"] = True
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        write_atomic(run_dir / "failure.txt", "".join(
            traceback.format_exception(type(exc), exc, exc.__traceback__)).encode())
        write_summary(run_dir, summary)
    except (OSError, TamedPumaError) as write_error:  # the failure could not be recorded
        summary["recorded"] = False
        print(f"error: cannot record the failure in {run_dir}: "
              f"{' '.join(str(write_error).split())}", file=sys.stderr)
    return summary


#: outcome of each job of the last multirun: (run_dir, 'complete'|'skipped'|'failed', why), read
#: by the main process at the end of the sweep from the sweep folder's OUTCOMES_FILE (the jobs may
#: run in other processes: Hydra's joblib launcher)
_OUTCOMES: list[tuple[str, str, str]] = []
#: (outcomes file, offset) of the running multirun, set by the callback at its start: the
#: outcomes of a sweep stopped before its end are read from there
_OUTCOMES_SOURCE: list = []
#: one JSON line per job ({"run_dir", "outcome", "why"}), appended by the job (O_APPEND: lines of
#: concurrent jobs do not mix)
OUTCOMES_FILE = "sweep_outcomes.jsonl"


def _record_outcome(run_dir: Path, outcome: str, why: str = "") -> None:
    """Append this job's outcome to its sweep folder's :data:`OUTCOMES_FILE`."""
    path = Path(HydraConfig.get().sweep.dir) / OUTCOMES_FILE
    line = json.dumps({"run_dir": str(run_dir), "outcome": outcome, "why": why}) + "\n"
    try:
        with open(path, "a", encoding="utf-8") as fh:
            fh.write(line)
    except OSError as exc:  # the run's own summary.json still says what happened
        print(f"error: cannot record the outcome in {path}: {exc}", file=sys.stderr)


def outcomes_since(path: Path, offset: int) -> list[tuple[str, str, str]]:
    """The outcomes appended to ``path`` after byte ``offset`` (this sweep's jobs)."""
    try:
        with open(path, "rb") as fh:
            fh.seek(offset)
            lines = fh.read().decode("utf-8", errors="replace").splitlines()
    except OSError:
        return []
    out = []
    for line in lines:
        try:
            o = json.loads(line)
            out.append((str(o["run_dir"]), str(o["outcome"]), str(o.get("why", ""))))
        except (ValueError, KeyError, TypeError):
            continue  # a line cut by a killed job
    return out


def _report(summary: dict) -> None:
    m = summary
    # whole-body success implies paper success (a superset of the same conditions)
    if m["success_whole_body"]:
        outcome = "success"
    elif m["success_paper"]:
        outcome = f"success under the paper criterion only [{m['failure_whole_body']}]"
    else:
        outcome = f"no success [{m['failure_whole_body']}]"
    tts = m.get("time_to_success_s")
    episode = f"episode {m['steps']} steps, {m['duration_s']:.2f} s"
    if isinstance(tts, (int, float)) and math.isfinite(tts):  # the settle time comes after
        episode = f"goal reached at {tts:.2f} s; {episode} with the settle time"
    print(f"{m['method_label']} on {m['task']}/{m['scenario']}: {outcome} ({episode}), "
          f"final position error {m['final_position_error_m']:.4f} m, "
          f"min clearance {m['min_clearance_m']:.3f} m, "
          f"controller {m['compute_ms_median']:.3f} ms (median)")
    if m.get("model"):
        mm = m["model"]
        print(f"model: {mm['model_origin']} {mm['model_path']} (sha256 "
              f"{mm['model_sha256'][:12]}, trained on {mm['model_data']} data "
              f"{mm['model_data_source']})")
    print(f"run folder: {m['run_dir']}")
    for kind, path in m["files"].items():
        print(f"  {kind}: {path}")
    print(f"  summary: {Path(m['run_dir']) / 'summary.json'}")
    if "rrd" in m["files"]:
        print(f"replay: rerun {m['files']['rrd']}")
    print(f"replay: python -m tamedpuma.replay {m['run_dir']}")


def _partial_log_line(run_dir: Path) -> str:
    """Where an interrupted run's partial logs are, or that it had not opened any yet."""
    files = sorted(str(p) for p in run_dir.glob("episode.*") if p.is_file())
    if not files:
        return f"interrupted before the run's logs were opened: nothing recorded in {run_dir}"
    hint = ("; recover an .mcap.active with tamedpuma.recording.recover_mcap"
            if any(f.endswith(".mcap.active") for f in files) else "")
    return f"interrupted: partial log (incomplete) in {', '.join(files)}{hint}"


def _die_with_launcher() -> None:
    """In a launcher's worker process (Hydra's joblib launcher: loky workers), ask Linux to send
    SIGTERM when the launching process dies (``prctl(PR_SET_PDEATHSIG)``), handled as in the
    main process (the run's logs close as incomplete, exit 143). Without it a SIGKILLed sweep
    left its two loky workers behind, re-parented to init and spinning at ~50 % CPU each after
    their last run. No-op in the main process (single runs, submitit and Ray jobs) and off
    Linux."""
    if not sys.platform.startswith("linux"):
        return
    if multiprocessing.current_process().name == "MainProcess":
        return
    signal.signal(signal.SIGTERM, _terminated)
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - no prctl in this libc
        pass
    # a launcher that died before the prctl above sends no signal (prctl(2): the death signal
    # is armed for a parent still alive): a worker still starting then is already orphaned,
    # so it leaves now
    launcher = os.environ.get(_LAUNCHER_PID)
    if launcher and launcher.isdigit() and os.getppid() != int(launcher):
        _leave_worker()


_LAUNCHER_PID = "TAMEDPUMA_SWEEP_LAUNCHER_PID"  # set by main(), read by its launcher's workers
_TERMINATED = []  # set in a launcher worker by SIGTERM (its launcher died, or it was stopped)
_RUN_OPEN = []  # non-empty while a launcher worker's run has its logs open
_INTERRUPT_SAID = []  # set when a run of this process said where its partial logs are
#: what an interrupt of the main process outside a run says (nothing is half-written then)
_INTERRUPTED_BETWEEN = ("interrupted ({}) outside a run: the complete runs are kept; the same "
                        "command goes on from there")


def _terminated(*_) -> None:
    """SIGTERM in a launcher worker. During a run: unwind it (its logs close as incomplete),
    then exit. Anywhere else in the job (before the run opens its logs, after they closed):
    leave at once, there is nothing to close."""
    if _TERMINATED and _RUN_OPEN:  # a second SIGTERM while the run closes its logs: the
        return  # first one is unwinding it (cut short, the Rerun log stayed .active)
    _TERMINATED.append(True)
    termination.request(143)  # raised again at the next step if this exit is lost
    if not _RUN_OPEN:
        _leave_worker()
    sys.exit(143)


def _terminated_main(*_) -> None:
    """SIGTERM in the main process: unwind (a run's logs close as incomplete, exit 143); a
    repeated SIGTERM while that unwinding closes the logs is ignored (the main process's only
    termination request is this handler's, :func:`main` clears it at the start)."""
    if termination.requested():
        return
    termination.request(143)  # raised again at the next step if this exit is lost
    sys.exit(143)


def _leave_worker() -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(143)


def _exit_if_terminated() -> None:
    """After a SIGTERMed job has closed its logs, leave the worker process for good: raised
    into the launcher's worker loop, the SystemExit would be caught and sent back as a task
    result, and the loky worker, its launcher gone, would wait for more work for ever
    (re-parented to init), also when the SIGTERM reached it while its job was still setting
    up, before the run."""
    if _TERMINATED:
        _leave_worker()


@hydra.main(config_path=str(CONF_DIR), config_name="sweep", version_base="1.3")
def _hydra_main(cfg: DictConfig) -> None:
    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    # Hydra logs INFO to the console: torch's exit-time cache statistics are not the run's
    logging.getLogger("torch").setLevel(logging.WARNING)
    if hydra_cfg.mode != RunMode.MULTIRUN:
        _job(cfg, run_dir, multirun=False)
        return
    _die_with_launcher()
    try:
        _job(cfg, run_dir, multirun=True)
    finally:  # a SIGTERM anywhere in the job ends the worker, not just the job
        _exit_if_terminated()


def _job(cfg: DictConfig, run_dir: Path, multirun: bool) -> None:
    """One run of the sweep (or the single run): set aside a previous attempt, run, record."""
    if multirun:
        refusal = model_mix(cfg, run_dir)
        if refusal:
            raise SweepStopped(refusal)
        state = run_state(run_dir)
        if state == "complete":
            _record_outcome(run_dir, "skipped", "already complete")
            print(f"skipped (already complete): {run_dir}")
            return
        _set_aside(run_dir)
    _RUN_OPEN.append(True)
    try:
        summary = run_one(cfg, run_dir)
    except (KeyboardInterrupt, SystemExit) as exc:
        if isinstance(exc, SystemExit) and exc.code in (0, None):
            raise
        print(_partial_log_line(run_dir), file=sys.stderr)
        _INTERRUPT_SAID.append(True)
        raise
    except Exception as exc:  # noqa: BLE001 - a sweep survives its worst run
        if multirun and _TERMINATED:  # a SIGTERM mid-run that surfaced as another error (seen:
            # raised inside OmegaConf's validation, it left a ConfigError): not the run's fault
            print(_partial_log_line(run_dir), file=sys.stderr)
            return
        if not multirun:
            if isinstance(exc, TamedPumaError):
                fail(str(exc))
            raise
        if no_space(exc, run_dir):  # every later run would fail alike: the sweep stops
            if not isinstance(exc, DiskFullError):
                exc = DiskFullError(getattr(exc, "filename", None) or run_dir,
                                    free_bytes(run_dir))
            raise SweepStopped(str(exc), str(run_dir)) from exc
        failure = record_failure(cfg, run_dir, exc)
        _record_outcome(run_dir, "failed", failure["reason"])
        where = (f"recorded in {run_dir / 'summary.json'}" if failure["recorded"]
                 else "not recorded")
        print(f"error: run failed ({failure['failure']}): {failure['reason']} [{where}]",
              file=sys.stderr)
        return
    finally:
        _RUN_OPEN.clear()
    if multirun:
        _exit_if_terminated()  # SIGTERMed just after the run ended: leave the worker all the same
        failed = summary["stop_reason"] == "nonfinite_command"
        _record_outcome(run_dir, "failed" if failed else "complete",
                        "controller returned NaN/inf" if failed else "")
    _report(summary)


def representative_jobs(batch):
    """The jobs of a sweep batch that between them hold every override at least once [list].

    Hydra's sweeper composes every job's config in the launching process before the first run
    (``Sweeper.validate_batch_is_legal``), so that a job that cannot be composed stops the sweep
    early: about 0.15 s per job here, 5 min of the 2000-run randomized suite, 40 s of Table 1.
    A job fails to compose through one of its overrides (an unknown group option, a missing
    key), so composing the first job holding each override finds the same failures, in about
    as many composes as there are distinct overrides (37 of Table 1's 420 jobs). A failure that
    needs two overrides together is left to the run itself, which records it and lets the sweep
    go on (see the module docstring)."""
    seen, jobs = set(), []
    for job in batch:
        if not seen.issuperset(job):
            seen.update(job)
            jobs.append(job)
    return jobs


def _validate_representatives(sweeper, batch) -> None:
    _VALIDATE_EVERY_JOB(sweeper, representative_jobs(batch))


class SweepStopped(BaseException):
    """Ends a sweep at once, through Hydra's launcher (which reports an Exception with a
    traceback): a full disk, on which every later run would fail alike. ``main`` prints the
    counts so far and the message, and exits with status 2."""


_WRITE_CONFIG = config_text.save_config


def save_config_or_stop(cfg, filename: str, output_dir: Path) -> None:
    """Hydra's ``_save_config`` (a job's ``.hydra/*.yaml``, the sweep's ``multirun.yaml``),
    through :func:`tamedpuma.app.config_text.save_config` (the same text); a full disk removes
    the partial file and stops the sweep with one line. Installed in the launching process by
    :func:`main` and in the ``cores`` launcher's workers by its ``execute_job``."""
    try:
        _WRITE_CONFIG(cfg, filename, output_dir)
    except OSError as exc:
        path = Path(output_dir) / filename
        if not no_space(exc, path):
            raise
        path.unlink(missing_ok=True)
        raise SweepStopped(str(DiskFullError(path, free_bytes(path)))) from exc


def _sweep_report() -> int:
    """Print the multirun's counts and failed runs; 1 if any run failed, else 0."""
    counts = {k: sum(1 for o in _OUTCOMES if o[1] == k) for k in ("complete", "skipped", "failed")}
    n = len(_OUTCOMES)
    print(f"sweep: {n} run{'' if n == 1 else 's'}: {counts['complete']} executed and complete, "
          f"{counts['skipped']} skipped (already complete), {counts['failed']} failed")
    for run_dir, outcome, why in _OUTCOMES:
        if outcome == "failed":
            print(f"  failed: {run_dir}: {why}")
    return 1 if counts["failed"] else 0


#: Rerun's own log filter: its file sink's errors (a full disk) are reported by the recorder
#: as one line instead, see :meth:`tamedpuma.recording.RerunRecorder.close`
_RERUN_LOG = "warn,re_log_encoding::rrd=off,re_sdk::recording_stream=off"


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    os.environ.setdefault("RUST_LOG", _RERUN_LOG)  # read when rerun is first imported
    # a killed run (SIGTERM) unwinds normally, so recorders close their files as incomplete
    termination.clear()
    signal.signal(signal.SIGTERM, _terminated_main)
    # loky's resource tracker of a launcher killed with SIGKILL removes the semaphores it left
    # and warns about each: noise after the workers closed their logs (see _die_with_launcher)
    os.environ["PYTHONWARNINGS"] = ",".join(filter(None, [
        os.environ.get("PYTHONWARNINGS"),
        "ignore::UserWarning:joblib.externals.loky.backend.resource_tracker"]))
    os.environ[_LAUNCHER_PID] = str(os.getpid())  # inherited by the joblib launcher's workers
    shell_completion(argv, "tamedpuma.sweep")
    plugged = with_plugin_configs(argv)
    if plugged != list(argv):  # Hydra reads sys.argv: the plugins' config folders go there
        argv = sys.argv[1:] = plugged
    try:
        error = precheck_overrides("sweep", argv)
    except KeyboardInterrupt:
        print("interrupted (Ctrl-C) while checking the configuration: nothing was run",
              file=sys.stderr)
        sys.exit(130)
    except SystemExit as exc:
        if exc.code == 143:
            print("interrupted (SIGTERM) while checking the configuration: nothing was run",
                  file=sys.stderr)
        raise
    if termination.requested():  # a SIGTERM inside OmegaConf surfaces as a config error: not one
        print("interrupted (SIGTERM) while checking the configuration: nothing was run",
              file=sys.stderr)
        sys.exit(143)
    if error:
        fail(error)
    _OUTCOMES.clear()
    _INTERRUPT_SAID.clear()
    _KEPT.clear()
    callbacks.forget_progress()
    Sweeper.validate_batch_is_legal = _validate_representatives
    hydra.core.utils._save_config = save_config_or_stop
    try:
        _hydra_main()
    except KeyboardInterrupt:
        if not _INTERRUPT_SAID:  # else the run printed where its partial log is
            print(_INTERRUPTED_BETWEEN.format("Ctrl-C"), file=sys.stderr)
        sys.exit(130)
    except SystemExit as exc:
        if exc.code == 143 and not _INTERRUPT_SAID:
            print(_INTERRUPTED_BETWEEN.format("SIGTERM"), file=sys.stderr)
        raise
    except SweepStopped as stop:
        message, run_dir = (list(stop.args) + [""])[:2]
        if _OUTCOMES_SOURCE:  # the callback's end-of-sweep collection did not run
            _OUTCOMES[:] = outcomes_since(*_OUTCOMES_SOURCE)
            if run_dir:
                _OUTCOMES.append((run_dir, "failed", message))
            if _OUTCOMES:
                _sweep_report()
        fail(message)
    if _OUTCOMES:
        sys.exit(_sweep_report())


if __name__ == "__main__":
    main()
