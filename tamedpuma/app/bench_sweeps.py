"""How long the paper's sweeps take on this machine, and whether every step in them stays bounded.

``python -m tamedpuma.bench --table1 N --suite N`` (or ``--sweeps``: these alone) runs each sweep
``N`` times exactly as a user types it, each into a fresh temporary folder, and reads what the
runs wrote (every ``summary.json``):

- **Table 1**: ``python -m tamedpuma.sweep +experiment=table1``; target ``≤ 4 min`` per 420 runs
  on 2 cores (the table holds more runs than the paper's 420: it is judged per run);
- **the randomized suite**: ``python -m tamedpuma.sweep -m +experiment=random
  method=puma,modulation_ik,fabrics,fpm,cpm`` (the paper's five methods on the suite's 400
  scenarios, with and without their obstacles: 4,000 runs); target ``≤ 45 min`` per 4,000 runs.

The wall time judged is the median over the repeats. Where the cores' time went comes from the
runs' summaries (per method: runs, steps, the controller's own time, the simulator's steps, the
episodes, the set-up). The step bound is judged on every step of every run of every repeat, as
the summaries record it (``compute_ms_max``, the wall time of ``controller.step``): no step over
:data:`BOUND_MS` for :data:`BOUNDED` methods, and every run's p99 within :data:`P99_MS` for
:data:`P99_BOUNDED`; the others (Modulation-IK's optimisation, the paper's laws as written)
are reported, not bounded. The longest step in thread CPU time (``compute_cpu_ms_max``) is
given beside it: a wall-time step far longer than its CPU time was the machine's, not the
controller's.
"""

from __future__ import annotations

import json
import statistics
import tempfile
from dataclasses import dataclass
from pathlib import Path

from tamedpuma.app.bench_runs import job_overheads, timed_command

#: no step over this [ms] (half the 20 ms control period) for the bounded methods
BOUND_MS = 10.0
BOUNDED = ("puma", "fabrics", "fpm", "cpm")
#: every run's 99th-percentile step within this [ms] for these methods
P99_MS = 2.0
P99_BOUNDED = ("fpm", "cpm")


@dataclass(frozen=True)
class Sweep:
    """One timed sweep: its command line after ``python -m tamedpuma.sweep``, the folder under
    ``output_root`` its runs land in, and its target: ``target_s`` of wall time per
    ``target_runs`` runs."""

    title: str
    args: tuple[str, ...]
    folder: str
    target_s: float
    target_runs: int


SWEEPS = {
    "table1": Sweep("`+experiment=table1`", ("+experiment=table1",), "table1", 240.0, 420),
    "suite": Sweep("the randomized suite (`-m +experiment=random "
                   "method=puma,modulation_ik,fabrics,fpm,cpm`)",
                   ("-m", "+experiment=random", "method=puma,modulation_ik,fabrics,fpm,cpm"),
                   "random", 2700.0, 4000),
}

_TOTALS = ("runs", "steps", "controller_s", "simulator_s", "episode_s", "build_s")
#: the per-method maxima over runs, each from its summary key
_MAXIMA_FROM = {"max_step_ms": "compute_ms_max", "max_step_cpu_ms": "compute_cpu_ms_max",
                "max_p99_ms": "compute_ms_p99", "max_p99_cpu_ms": "compute_cpu_ms_p99"}
_MAXIMA = tuple(_MAXIMA_FROM)


