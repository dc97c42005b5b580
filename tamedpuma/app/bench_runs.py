"""The whole-command figures of ``python -m tamedpuma.bench``: PUMA training and the Table-1 sweep.

Both run the project's own commands in a fresh process, exactly as a user types them, and read
what those commands wrote (the training's ``report.json``; every run's ``summary.json``), so the
figures and the profile that explains them come from the same run:

- **training**: ``python -m tamedpuma.train task=<task> seed=<seed> out_dir=<tmp>`` per task and
  seed: process wall time, the pipeline's CPU time, iterations, and the training's accuracy and
  stability targets read from the evaluation, each judged with the time target: those of the
  learner table (:data:`tamedpuma.puma.learner_table.TARGETS`: every random start converged,
  mean DTW per point ≤ 1 cm, worst demonstration ≤ 3 cm, ψ-compatible ≥ 99.5 %, ≤ 90 s);
- **Table 1**: ``python -m tamedpuma.sweep +experiment=table1 output_root=<tmp>``: wall time, and
  where the cores' time went, from the runs' summaries: per method the runs, steps, the
  controller's own time (the sum of its per-step times), the rest of the episodes (simulator,
  state reads, recorders) and the runs' set-up (config, model, scenario, controller); what is
  left of cores × wall is the sweep's own cost (Hydra's per-job compose and job files, worker
  dispatch, the final tables) and idle cores.
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
#: The Table-1 target: TABLE1_TARGET_S of wall time on the 2-core machine for
#: TABLE1_TARGET_RUNS runs (a sweep of more runs, as Table 1 with more methods, is judged per run)
TABLE1_TARGET_S, TABLE1_TARGET_RUNS = 240.0, 420


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


def table1_profile(root: Path) -> dict:
    """Where a Table-1 sweep's time went, from the ``summary.json`` of every run below ``root``:
    per method label the runs, steps, controller time (the sum of its per-step times), the
    simulator's steps (PyBullet's physics and observation), episode time and set-up time [s];
    and their totals. Runs written before summaries carried ``wall_s`` count in runs and steps
    only (and before they carried its ``simulator``, with no simulator time)."""
    methods: dict[str, dict] = {}
    for path in sorted(Path(root).rglob("summary.json")):
        try:
            s = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        m = methods.setdefault(s.get("method_label") or s.get("method", "?"), {
            "runs": 0, "steps": 0, "controller_s": 0.0, "simulator_s": 0.0, "episode_s": 0.0,
            "build_s": 0.0})
        wall = s.get("wall_s") or {}
        m["runs"] += 1
        m["steps"] += int(s.get("steps") or 0)
        m["controller_s"] += sum(s.get("step_compute_ms") or []) / 1e3
        m["simulator_s"] += float(wall.get("simulator") or 0.0)
        m["episode_s"] += float(wall.get("episode") or 0.0)
        m["build_s"] += float(wall.get("build") or 0.0)
    total = {k: sum(m[k] for m in methods.values())
             for k in ("runs", "steps", "controller_s", "simulator_s", "episode_s", "build_s")}
    return {"methods": {k: {kk: round(v, 3) if isinstance(v, float) else v
                            for kk, v in m.items()} for k, m in methods.items()},
            "total": {k: round(v, 3) if isinstance(v, float) else v for k, v in total.items()}}


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


def time_table1(cores: int, timeout: float = 7200.0) -> dict:
    """``python -m tamedpuma.sweep +experiment=table1`` into a temporary folder: its wall time,
    then the profile of its runs and the time ``python -m tamedpuma.analysis.tables`` takes to
    rebuild the tables from the logs (the sweep's last step)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        item = timed_command(["-m", "tamedpuma.sweep", "+experiment=table1",
                              f"output_root={tmp}"], timeout)
        item["cores"] = cores
        table_root = Path(tmp) / "table1"
        item["profile"] = table1_profile(table_root)
        tables = timed_command(["-m", "analysis.tables", str(table_root)], timeout)
        item["tables_wall_s"] = tables["wall_s"]
    item["job"] = job_overheads()
    return item


