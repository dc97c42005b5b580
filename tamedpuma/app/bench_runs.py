"""The whole-command figures of ``python -m tamedpuma.bench``: PUMA training, and what the sweeps'
timing (:mod:`tamedpuma.app.bench_sweeps`) shares with it.

The training runs the project's own command in a fresh process, exactly as a user types it, and
reads what it wrote (its ``report.json``), so the figures and what explains them come from the
same run:

- **training**: ``python -m tamedpuma.train task=<task> seed=<seed> out_dir=<tmp>`` per task and
  seed: process wall time, the pipeline's CPU time, iterations, and the training's accuracy and
  stability targets read from the evaluation, each judged with the time target: those of the
  learner table (:data:`tamedpuma.puma.learner_table.TARGETS`: every random start converged,
  mean DTW per point ≤ 1 cm, worst demonstration ≤ 3 cm, ψ-compatible ≥ 99.5 %, ≤ 90 s);
- **Hydra's per-job cost** (:func:`job_overheads`), which the sweeps' profile names.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from tamedpuma.puma import learner_table

#: The training targets: the learner table's, those of a second-order model (the default).
TARGETS = learner_table.TARGETS


def timed_command(argv: list[str], timeout: float | None = None) -> dict:
    """Run ``python argv`` in a fresh process: its command line, wall time [s], exit code, and
    the last line of its stderr when it failed."""
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, *argv], capture_output=True, text=True,
                              timeout=timeout)
        code, err = proc.returncode, proc.stderr
    except subprocess.TimeoutExpired:
        code, err = None, f"timed out after {timeout} s"
    item = {"command": "python " + " ".join(argv),
            "wall_s": round(time.perf_counter() - t0, 1), "returncode": code}
    if code != 0:
        lines = [ln for ln in (err or "").splitlines() if ln.strip()]
        item["error"] = lines[-1] if lines else "no output"
    return item


def training_figures(report: dict) -> dict:
    """The training figures from a training ``report.json`` (missing ones: None)."""
    ev = report.get("evaluation") or {}
    conv, imit, comp = (ev.get(k) or {} for k in ("convergence", "imitation", "compatibility"))
    return {"iterations": report.get("iterations_run") or report.get("iterations"),
            "iterations_max": report.get("iterations"),
            "pipeline_s": report.get("pipeline_seconds"),
            "pipeline_cpu_s": report.get("pipeline_cpu_seconds"),
            "converged_fraction": conv.get("converged_fraction"), "starts": conv.get("starts"),
            "final_pos_error_max_m": conv.get("final_pos_error_max"),
            "dtw_m": imit.get("dtw"), "dtw_max_m": imit.get("dtw_max"),
            "compatible_fraction": comp.get("compatible_fraction"),
            "samples": comp.get("samples")}


def training_verdict(row: dict) -> list[str]:
    """The targets ``row`` misses, in words (empty: every target met)."""
    t, missed = TARGETS, []
    if row.get("returncode") != 0:
        return [f"the command failed ({row.get('error', 'exit ' + str(row.get('returncode')))})"]
    conv, dtw, comp = (row.get(k) for k in ("converged_fraction", "dtw_m",
                                             "compatible_fraction"))
    if conv is None or conv < t["converged"]:
        missed.append(f"converged {_pct(conv)} of {row.get('starts')} starts")
    if dtw is None or dtw > t["dtw"][2]:
        missed.append(f"DTW {_cm(dtw)} cm")
    worst = row.get("dtw_max_m")
    if worst is None or worst > t["dtw_worst"]:
        missed.append(f"worst demonstration {_cm(worst)} cm")
    if comp is None or comp < t["compatible"]:
        missed.append(f"ψ-compatible {_pct(comp)}")
    if row["wall_s"] > t["train_s"]:
        missed.append(f"{row['wall_s']:.0f} s wall")
    return missed


def demos_override(task: str) -> list[str]:
    """``task.demos=<folder>`` of the authors' demonstrations of ``task`` where they are on this
    machine (``../shared/data/pumafabrics-demos``, ``$TAMEDPUMA_DEMOS`` or the download folder:
    the targets are the real data's), else nothing: the task's seeded synthetic demonstrations."""
    from tamedpuma.puma import download

    folder = download.TASK_FOLDERS[task]
    root = download.find_root((folder,))
    return [] if root is None else [f"task.demos={root / folder}"]


def time_training(tasks=("tomato", "pouring"), seeds=(0,), timeout: float = 3600.0) -> list[dict]:
    """Train every (task, seed) with the default config on the authors' demonstrations (the
    synthetic ones where they are absent, said in the row's ``demos``) in a fresh process, one
    after another (one torch thread each: ``conf/puma/default.yaml``), and read its report."""
    import tempfile

    rows = []
    for task in tasks:
        demos = demos_override(task)
        for seed in seeds:
            with tempfile.TemporaryDirectory() as tmp:
                row = {"task": task, "seed": seed,
                       "demos": demos[0].partition("=")[2] if demos else "synthetic (seeded)",
                       **timed_command(["-m", "tamedpuma.train", f"task={task}", *demos,
                                        f"seed={seed}", f"out_dir={tmp}/m"], timeout)}
                report = Path(tmp) / "m" / "report.json"
                if report.is_file():
                    row.update(training_figures(json.loads(report.read_text())))
            rows.append(row)
            print(f"bench: training {task} seed {seed}: {row['wall_s']} s", file=sys.stderr)
    return rows


def _pct(x) -> str:
    return "?" if x is None else f"{100 * x:.1f}%"


def _cm(x) -> str:
    return "?" if x is None else f"{100 * x:.2f}"


def training_lines(rows: list[dict], measured_by: str | None = None) -> list[str]:
    """Markdown: the training table and its verdict (``measured_by``: the bench command
    and date that measured it, when another run than the rest of the report's)."""
    if not rows:
        return []
    demos = "; ".join(f"{t}: {d}" for t, d in dict.fromkeys(
        (r["task"], r.get("demos", "?")) for r in rows))
    lines = ["", "PUMA training, the default config (`python -m tamedpuma.train task=<task> "
             "task.demos=<folder> seed=<seed> out_dir=...`, one run after another, one torch "
             f"thread; demonstrations: {demos}; targets: {_targets()}"
             + (f"; measured by {measured_by}" if measured_by else "") + "):", "",
             "| task | seed | process wall [s] | pipeline CPU [s] | iterations run (of max) "
             "| CPU per iteration [ms] | converged | mean DTW/point [cm] | ψ-compatible "
             "| targets |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        missed = training_verdict(r)
        cpu = r.get("pipeline_cpu_s")
        lines.append(f"| {r['task']} | {r['seed']} | {r['wall_s']:.0f} | "
                     f"{'?' if cpu is None else f'{cpu:.0f}'} | {r.get('iterations', '?')} "
                     f"(of {r.get('iterations_max', '?')}) | "
                     f"{_per_iteration(r)} | "
                     f"{_pct(r.get('converged_fraction'))} of {r.get('starts', '?')} | "
                     f"{_cm(r.get('dtw_m'))} | {_pct(r.get('compatible_fraction'))} | "
                     f"{'met' if not missed else 'missed: ' + '; '.join(missed)} |")
    return lines


def _targets() -> str:
    """The training targets in words."""
    t = TARGETS
    return (f"{100 * t['converged']:.0f}% of the evaluation's random starts "
            f"converged, mean DTW per point ≤ {100 * t['dtw'][2]:.0f} cm, worst demonstration "
            f"≤ {100 * t['dtw_worst']:.0f} cm, ψ-compatible "
            f"≥ {100 * t['compatible']:.1f}%, ≤ {t['train_s']:.0f} s")


def _per_iteration(row: dict) -> str:
    """The pipeline's CPU time per training iteration [ms] (validations, saving and the
    evaluation included: an upper bound of one iteration's cost)."""
    cpu, its = row.get("pipeline_cpu_s"), row.get("iterations")
    return "?" if not cpu or not its else f"{1e3 * cpu / its:.0f}"


def training_target_line(rows: list[dict]) -> str:
    """One line of the training targets."""
    if not rows:
        return ""
    bad = [(r, training_verdict(r)) for r in rows if training_verdict(r)]
    runs = ", ".join(t + " seeds " + "/".join(str(r["seed"]) for r in rows if r["task"] == t)
                     for t in dict.fromkeys(r["task"] for r in rows))
    tasks = dict.fromkeys(r["task"] for r in rows)
    walls = "; ".join(t + " " + "/".join(f"{r['wall_s']:.0f}" for r in rows if r["task"] == t)
                      + " s" for t in tasks)
    if not bad:
        return (f"- PUMA training ≤ {TARGETS['train_s']:.0f} s per model on one core "
                f"with every accuracy and stability target ({runs}): **met** ({walls}).")
    why = "; ".join(f"{r['task']} seed {r['seed']}: " + ", ".join(m) for r, m in bad)
    cost = "; ".join(t + " " + "/".join(f"{r.get('iterations', '?')} × {_per_iteration(r)}"
                                        for r in rows if r["task"] == t) for t in tasks)
    return (f"- PUMA training ≤ {TARGETS['train_s']:.0f} s per model on one core with "
            f"every accuracy and stability target ({runs}): **not met**: {why} (all: {walls}). "
            f"The time is the iterations the early stop needs × the CPU time of one (ms, "
            f"validations and evaluation included): {cost}; what an iteration spends is in the "
            f"\"training speed\" section below (backward pass, rollouts' forward pass, "
            f"per-operation overhead of small tensors).")


def job_overheads(repeats: int = 7) -> dict:
    """Per-job costs of a Table-1 run outside its ``run_one`` [s, medians of ``repeats``]:
    Hydra's composition of the job's config (what every worker of the ``cores`` launcher does
    before each job, ``ConfigLoaderImpl.load_sweep_config``: the job's overrides on
    ``sweep.yaml``, Hydra's own config included, each config file read once per worker) and the
    schema's typing of it (``schema.run_config``, the first thing
    ``build`` does, inside the run's set-up)."""
    from statistics import median

    from omegaconf import OmegaConf

    from tamedpuma.app.compose import compose, session
    from tamedpuma.app.schema import run_config

    overrides = ["+experiment=table1", "case=pouring_03", "method=cpm", "without_obstacles=true"]
    composing, typing = [], []
    with session(shared_reads=True):
        compose("sweep", overrides, hydra_config=True)  # the worker's first job reads the files
        for _ in range(repeats):
            t0 = time.perf_counter()
            cfg = compose("sweep", overrides, hydra_config=True)
            t1 = time.perf_counter()
            with_hydra = OmegaConf.to_container(cfg, resolve=False)
            with_hydra.pop("hydra", None)
            t2 = time.perf_counter()
            run_config(OmegaConf.create(with_hydra))
            typing.append(time.perf_counter() - t2)
            composing.append(t1 - t0)
    return {"compose_s": round(median(composing), 4), "typing_s": round(median(typing), 4)}