def sweep_profile(root: Path) -> dict:
    """Where a sweep's time went and its longest steps, from the ``summary.json`` of every run
    below ``root``: per method label the runs, steps, controller time (the sum of its per-step
    times), the simulator's steps (PyBullet's physics and observation), episode and set-up time
    [s], the longest step (wall and thread CPU) and the largest run p99 [ms], the runs with a
    step over :data:`BOUND_MS`; and the totals. Unreadable summaries are skipped."""
    methods: dict[str, dict] = {}
    for path in sorted(Path(root).rglob("summary.json")):
        try:
            s = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        m = methods.setdefault(s.get("method_label") or s.get("method", "?"), {
            **{k: 0 if k in ("runs", "steps") else 0.0 for k in _TOTALS},
            **dict.fromkeys(_MAXIMA, 0.0), "runs_over_bound": 0})
        wall = s.get("wall_s") or {}
        m["runs"] += 1
        m["steps"] += int(s.get("steps") or 0)
        m["controller_s"] += sum(s.get("step_compute_ms") or []) / 1e3
        m["simulator_s"] += float(wall.get("simulator") or 0.0)
        m["episode_s"] += float(wall.get("episode") or 0.0)
        m["build_s"] += float(wall.get("build") or 0.0)
        run_maxima = {field: float(s.get(key) or 0.0) for field, key in _MAXIMA_FROM.items()}
        for field, value in run_maxima.items():
            m[field] = max(m[field], value)
        m["runs_over_bound"] += int(run_maxima["max_step_ms"] > BOUND_MS)
    total = {k: sum(m[k] for m in methods.values()) for k in _TOTALS}
    return {"methods": {k: _rounded(m) for k, m in methods.items()}, "total": _rounded(total)}


def _rounded(d: dict) -> dict:
    return {k: round(v, 3) if isinstance(v, float) else v for k, v in d.items()}


def merged_bounds(profiles: list[dict]) -> dict:
    """Per method, over the repeats: the longest step (wall, CPU), the largest run p99, the runs
    and the runs with a step over the bound."""
    out: dict[str, dict] = {}
    for prof in profiles:
        for name, m in prof["methods"].items():
            o = out.setdefault(name, {"runs": 0, "runs_over_bound": 0, **dict.fromkeys(_MAXIMA,
                                                                                       0.0)})
            o["runs"] += m["runs"]
            o["runs_over_bound"] += m["runs_over_bound"]
            for k in _MAXIMA:
                o[k] = max(o[k], m.get(k, 0.0))
    return out


def time_sweep(name: str, cores: int, repeats: int = 1, timeout: float = 4 * 3600.0) -> dict:
    """``SWEEPS[name]`` run ``repeats`` times, each into a fresh temporary folder: every wall
    time, their median, the profile of each run, the bounds over all of them and Hydra's
    per-job cost; the tables' rebuild time from the logs (Table 1's last step) of the last."""
    sweep = SWEEPS[name]
    item = {"name": name, "cores": cores, "repeats": [], "profiles": []}
    for _ in range(max(1, repeats)):
        with tempfile.TemporaryDirectory() as tmp:
            run = timed_command(["-m", "tamedpuma.sweep", *sweep.args, f"output_root={tmp}"],
                                timeout)
            item["repeats"].append(run)
            item["profiles"].append(sweep_profile(Path(tmp) / sweep.folder))
            if any(m["runs_over_bound"] for name_, m in item["profiles"][-1]["methods"].items()
                   if name_ in BOUNDED):
                item.setdefault("rechecks", []).extend(recheck(Path(tmp) / sweep.folder, timeout))
            if name == "table1":
                tables = timed_command(["-m", "analysis.tables", str(Path(tmp) / "table1")],
                                       timeout)
                item["tables_wall_s"] = tables["wall_s"]
    walls = [r["wall_s"] for r in item["repeats"]]
    failed = [r for r in item["repeats"] if r["returncode"] != 0]
    item.update(command=item["repeats"][0]["command"], wall_s=statistics.median(walls),
                walls_s=walls, returncode=failed[0]["returncode"] if failed else 0,
                bounds=merged_bounds(item["profiles"]),
                profile=item["profiles"][walls.index(statistics.median_low(walls))])
    item["job"] = job_overheads()
    return item


