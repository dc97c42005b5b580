"""Config dict → data → training → checkpoint → evaluation report (no Hydra here).

The entry points (``tamedpuma.train``, ``tamedpuma.lasa``) compose the config with Hydra and call
:func:`run`. Config keys: see ``conf/train.yaml``, ``conf/task/*.yaml`` and ``conf/puma/*.yaml``.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from . import checkpoint, data, demos_synthetic, evaluation
from .network import NetConfig, StateSpec
from .training import TrainConfig, Workspace, train

REPO_ROOT = Path(__file__).resolve().parents[2]


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


def resolve_path(p: str) -> Path:
    """Absolute, else relative to the working directory if it exists there, else the repo root."""
    path = Path(p).expanduser()
    if path.is_absolute() or path.exists():
        return path
    return REPO_ROOT / path


def _require(cfg: dict, key: str, where: str):
    if key not in cfg or cfg[key] is None and key != "demos":
        raise ConfigError(f"missing config key {where}.{key}")
    return cfg[key]


def load_demos(task: dict, puma: dict) -> data.Demonstrations:
    """The task's demonstrations: synthetic (demos null), LASA (demos 'lasa') or a folder."""
    name = _require(task, "name", "task")
    src = task.get("demos")
    dt = float(_require(puma, "dt", "puma"))
    kw = {"smoothing": float(puma.get("smoothing", 0.0)), "hold": int(puma.get("hold", 10)),
          "use_orientation": bool(puma.get("orientation", True))}
    if src is None:
        syn = task.get("synthetic") or {}
        raws = demos_synthetic.generate(name, _require(task, "goal_position", "task"),
                                        _require(task, "goal_quaternion", "task"),
                                        int(syn.get("n_demos", 10)), int(syn.get("seed", 0)))
        return data.prepare(raws, dt, source=f"synthetic:{name}", **kw)
    if src == "lasa":
        shape = str(_require(task, "shape", "task"))
        raws = data.load_lasa(shape, int(task.get("every", 10)))
        kw["use_orientation"] = False
        return data.prepare(raws, dt, source=f"lasa:{shape}", unit=task.get("unit", "mm"), **kw)
    folder = resolve_path(str(src))
    return data.prepare(data.load_pickle_demos(folder), dt, source=str(src), **kw)


def workspace_of(task: dict, demos: data.Demonstrations) -> Workspace:
    ws = task.get("workspace")
    if ws is None:
        return Workspace.around(demos, float(task.get("margin", 0.1)))
    try:
        return Workspace(tuple(float(v) for v in ws["position_low"]),
                         tuple(float(v) for v in ws["position_high"]),
                         float(ws.get("max_angle", 0.0)))
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"invalid task.workspace ({exc}); needs position_low, position_high, "
                          "max_angle") from None


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


def run(cfg: dict, log=print) -> dict:
    """Train, save, (re)load and evaluate as configured; returns the report (also on disk)."""
    t_start, cpu_start = time.perf_counter(), time.process_time()
    task, puma = cfg.get("task") or {}, cfg.get("puma") or {}
    if not isinstance(task, dict) or not isinstance(puma, dict):
        raise ConfigError("config needs 'task' and 'puma' groups")
    seed = int(cfg.get("seed", 0))
    out_dir = resolve_path(str(cfg.get("out_dir", f"runs/puma/{task.get('name', 'task')}")))
    train_cfg = _dataclass(TrainConfig, puma.get("train"), "puma.train")
    net_cfg = _dataclass(NetConfig, puma.get("network"), "puma.network")
    eval_cfg = _dataclass(evaluation.EvalConfig, puma.get("eval"), "puma.eval")
    demos = load_demos(task, puma)
    ws = workspace_of(task, demos)
    if task.get("workspace") is None and demos.unit != "m":
        # tolerances scale with the workspace for non-metric data (e.g. LASA in mm)
        size = float(np.max(np.subtract(ws.high, ws.low)))
        eval_cfg = evaluation.EvalConfig(**{**asdict(eval_cfg),
                                            "pos_tol": float(task.get("pos_tol", 0.01 * size)),
                                            "compat_min_dist": 0.02 * size})
    try:
        spec = StateSpec(demos.n_pos, bool(puma.get("orientation", True)) and demos.orientation,
                         int(puma.get("order", 2)))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if spec.orientation and spec.order != 2:
        raise ConfigError("an R3 x S3 primitive must be second order (puma.order=2)")
    if not spec.orientation:
        ws = Workspace(ws.low, ws.high, 0.0)
    log(f"PUMA {task.get('name')}: {len(demos)} demonstrations from {demos.source}, "
        f"spec {spec}, dt {demos.dt} s")
    result = train(demos, ws, spec, net_cfg, train_cfg, seed=seed,
                   progress=bool(cfg.get("progress", True)),
                   validator=evaluation.validator(demos, ws, eval_cfg))
    report = {"task": task.get("name"), "data_source": demos.source, "data_hash": demos.data_hash,
              "n_demos": len(demos), "spec": asdict(spec), "seed": seed,
              "train_seconds": round(result.seconds, 2), "iterations": train_cfg.iterations,
              "final_losses": result.history[-1] if result.history else {},
              "selection": result.selection}
    goal = {"position": task.get("goal_position"), "quaternion": task.get("goal_quaternion")}
    meta = checkpoint.Meta(demos.dt, data.GOAL_CONVENTION, goal, demos.unit, ws, cfg,
                           demos.data_hash, demos.source, report)
    path = checkpoint.save(out_dir / "puma.pt", result.net, meta)
    if cfg.get("evaluate", True):
        from .primitive import load_primitive

        net, _ = checkpoint.load(path)  # evaluate what was saved
        t0 = time.perf_counter()
        report["evaluation"] = evaluation.evaluate(net, demos, ws, eval_cfg)
        report["evaluation_seconds"] = round(time.perf_counter() - t0, 2)
        report["inference"] = inference_timing(load_primitive(path, threads=1))
        meta = checkpoint.Meta(**{**meta.__dict__, "report": report})
        checkpoint.save(path, result.net, meta)
    report["checkpoint"] = str(path)
    report["pipeline_seconds"] = round(time.perf_counter() - t_start, 2)
    report["pipeline_cpu_seconds"] = round(time.process_time() - cpu_start, 2)
    (out_dir / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    if cfg.get("bench_out") and "evaluation" in report:
        bench = resolve_path(str(cfg["bench_out"]))
        bench.parent.mkdir(parents=True, exist_ok=True)
        bench.write_text(json.dumps(benchmark_summary(report, cfg), indent=2) + "\n")
    return report


def benchmark_summary(report: dict, cfg: dict) -> dict:
    """The headline figures of one training run (for benchmarks/puma_<task>.json)."""
    import os
    import platform

    import torch

    ev = report["evaluation"]
    im, cv, cp = ev["imitation"], ev["convergence"], ev["compatibility"]
    return {
        "task": report["task"], "data_source": report["data_source"],
        "data_hash": report["data_hash"], "n_demos": report["n_demos"],
        "config": {"iterations": report["iterations"], "seed": report["seed"],
                   "network": cfg["puma"]["network"], "dt": cfg["puma"]["dt"],
                   "threads": cfg["puma"]["train"].get("threads", 1)},
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
        "command": cfg.get("command", ""),
    }
