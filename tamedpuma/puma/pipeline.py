"""Config dict → data → training → checkpoint → evaluation report (no Hydra here).

The entry points (``tamedpuma.train``, ``tamedpuma.lasa``) compose the config with Hydra and call
:func:`run`. Config keys: see ``conf/train.yaml``, ``conf/task/*.yaml`` and ``conf/puma/*.yaml``.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..paths import resolve, writable_problem, write_atomic
from . import checkpoint, data, demo_formats, demos_synthetic, evaluation, gates, task_from_demos
from .network import NetConfig, StateSpec
from .training import TrainConfig, Workspace, train


def _dataclass(cls, d: dict | None, where: str):
    d = dict(d or {})
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise ConfigError(f"unknown key(s) in {where}: {', '.join(unknown)} "
                          f"(known: {', '.join(sorted(names))})")
    try:
        return cls(**d)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"invalid {where}: {exc}") from None


def _require(cfg: dict, key: str, where: str):
    if key not in cfg or cfg[key] is None and key != "demos":
        raise ConfigError(f"missing config key {where}.{key}")
    return cfg[key]


def load_raws(task: dict, puma: dict) -> tuple[list[data.RawDemo], str, str]:
    """The task's raw demonstrations, their source and unit: synthetic (demos null), LASA (demos
    'lasa'), or a folder/file in any format of :mod:`tamedpuma.puma.demo_formats`."""
    name = _require(task, "name", "task")
    src = task.get("demos")
    if src is None and task.get("goal_position") is None:  # no data, no synthetic set's goal
        raise ConfigError("missing config key task.demos (a task from demonstrations needs "
                          "task.demos=PATH: a folder or file of demonstrations)")
    if src is None:
        syn = task["synthetic"]
        raws = demos_synthetic.generate(str(syn.get("kind") or name),
                                        _require(task, "goal_position", "task"),
                                        _require(task, "goal_quaternion", "task"),
                                        int(syn["n_demos"]), int(syn["seed"]),
                                        time_law=str(syn["time_law"]))
        return raws, f"synthetic:{name}", "m"
    if src == "lasa":
        shape = str(_require(task, "shape", "task"))
        return data.load_lasa(shape, int(task["every"])), f"lasa:{shape}", task["unit"]
    return demo_formats.load_any(resolve(str(src))), str(src), "m"


def derived_task(task: dict, raws: list[data.RawDemo]) -> task_from_demos.DerivedTask:
    """Goal, workspace and Δt from the data, with the task's margins (``task.margin`` [m],
    ``task.angle_margin`` [rad], ``task.spread_limit`` [rad], ``task.min_dt`` [s])."""
    return task_from_demos.derive(
        raws, margin=float(task["margin"]), angle_margin=float(task["angle_margin"]),
        spread_limit=float(task["spread_limit"]), min_dt=float(task["min_dt"]))


def model_dt(task: dict, puma: dict, raws: list[data.RawDemo]) -> float:
    """``task.dt`` if set (``auto``: derived from the data), else ``puma.dt`` [s]."""
    dt = task["dt"]
    if dt == "auto":
        return task_from_demos.model_step(raws, float(task["min_dt"]))[0]
    return float(dt if dt is not None else _require(puma, "dt", "puma"))


def load_demos(task: dict, puma: dict) -> data.Demonstrations:
    """The task's demonstrations, prepared (relative to their final poses, resampled to Δt)."""
    return prepare_demos(task, puma, *load_raws(task, puma))


def prepare_demos(task: dict, puma: dict, raws: list[data.RawDemo], source: str,
                  unit: str) -> data.Demonstrations:
    kw = {"smoothing": float(puma["smoothing"]), "hold": int(puma["hold"]),
          "use_orientation": bool(puma["orientation"]) and source[:5] != "lasa:"}
    return data.prepare(raws, model_dt(task, puma, raws), source=source, unit=unit, **kw)


