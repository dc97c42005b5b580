"""The learner across motions and seeds: train and evaluate each demonstration set, one table.

Each job is one composed training config (``pipeline.run``); its row holds the imitation (mean
and worst demonstration DTW per point, mean discrete Fréchet distance; m for the robot sets, the
data's unit otherwise), the converged fraction of the random starts, the ψ-compatible fraction,
the iterations run, the training's wall time and the whole run's wall and CPU time [s], and the
gates that failed. The Markdown table and a JSON twin are rewritten after every job, so a long
run can be read (and stopped) at any point; the last lines give the medians.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import pipeline


@dataclass(frozen=True)
class Job:
    """One training: a demonstration set's name, the model order, the seed, the config and the
    scenario starts its workspace check covers (:func:`pipeline.check_workspace`)."""

    name: str
    order: int
    seed: int
    cfg: dict
    starts: tuple = ()


def row(job: Job, report: dict) -> dict:
    """The table row of one finished training (its ``report.json``)."""
    ev = report["evaluation"]
    im, cv, cp = ev["imitation"], ev["convergence"], ev["compatibility"]
    gates = report.get("gates") or {}
    return {"set": job.name, "order": job.order, "seed": job.seed, "n_demos": report["n_demos"],
            "unit": report.get("unit", "m"), "dtw": im["dtw"], "dtw_worst": im["dtw_max"],
            "frechet": im["frechet"], "converged": cv["converged_fraction"],
            "compatible": cp["compatible_fraction"], "iterations": report["iterations_run"],
            "train_s": report["train_seconds"], "wall_s": report["pipeline_seconds"],
            "cpu_s": report["pipeline_cpu_seconds"],
            "gates_failed": [f["gate"] for f in gates.get("failures", [])],
            "field_dtw": (report.get("first_order_field") or {}).get("dtw"),
            "field_dtw_worst": (report.get("first_order_field") or {}).get("dtw_max")}


def _scale(r: dict) -> tuple[float, str]:
    return (100.0, "cm") if r["unit"] == "m" else (1.0, r["unit"])


def _field(r: dict) -> str:
    """The data's first-order field (mean / worst demonstration DTW) of a first-order row."""
    if r.get("field_dtw") is None:
        return "—"
    k, u = _scale(r)
    return f"{k * r['field_dtw']:.2f} / {k * r['field_dtw_worst']:.2f} {u}"


def markdown(rows: list[dict], note: str = "") -> str:
    """The table, one row per training, then the medians of the times and the share met; with
    first-order rows, a column of what the data's own first-order field reaches
    (:mod:`.data_field`: no first-order model is expected to imitate more closely)."""
    field = any(r.get("field_dtw") is not None for r in rows)
    lines = ["| set | order | seed | demos | DTW mean | DTW worst demo | Fréchet | converged | "
             "ψ-compatible | iterations | train [s] | wall [s] | CPU [s] | gates failed |"
             + (" first-order field of the data (mean / worst) |" if field else ""),
             "|" + "---|" * (14 + field)]
    for r in rows:
        k, u = _scale(r)
        lines.append(
            f"| {r['set']} | {r['order']} | {r['seed']} | {r['n_demos']} | "
            f"{k * r['dtw']:.2f} {u} | {k * r['dtw_worst']:.2f} {u} | {k * r['frechet']:.2f} {u}"
            f" | {100 * r['converged']:.1f}% | {100 * r['compatible']:.2f}% | {r['iterations']} | "
            f"{r['train_s']:.0f} | {r['wall_s']:.0f} | {r['cpu_s']:.0f} | "
            f"{', '.join(r['gates_failed']) or 'none'} |" + (f" {_field(r)} |" if field else ""))
    if rows:
        med = lambda key: float(np.median([r[key] for r in rows]))  # noqa: E731
        lines.append(f"\nMedians over {len(rows)} runs: train {med('train_s'):.0f} s, wall "
                     f"{med('wall_s'):.0f} s, CPU {med('cpu_s'):.0f} s; all gates passed in "
                     f"{sum(not r['gates_failed'] for r in rows)} of {len(rows)}.")
    summaries = families(rows)
    if summaries:
        lines += ["", *summaries]
    return "\n".join(lines) + "\n" + (f"\n{note}\n" if note else "")