def recheck(root: Path, timeout: float) -> list[dict]:
    """Each step over :data:`BOUND_MS` of a bounded method below ``root`` re-run with
    ``python -m tamedpuma.recheck`` (the same run, the same states: a step the controller's work
    makes slow is slow again, one the machine took is not): ``{method, step, wall_ms, cpu_ms,
    least_wall_ms, reproduced}`` per step; a recheck that fails gives one entry saying so."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "recheck.json"
        run = timed_command(["-m", "tamedpuma.recheck", str(root), "--bound", str(BOUND_MS),
                             "--methods", *BOUNDED, "--json", str(out)], timeout)
        try:
            found = json.loads(out.read_text())
        except (OSError, ValueError):
            return [{"error": run.get("error") or "no verdicts written"}]
    keys = ("method", "step", "wall_ms", "cpu_ms", "least_wall_ms", "reproduced")
    return [{k: v.get(k) for k in keys} | {"run": Path(v.get("run_dir", "")).name} for v in found]


def verdict_line(item: dict) -> str:
    """The target's verdict: the median wall time per target run count, with the profile of the
    median repeat in words (where the cores' time went)."""
    sweep = SWEEPS[item.get("name", "table1")]
    wall, cores = item["wall_s"], item.get("cores") or 1
    tot = (item.get("profile") or {}).get("total") or {}
    runs = tot.get("runs") or sweep.target_runs
    per_target = wall * sweep.target_runs / runs
    met = item.get("returncode") == 0 and per_target <= sweep.target_s
    walls = item.get("walls_s") or [wall]
    each = ""
    if len(walls) > 1:
        each = f"median of {len(walls)}: {', '.join(f'{w:.0f}' for w in walls)} s; "
    by = f"; measured by {item['measured_by']}" if item.get("measured_by") else ""
    head = (f"- {sweep.title} ≤ {sweep.target_s / 60:.0f} minutes per {sweep.target_runs} runs "
            f"on {cores} cores: **{'met' if met else 'not met'}** ({each}{wall:.0f} s wall "
            f"for {runs} runs, {per_target:.0f} s per {sweep.target_runs}, exit "
            f"{item['returncode']}{by}).")
    if not tot.get("runs"):
        return head
    return head + " " + _where_it_went(item, tot, wall, cores)


def _where_it_went(item: dict, tot: dict, wall: float, cores: int) -> str:
    capacity = wall * cores
    episodes, build, ctrl = tot["episode_s"], tot["build_s"], tot["controller_s"]
    sim = tot.get("simulator_s", 0.0)
    job = item.get("job") or {}
    compose = job.get("compose_s", float("nan"))
    typing = job.get("typing_s", float("nan"))
    tables = item.get("tables_wall_s")
    rebuild = (f", rebuilding the tables from the {tot['runs']} logs at the end takes "
               f"{tables:.0f} s on {cores} cores" if tables is not None else "")
    return (f"Of the {cores} cores × {wall:.0f} s = {capacity:.0f} core-s, the {tot['runs']} "
            f"runs' episodes took {episodes:.0f} s ({tot['steps']} steps: the controllers "
            f"{ctrl:.0f} s, the simulator's steps (PyBullet's physics and the next observation) "
            f"{sim:.0f} s, the loop's state reads, metrics and recorders "
            f"{episodes - ctrl - sim:.0f} s), their set-up (config typing, model, scenario, "
            f"controller) {build:.0f} s (the schema's typing {typing:.2f} s a run), and the "
            f"other {capacity - episodes - build:.0f} s went to the sweep's "
            f"own work and idle cores: Hydra composes every job's config in its worker "
            f"({compose:.2f} s a job, {compose * tot['runs']:.0f} core-s in all){rebuild}, "
            f"and the rest is job files, worker dispatch, the models check and the cores' idle "
            f"time at the start and the end. The episodes alone on {cores} cores need "
            f"{episodes / cores:.0f} s.")


def bound_line(items: list[dict]) -> str | None:
    """The step-bound verdict over every run of every timed sweep: no step over BOUND_MS for the
    bounded methods, every run's p99 within P99_MS for FPM and CPM; the others' longest step."""
    items = [it for it in items if it and it.get("bounds")]
    if not items:
        return None
    merged = merged_bounds([{"methods": it["bounds"]} for it in items])
    over = {m: b for m, b in merged.items() if m in BOUNDED and b["runs_over_bound"]}
    p99 = {m: b for m, b in merged.items() if m in P99_BOUNDED and b["max_p99_ms"] > P99_MS}
    met = not over and not p99 and all(m in merged for m in BOUNDED)
    where = " and ".join(f"{SWEEPS[it.get('name', 'table1')].title} ×{len(it['walls_s'])}"
                         for it in items)
    runs = sum(b["runs"] for b in merged.values())

    def longest(names):
        return ", ".join(f"{m} {merged[m]['max_step_ms']:.1f} ms (CPU "
                         f"{merged[m]['max_step_cpu_ms']:.1f})" for m in names if m in merged)

    others = [m for m in sorted(merged) if m not in BOUNDED]
    p99_worst = ", ".join(f"{m} {merged[m]['max_p99_ms']:.2f} ms (CPU "
                          f"{merged[m]['max_p99_cpu_ms']:.2f})" for m in P99_BOUNDED
                          if m in merged)
    line = (f"- No controller step over {BOUND_MS:.0f} ms for {', '.join(BOUNDED)}, every run's "
            f"p99 ≤ {P99_MS:.0f} ms for {' and '.join(P99_BOUNDED)} ({where}: {runs} runs, "
            f"every step as its summary records it): **{'met' if met else 'not met'}**. "
            f"Longest step: {longest(BOUNDED)}; largest run p99: {p99_worst}.")
    if over:
        line += " Runs with a step over the bound: " + ", ".join(
            f"{m} {b['runs_over_bound']} of {b['runs']}" for m, b in over.items()) + "."
        line += _recheck_words([r for it in items for r in it.get("rechecks") or []])
    if others:
        line += f" Not bounded (reported): {longest(others)}."
    return line


def _recheck_words(rechecks: list[dict]) -> str:
    """What the re-runs of the slow steps say (``python -m tamedpuma.recheck``)."""
    if not rechecks:
        return ""
    failed = [r["error"] for r in rechecks if "error" in r]
    steps = [r for r in rechecks if "error" not in r]
    mine = [r for r in steps if r.get("reproduced")]
    words = (f" Re-run at the same states (`python -m tamedpuma.recheck`), {len(mine)} of "
             f"{len(steps)} such steps were slow again (the controller's work)")
    if steps and not mine:
        fast = max(r["least_wall_ms"] or 0.0 for r in steps)
        words += (f"; at most {fast:.2f} ms there, so the time was the machine's (another "
                  "process, or the hypervisor, which a guest counts as the running thread's "
                  "CPU time too)")
    return words + (f"; a recheck failed: {failed[0]}" if failed else "") + "."


def method_table(item: dict | None) -> list[str]:
    """Markdown: the caption and the per-method table of the median repeat's profile."""
    prof = (item or {}).get("profile") or {}
    tot = prof.get("total") or {}
    if not tot.get("runs"):
        return []
    sweep = SWEEPS[item.get("name", "table1")]
    episodes = tot["episode_s"]
    lines = ["", f"{sweep.title} ({item['wall_s']:.0f} s), where its time went, per method "
             "(from the runs' `summary.json`: the controller is the sum of its per-step times, "
             "the episode also holds PyBullet, state reads and recorders, the set-up builds "
             "config, model, scenario and controller; the longest step over every repeat):", "",
             "| method | runs | steps | controller [s] | ms per step | simulator [s] | "
             "episodes [s] | set-up [s] | share of the episodes | longest step [ms] |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    bounds = item.get("bounds") or {}
    for name, m in sorted(prof["methods"].items(), key=lambda kv: -kv[1]["episode_s"]):
        per = 1e3 * m["controller_s"] / m["steps"] if m["steps"] else float("nan")
        share = m["episode_s"] / episodes if episodes else float("nan")
        top = (bounds.get(name) or m).get("max_step_ms", float("nan"))
        lines.append(f"| {name} | {m['runs']} | {m['steps']} | {m['controller_s']:.0f} | "
                     f"{per:.2f} | {m.get('simulator_s', 0.0):.0f} | {m['episode_s']:.0f} | "
                     f"{m['build_s']:.0f} | {100 * share:.0f}% | {top:.2f} |")
    return lines
