"""The LASA benchmark: train and evaluate a second-order 2-D primitive on each handwriting shape.

Per shape: train (``pipeline.run``), then roll out from each demonstration's start (mean RMSE,
DTW per point and discrete Fréchet distance against the demonstrations, and the largest DTW per
point of one demonstration, mm) and from a
``grid × grid`` lattice of rest states covering the workspace (the demonstrations' bounding box
plus a margin); a grid rollout that does not end within ``pos_tol`` (1% of the workspace size
unless configured) after ``horizon`` seconds counts as non-converging (goal: 0).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..paths import resolve
from . import checkpoint, data, evaluation, pipeline


def grid_starts(ws, grid: int) -> np.ndarray:
    """``grid²`` points on a lattice over the 2-D workspace box."""
    axes = [np.linspace(lo, hi, grid) for lo, hi in zip(ws.low, ws.high)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(axes))


def run_shape(cfg: dict, shape: str, grid: int, log=print) -> dict:
    """Train and evaluate one shape; returns one table row."""
    cfg = {**cfg, "task": {**cfg["task"], "shape": shape},
           "out_dir": str(Path(cfg["out_dir"]) / shape)}
    report = pipeline.run(cfg, log=log)
    net, meta = checkpoint.load(report["checkpoint"])
    ev = report["evaluation"]
    eval_cfg = evaluation.EvalConfig(**{**cfg["puma"]["eval"],
                                        "pos_tol": ev["convergence"]["pos_tol"]})
    conv = evaluation.convergence_from(net, grid_starts(meta.workspace, grid), None, meta.dt,
                                       eval_cfg)
    im = ev["imitation"]
    return {"shape": shape, "rmse": im["rmse"], "dtw": im["dtw"], "dtw_max": im["dtw_max"],
            "frechet": im["frechet"],
            "grid_starts": conv["starts"], "grid_not_converged": conv["not_converged"],
            "random_converged_fraction": ev["convergence"]["converged_fraction"],
            "compatible_fraction": ev["compatibility"]["compatible_fraction"],
            "pos_tol": conv["pos_tol"], "train_seconds": report["train_seconds"]}


def markdown(rows: list[dict], note: str = "") -> str:
    """The table: one row per shape, then the means (counts summed)."""
    head = ("| shape | RMSE [mm] | DTW/point [mm] | worst demo DTW/point [mm] | Fréchet [mm] | "
            "grid not converged | random starts converged | ψ-compatible | train [s] |\n"
            "|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        lines.append(f"| {r['shape']} | {r['rmse']:.2f} | {r['dtw']:.2f} | {r['dtw_max']:.2f} | "
                     f"{r['frechet']:.2f} | "
                     f"{r['grid_not_converged']}/{r['grid_starts']} | "
                     f"{100 * r['random_converged_fraction']:.1f}% | "
                     f"{100 * r['compatible_fraction']:.1f}% | {r['train_seconds']:.0f} |")
    if rows:
        m = lambda k: float(np.mean([r[k] for r in rows]))  # noqa: E731
        lines.append(f"| **mean ({len(rows)} shapes)** | {m('rmse'):.2f} | {m('dtw'):.2f} | "
                     f"{m('dtw_max'):.2f} | {m('frechet'):.2f} | "
                     f"{sum(r['grid_not_converged'] for r in rows)}/"
                     f"{sum(r['grid_starts'] for r in rows)} | "
                     f"{100 * m('random_converged_fraction'):.1f}% | "
                     f"{100 * m('compatible_fraction'):.1f}% | {m('train_seconds'):.0f} |")
    return "\n".join(lines) + "\n" + (f"\n{note}\n" if note else "")


def run(cfg: dict, log=print, stamp=None) -> list[dict]:
    """All configured shapes; writes the Markdown table and a JSON beside it after each shape
    (``{"provenance": stamp(), "rows": [...]}``; ``stamp`` gives the run's provenance, its end
    set to now)."""
    task = cfg["task"]
    shapes = task["shapes"]
    names = data.lasa_names() if shapes in ("all", None) else [str(s) for s in shapes]
    known = set(data.lasa_names())
    bad = [s for s in names if s not in known]
    if bad:
        raise data.DataError(f"unknown LASA shape(s) {', '.join(bad)}")
    table = resolve(str(task["table"]))
    table.parent.mkdir(parents=True, exist_ok=True)
    rows, t0 = [], time.perf_counter()
    for name in names:
        rows.append(run_shape(cfg, name, int(task["grid"]), log=log))
        p = cfg["puma"]
        note = (f"Second-order 2-D PUMA, {p['train']['iterations']} iterations, width "
                f"{p['network']['width']}, seed {cfg['seed']}; every {task.get('every')}th "
                f"sample; a rollout converges when it ends within 1% of its shape's workspace size "
                f"({min(r['pos_tol'] for r in rows):.2g}-{max(r['pos_tol'] for r in rows):.2g} mm) "
                f"after {p['eval']['horizon']} s; {len(rows)}/{len(names)} shapes done in "
                f"{time.perf_counter() - t0:.0f} s. Command: `python -m tamedpuma.lasa`.")
        table.write_text("# LASA handwriting benchmark (PUMA)\n\n" + markdown(rows, note))
        table.with_suffix(".json").write_text(json.dumps(
            {"provenance": stamp() if stamp else None, "rows": rows}, indent=1) + "\n")
        log(f"{name}: DTW {rows[-1]['dtw']:.2f} mm, grid not converged "
            f"{rows[-1]['grid_not_converged']}")
    return rows