def families(rows: list[dict]) -> list[str]:
    """One line per family of sets (``lasa:Angle``, ``lasa:CShape``, ...: the name before the
    colon) and seed: how many sets, the mean over them of the mean DTW, the largest worst
    demonstration's DTW (and its set), the lowest converged and ψ-compatible shares, how many
    passed every gate, and the median training time."""
    groups: dict[tuple[str, int], list[dict]] = {}
    for r in rows:
        if ":" in r["set"]:
            groups.setdefault((r["set"].split(":")[0], r["seed"]), []).append(r)
    out = []
    for (family, seed), group in sorted(groups.items()):
        k, u = _scale(group[0])
        worst = max(group, key=lambda r: r["dtw_worst"])
        out.append(
            f"- {family}, seed {seed}: {len(group)} sets, mean DTW "
            f"{k * float(np.mean([r['dtw'] for r in group])):.2f} {u} (largest "
            f"{k * max(r['dtw'] for r in group):.2f} {u}), worst demonstration "
            f"{k * worst['dtw_worst']:.2f} {u} ({worst['set']}), converged ≥ "
            f"{100 * min(r['converged'] for r in group):.1f}%, ψ-compatible ≥ "
            f"{100 * min(r['compatible'] for r in group):.2f}%, every gate passed by "
            f"{sum(not r['gates_failed'] for r in group)}, median training "
            f"{float(np.median([r['train_s'] for r in group])):.0f} s")
    return out


def run(jobs: list[Job], table: Path, log=print, stamp=None) -> list[dict]:
    """Train and evaluate every job in turn; rewrite ``table`` (.md) and its ``.json`` after each
    (``{"provenance": stamp(now), "rows": [...]}``: ``stamp`` is a callable giving the run's
    provenance, its end set to now). A job whose training fails is logged and left out (the
    others still run)."""
    from ..errors import TamedPumaError

    table.parent.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, job in enumerate(jobs):
        log(f"[{i + 1}/{len(jobs)}] {job.name} order {job.order} seed {job.seed}")
        t0 = time.perf_counter()
        try:
            report = pipeline.run(job.cfg, log=log, starts=job.starts)
        except TamedPumaError as exc:
            log(f"failed: {job.name} seed {job.seed}: {exc}")
            continue
        rows.append(row(job, report))
        log(f"done in {time.perf_counter() - t0:.0f} s: {json.dumps(rows[-1])}")
        note = (f"Machine: {os.cpu_count()} cores, load average at the last row "
                f"{', '.join(f'{x:.1f}' for x in os.getloadavg())}.")
        table.write_text(markdown(rows, note))
        table.with_suffix(".json").write_text(json.dumps(
            {"provenance": stamp() if stamp else None, "rows": rows}, indent=2) + "\n")
    return rows


#: what a model of a robot set must show (:func:`targets`): mean DTW per point [m] by model
#: order, the worst demonstration's [m], the converged and ψ-compatible shares, and the median
#: training time of a second-order model [s]
TARGETS = {"dtw": {2: 0.010, 1: 0.015}, "dtw_worst": 0.03, "converged": 1.0,
           "compatible": 0.995, "train_s": 90.0}


def misses(r: dict) -> list[str]:
    """The targets a row of a robot set (in m) misses, by name; [] for other units."""
    if r["unit"] != "m":
        return []
    t = TARGETS
    checks = {"DTW": r["dtw"] <= t["dtw"].get(r["order"], t["dtw"][2]),
              "worst demo": r["dtw_worst"] <= t["dtw_worst"],
              "converged": r["converged"] >= t["converged"],
              "ψ": r["compatible"] >= t["compatible"]}
    return [name for name, ok in checks.items() if not ok]


def targets(rows: list[dict]) -> str:
    """One paragraph: the rows of robot sets meeting every target, those missing which, and the
    median training time of the second-order models against its target."""
    robot = [r for r in rows if r["unit"] == "m"]
    if not robot:
        return "No robot set in the table: the targets are not judged."
    t = TARGETS
    missed = [f"{r['set']} order {r['order']} seed {r['seed']} ({', '.join(misses(r))})"
              for r in robot if misses(r)]
    second = [r["train_s"] for r in rows if r["order"] == 2]
    med = float(np.median(second)) if second else float("nan")
    robot_second = [r["train_s"] for r in robot if r["order"] == 2]
    alone = (f"; {float(np.median(robot_second)):.0f} s over the robot sets' "
             f"{len(robot_second)} alone" if robot_second and len(robot_second) < len(second)
             else "")
    return (f"Targets (robot sets): mean DTW ≤ {100 * t['dtw'][2]:.1f} cm (first order "
            f"≤ {100 * t['dtw'][1]:.1f} cm), worst demonstration ≤ {100 * t['dtw_worst']:.0f} cm, "
            f"{100 * t['converged']:.0f} % converged, ψ-compatible ≥ {100 * t['compatible']:.1f} "
            f"%: met by {len(robot) - len(missed)} of {len(robot)} models"
            + (f"; missed by {'; '.join(missed)}" if missed else "")
            + f". Median training of a second-order model: {med:.0f} s over the table's "
            f"{len(second)} (target ≤ {t['train_s']:.0f} s: "
            f"{'met' if med <= t['train_s'] else 'missed'}){alone}.")