def table1_lines(item: dict | None) -> list[str]:
    """Markdown: ``["", verdict line with the profile in words, "", caption, "", table...]``
    (the verdict joins the target list, the rest follows the training table)."""
    if not item:
        return []
    wall, cores = item["wall_s"], item.get("cores") or 1
    prof = item.get("profile") or {}
    tot = prof.get("total") or {}
    runs = tot.get("runs") or TABLE1_TARGET_RUNS
    per_target = wall * TABLE1_TARGET_RUNS / runs
    met = item.get("returncode") == 0 and per_target <= TABLE1_TARGET_S
    head = (f"- `+experiment=table1` ≤ {TABLE1_TARGET_S / 60:.0f} minutes per "
            f"{TABLE1_TARGET_RUNS} runs on {cores} cores: **{'met' if met else 'not met'}** "
            f"({wall:.0f} s wall for {runs} runs, {per_target:.0f} s per {TABLE1_TARGET_RUNS}, "
            f"exit {item['returncode']}).")
    if not tot.get("runs"):
        return ["", head]
    capacity = wall * cores
    episodes, build, ctrl = tot["episode_s"], tot["build_s"], tot["controller_s"]
    rest = capacity - episodes - build
    job = item.get("job") or {}
    compose = job.get("compose_s", float("nan")) * tot["runs"]
    tables = item.get("tables_wall_s", float("nan"))
    lines = ["", head + (
        f" Of the {cores} cores × {wall:.0f} s = {capacity:.0f} core-s, the {tot['runs']} runs' "
        f"episodes took {episodes:.0f} s ({tot['steps']} steps: the controllers "
        f"{ctrl:.0f} s, the simulator's steps (PyBullet's physics and the next observation) "
        f"{tot.get('simulator_s', 0.0):.0f} s, the loop's state reads, metrics and recorders "
        f"{episodes - ctrl - tot.get('simulator_s', 0.0):.0f} s), their "
        f"set-up (config typing, model, scenario, controller) {build:.0f} s (the schema's "
        f"typing {job.get('typing_s', float('nan')):.2f} s a run), and the other {rest:.0f} s "
        f"went to the sweep's own work and idle cores: Hydra composes every job's config "
        f"in its worker ({job.get('compose_s', float('nan')):.2f} s a job, "
        f"{compose:.0f} core-s in all), rebuilding the tables from the {tot['runs']} logs at "
        f"the end takes {tables:.0f} s on {cores} cores, and the rest is job files, worker "
        f"dispatch, the models check and the cores' idle time at the start and the end. "
        f"The episodes alone "
        f"on {cores} cores need {episodes / cores:.0f} s."), "",
        f"The Table-1 sweep ({wall:.0f} s), where its time went, per method (from the runs' "
        "`summary.json`: the controller is the sum of its per-step times, the episode also "
        "holds PyBullet, state reads and recorders, the set-up builds config, model, scenario "
        "and controller):", "",
        "| method | runs | steps | controller [s] | ms per step | simulator [s] | episodes [s] "
        "| set-up [s] | share of the episodes |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    methods = sorted(prof["methods"].items(), key=lambda kv: -kv[1]["episode_s"])
    for name, m in methods:
        per = 1e3 * m["controller_s"] / m["steps"] if m["steps"] else float("nan")
        share = m["episode_s"] / episodes if episodes else float("nan")
        lines.append(f"| {name} | {m['runs']} | {m['steps']} | {m['controller_s']:.0f} | "
                     f"{per:.2f} | {m.get('simulator_s', 0.0):.0f} | {m['episode_s']:.0f} | "
                     f"{m['build_s']:.0f} | {100 * share:.0f}% |")
    return lines