def workspace_of(task: dict, demos: data.Demonstrations) -> Workspace:
    ws = task.get("workspace")
    if ws == "derived":
        raise ConfigError("task.workspace 'derived' needs task.derive=true")
    if ws is None:
        return Workspace.around(demos, float(task["margin"]))
    try:
        return Workspace(tuple(float(v) for v in ws["position_low"]),
                         tuple(float(v) for v in ws["position_high"]),
                         float(ws["max_angle"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"invalid task.workspace ({exc}); needs position_low, position_high, "
                          "max_angle") from None




def check_workspace(task: dict, raws: list[data.RawDemo], ws: Workspace,
                    log=print, starts=()) -> list[str]:
    """Warn (``task.workspace_check.action: warn``), refuse (``error``) or skip
    (``off``) when a demonstration (relative to its own final pose) or a scenario start
    (relative to its goal) leaves the workspace; returns the problems, each naming how far.
    starts: the scenario starts to check, ``(name, position, quaternion, goal position, goal
    quaternion)`` each (the app layer reads them: ``tamedpuma.app.config.workspace_starts``); a
    goal of None is the task's."""
    action = str(task["workspace_check"]["action"])
    if action not in ("warn", "error", "off"):
        raise ConfigError(f"task.workspace_check.action must be warn, error or off, not {action!r}")
    if action == "off":
        return []
    found = task_from_demos.demo_excursions(raws, ws)
    if len(ws.low) == 3:
        for name, p, q, gp, gq in starts:
            gp = task.get("goal_position") if gp is None else gp
            gq = task.get("goal_quaternion") if gq is None else gq
            if gp is None:
                continue
            found += task_from_demos.start_excursions(
                [(name, p, q if raws[0].quat is not None else None)], gp, gq, ws)
    problems = [str(ex) for ex in found]
    if problems and action == "error":
        raise ConfigError(f"{len(problems)} item(s) leave the task workspace, first "
                          f"{problems[0]} (task.workspace_check.action=warn to train anyway)")
    for text in problems:
        log(f"warning: workspace: {text}")
    return problems


def inference_timing(prim, repeats: int = 300) -> dict:
    """Median per-call wall time [ms] of the primitive's inference methods for one state."""
    import timeit

    rng = np.random.default_rng(0)
    out = {}
    spec = prim.spec

    def med(fn):
        fn()
        return float(np.median(timeit.repeat(fn, number=1, repeat=repeats)) * 1e3)

    if spec.orientation:
        p, v, w = rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.1
        q = np.array([0.1, 0.2, 0.3, 0.9]) / np.linalg.norm([0.1, 0.2, 0.3, 0.9])
        gp, gq = np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
        out["acceleration_ms"] = med(lambda: prim.acceleration(p, q, v, w, gp, gq))
        out["potential_ms"] = med(lambda: prim.potential(p, q, gp, gq))
    else:
        x = rng.normal(size=spec.n_pos) * 0.1
        if spec.order == 2:
            out["acceleration_ms"] = med(lambda: prim.acceleration(x, x * 0.1))
        else:
            out["velocity_ms"] = med(lambda: prim.velocity(x))
        out["potential_ms"] = med(lambda: prim.potential(x))
    return out


STATE_FILE = "train_state.pt"  # a training's resumable state, removed when it finishes


def prepare_out_dir(out_dir: Path, overwrite: bool) -> Path:
    """Check ``out_dir`` before the first iteration: an existing ``puma.pt`` is refused unless
    ``overwrite``; the folder must be writable. Returns the checkpoint path."""
    path = out_dir / "puma.pt"
    if path.exists() and not overwrite:
        raise ConfigError(f"{path} exists: pass overwrite=true to replace it, or choose another "
                          "out_dir")
    problem = writable_problem(out_dir)
    if problem:
        raise ConfigError(problem)
    return path


def _resumable(out_dir: Path, cfg: dict, overwrite: bool, log) -> dict | None:
    """The saved state of a killed training of the same config in ``out_dir``, if any."""
    import torch

    path = out_dir / STATE_FILE
    if not path.exists():
        return None
    try:
        saved = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # a state cut short by the kill itself: start over
        log(f"ignoring an unreadable {path} ({type(exc).__name__}); training from the start")
        return None
    if saved.get("config") != _training_part(cfg):
        if overwrite:
            return None
        raise ConfigError(f"{path} holds a partial training of another config: delete it, pass "
                          "overwrite=true, or choose another out_dir")
    log(f"resuming from iteration {saved['state']['it']} ({path})")
    return saved["state"]


def _training_part(cfg: dict) -> dict:
    """The keys that decide a training's result (not progress bars, evaluation or paths)."""
    return {k: cfg[k] for k in ("task", "puma", "seed")}


def _saver(out_dir: Path, cfg: dict):
    from .checkpoint import save_atomic

    def save(state: dict) -> None:
        save_atomic({"config": _training_part(cfg), "state": state}, out_dir / STATE_FILE)
    return save


@dataclass(frozen=True)
class Prepared:
    """Everything a training needs, checked before its first iteration: the config (with a
    derived task's goal filled in), the prepared demonstrations, the workspace, the state spec,
    the settings and the workspace problems found."""

    cfg: dict
    demos: data.Demonstrations
    workspace: Workspace
    spec: StateSpec
    train_cfg: TrainConfig
    net_cfg: NetConfig
    eval_cfg: evaluation.EvalConfig
    problems: list
    derived: task_from_demos.DerivedTask | None
    spread: np.ndarray  # per demonstration: DTW/point to the nearest other one [unit]
    nearest: np.ndarray  # per demonstration: the index of that nearest one


def prepare(cfg: dict, log=print, starts=()) -> Prepared:
    """Demonstrations → (derived task,) workspace, its check (with the scenario ``starts``:
    :func:`check_workspace`), state spec and evaluation settings (tolerances scaled to the
    workspace for non-metric data)."""
    task, puma = cfg["task"], cfg["puma"]
    train_cfg = _dataclass(TrainConfig, puma.get("train"), "puma.train")
    net_cfg = _dataclass(NetConfig, puma.get("network"), "puma.network")
    eval_cfg = _dataclass(evaluation.EvalConfig, puma.get("eval"), "puma.eval")
    raws, source, unit = load_raws(task, puma)
    derived = derived_task(task, raws) if task.get("derive") else None
    if derived is not None:
        if task.get("workspace") is not None:
            raise ConfigError("task.derive=true derives the workspace: leave task.workspace null")
        task = {**task, "goal_position": list(derived.goal_position),
                "goal_quaternion": derived.goal_quaternion and list(derived.goal_quaternion)}
        cfg = {**cfg, "task": task}
        if derived.goal_rule == "medoid":
            log(f"note: the final orientations spread {np.rad2deg(derived.final_angle_spread):.0f}"
                " deg; goal orientation = the medoid final orientation (each demonstration is "
                "learned relative to its own final pose)")
    demos = prepare_demos(task, puma, raws, source, unit)
    ws = derived.workspace if derived is not None else workspace_of(task, demos)
    problems = check_workspace(task, raws, ws, log, starts)
    if task.get("workspace") is None and demos.unit != "m":
        # tolerances scale with the workspace for non-metric data (e.g. LASA in mm)
        size = float(np.max(np.subtract(ws.high, ws.low)))
        eval_cfg = evaluation.EvalConfig(**{**asdict(eval_cfg),
                                            "pos_tol": float(task["pos_tol"] or 0.01 * size),
                                            "compat_min_dist": 0.02 * size})
    try:
        spec = StateSpec(demos.n_pos, bool(puma["orientation"]) and demos.orientation,
                         int(puma["order"]))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if spec.orientation and spec.order != 2:
        raise ConfigError("an R3 x S3 primitive must be second order (puma.order=2)")
    if not spec.orientation:
        ws = Workspace(ws.low, ws.high, 0.0)
    return Prepared(cfg, demos, ws, spec, train_cfg, net_cfg, eval_cfg, problems, derived,
                    *gates.nearest_demos(demos))


def validator_of(p: Prepared):
    """The training's validation (checkpoint selection, early stopping: ``puma.train.val_*``,
    ``stop_*``, ``patience``, ``min_delta``); :func:`stop_target` is the DTW that is good
    enough to stop at."""
    t = p.train_cfg
    return evaluation.validator(p.demos, p.workspace, p.eval_cfg, starts=t.val_starts,
                                confirm=t.val_confirm, horizon=t.val_horizon or None,
                                stop_dtw=0.0, stop_compat=t.stop_compat,
                                keep_dtw=t.keep_dtw, target=stop_target(p),
                                patience=t.patience, min_delta=t.min_delta,
                                plateau_stops=t.anneal == 0, smooth=t.plateau_smooth)


def stop_target(p: Prepared) -> float:
    """The mean DTW [unit] at which training may stop (0: off): the smallest of those set of
    ``stop_gate`` × min(the imitation gate's limit (:func:`gates.imitation_limit`), ``pos_tol``)
    (what the gates ask, with a margin for the evaluation's other starts; at most the
    convergence tolerance however far apart the demonstrations are), ``stop_spread`` × the
    demonstrations' median spread, and ``stop_dtw``."""
    t = p.train_cfg
    gate = min(gates.imitation_limit(p.spread, gates.demo_extent(p.demos), p.eval_cfg),
               p.eval_cfg.pos_tol)
    found = [x for x in (t.stop_gate * gate, t.stop_spread * float(np.median(p.spread)),
                         t.stop_dtw) if x > 0]
    return float(min(found)) if found else 0.0


def _training_report(p: Prepared, result, seed: int) -> dict:
    """The report of a finished training (before its evaluation)."""
    demos, ws = p.demos, p.workspace
    report = {"task": p.cfg["task"].get("name"), "data_source": demos.source,
              "data_hash": demos.data_hash, "n_demos": len(demos), "spec": asdict(p.spec),
              "unit": demos.unit, "seed": seed, "train_seconds": round(result.seconds, 2),
              "iterations": p.train_cfg.iterations, "iterations_run": result.iterations_run,
              "final_losses": result.history[-1] if result.history else {},
              "selection": result.selection, "dt": demos.dt,
              "workspace": {"position_low": list(ws.low), "position_high": list(ws.high),
                            "max_angle": ws.max_angle},
              "workspace_problems": p.problems}
    if p.derived is not None:
        report["derived"] = p.derived.as_dict()
    return report


def run(cfg: dict, log=print, starts=()) -> dict:
    """Train, save, (re)load and evaluate as configured; returns the report (also on disk).

    Before the first iteration: an existing checkpoint is refused unless ``overwrite``, the output
    folder must be writable. Every ``save_every`` iterations the state is saved in
    ``out_dir/train_state.pt``; a killed training started again with the same config resumes
    from it (the result is the same as uninterrupted)."""
    t_start, cpu_start = time.perf_counter(), time.process_time()
    seed = int(cfg["seed"])
    out_dir = resolve(str(cfg["out_dir"]))
    ckpt_path = prepare_out_dir(out_dir, bool(cfg["overwrite"]))
    p = prepare(cfg, log, starts)
    if p.train_cfg.strict and not cfg["evaluate"]:
        raise ConfigError("puma.train.strict=true needs evaluate=true (the gates judge the "
                          "evaluation)")
    cfg, task, demos = p.cfg, p.cfg["task"], p.demos
    log(f"PUMA {task.get('name')}: {len(demos)} demonstrations from {demos.source}, "
        f"spec {p.spec}, dt {demos.dt} s")
    resume = _resumable(out_dir, cfg, bool(cfg["overwrite"]), log)
    result = train(demos, p.workspace, p.spec, p.net_cfg, p.train_cfg, seed=seed,
                   progress=bool(cfg["progress"]), resume=resume,
                   save=_saver(out_dir, cfg), save_every=int(cfg["save_every"]),
                   validator=validator_of(p))
    report = _training_report(p, result, seed)
    goal = {"position": task.get("goal_position"), "quaternion": task.get("goal_quaternion")}
    meta = checkpoint.Meta(demos.dt, data.GOAL_CONVENTION, goal, demos.unit, p.workspace, cfg,
                           demos.data_hash, demos.source, report)
    path = checkpoint.save(ckpt_path, result.net, meta)
    (out_dir / STATE_FILE).unlink(missing_ok=True)
    if cfg["evaluate"]:
        _evaluate(p, path, result.net, meta, report, log)
    report["checkpoint"] = str(path)
    report["pipeline_seconds"] = round(time.perf_counter() - t_start, 2)
    report["pipeline_cpu_seconds"] = round(time.process_time() - cpu_start, 2)
    write_atomic(out_dir / "report.json", (json.dumps(report, indent=2) + "\n").encode())
    if cfg["bench_out"] and "evaluation" in report:
        bench = resolve(str(cfg["bench_out"]))
        bench.parent.mkdir(parents=True, exist_ok=True)
        bench.write_text(json.dumps(benchmark_summary(report, cfg), indent=2) + "\n")
    return report


def _evaluate(p: Prepared, path: Path, net, meta, report: dict, log) -> None:
    """Evaluate the saved checkpoint, judge it (:func:`_gate`) and save it again with the report;
    with ``puma.train.strict`` a failed gate removes it and raises :class:`gates.GateError`."""
    from .primitive import load_primitive

    saved, _ = checkpoint.load(path)  # evaluate what was saved
    t0 = time.perf_counter()
    report["evaluation"] = evaluation.evaluate(saved, p.demos, p.workspace, p.eval_cfg)
    report["evaluation_seconds"] = round(time.perf_counter() - t0, 2)
    report["inference"] = inference_timing(load_primitive(path, threads=1))
    failures = _gate(p, report, log, gates.routes_followed_by(saved, p.demos))
    checkpoint.save(path, net, checkpoint.Meta(**{**meta.__dict__, "report": report}))
    if failures and p.train_cfg.strict:
        path.unlink()
        out = path.parent / "report.json"
        out.write_text(json.dumps(report, indent=2) + "\n")
        raise gates.GateError(f"not saved (puma.train.strict=true): {len(failures)} gate(s) "
                              f"failed, first: {failures[0].line} (all in {out})")


def _gate(p: Prepared, report: dict, log, follows=None) -> list[gates.Failure]:
    """Judge the evaluation (:mod:`.gates`; ``follows``: :func:`gates.routes_followed_by`), store
    the verdict in ``report["gates"]`` and log one warning line per failed gate."""
    field = gates.first_order_field(p.demos, p.spec.order, p.eval_cfg)
    failures = gates.check(report["evaluation"], p.spread, gates.demo_names(p.demos), p.eval_cfg,
                           p.demos.unit, p.nearest, gates.demo_extent(p.demos), follows, field)
    if field is not None:
        report["first_order_field"] = {"bandwidth": gates.field_bandwidth(p.eval_cfg),
                                       "dtw": float(np.mean(field)),
                                       "dtw_max": float(np.max(field)),
                                       "dtw_per_demo": [float(v) for v in field]}
    report["gates"] = gates.as_report(failures, p.spread, p.eval_cfg)
    report["stop_target"] = stop_target(p)
    for f in failures:
        log(f"warning: gate {f.gate}: {f.line}")
    return failures


def benchmark_summary(report: dict, cfg: dict) -> dict:
    """The headline figures of one training run (the JSON ``bench_out`` names)."""
    import platform

    import torch

    ev = report["evaluation"]
    im, cv, cp = ev["imitation"], ev["convergence"], ev["compatibility"]
    return {
        "task": report["task"], "data_source": report["data_source"],
        "data_hash": report["data_hash"], "n_demos": report["n_demos"],
        "config": {"iterations": report["iterations"], "seed": report["seed"],
                   "network": cfg["puma"]["network"], "dt": cfg["puma"]["dt"],
                   "threads": cfg["puma"]["train"]["threads"]},
        "train_seconds": report["train_seconds"],
        "pipeline_seconds": report.get("pipeline_seconds"),
        "pipeline_cpu_seconds": report.get("pipeline_cpu_seconds"),
        "selection": report.get("selection"),
        "evaluation_seconds": report.get("evaluation_seconds"),
        "convergence": {"starts": cv["starts"], "converged_fraction": cv["converged_fraction"],
                        "pos_tol_m": cv["pos_tol"], "ang_tol_rad": cv["ang_tol"],
                        "horizon_s": cv["horizon_s"],
                        "final_pos_error_max_m": cv["final_pos_error_max"],
                        "final_angle_error_max_rad": cv["final_angle_error_max"]},
        "imitation": {"dtw_per_point_m": im["dtw"], "dtw_per_point_max_demo_m": im["dtw_max"],
                      "rmse_m": im["rmse"], "frechet_m": im["frechet"],
                      "dtw_per_point_rad": im.get("dtw_angle"), "rmse_rad": im.get("rmse_angle"),
                      "frechet_rad": im.get("frechet_angle")},
        "psi_compatible_fraction": cp["compatible_fraction"],
        "psi_samples": cp["samples"],
        "inference_ms_per_call": report.get("inference"),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "torch": torch.__version__,
                    "load_average_at_end": [round(x, 2) for x in os.getloadavg()]},
        "command": cfg.get("command") or "",  # set by the entry point
    }
