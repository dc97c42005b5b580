"""The benchmark's measurements in worker processes: controller cells side by side in two source
trees, and whole episodes per recorder setting.

Each worker is ``python -m tamedpuma.app.bench_worker KIND`` run with its source tree first on
``PYTHONPATH`` (:mod:`tamedpuma.app.bench_worker` holds the protocol), so that "now" and a
baseline checkout are each measured by their own code, and blocks of work alternate between them
so that a change of the machine's load hits every side alike.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tamedpuma.app.bench_timing import cell, method_overrides, warm_calls

#: Recorder settings timed, as sweep overrides.
RECORDERS = {"none": ["recorder=none"], "mcap": ["recorder=mcap"],
             "rerun": ["recorder=none", "recorder.rerun=true"], "mcap+rerun": ["recorder=default"]}
WORKER_MODULE = "tamedpuma.app.bench_worker"


class Worker:
    """One worker process (``kind``: timing or episode) in source tree ``tree``."""

    def __init__(self, tree: Path, kind: str, setup: dict):
        self.log = tempfile.TemporaryFile(mode="w+")
        path = os.pathsep.join(p for p in (str(tree), os.environ.get("PYTHONPATH")) if p)
        self.proc = subprocess.Popen([sys.executable, "-m", WORKER_MODULE, kind], cwd=tree,
                                     env={**os.environ, "PYTHONPATH": path},
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self.log, text=True)
        self.model = self.ask(setup).get("model")

    def ask(self, cmd: dict) -> dict:
        """Send one command; its answer."""
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        return self.read()

    def read(self) -> dict:
        """The worker's next answer (RuntimeError with its last line of stderr if it ended)."""
        line = self.proc.stdout.readline()
        if not line:
            self.proc.wait()
            self.log.seek(0)
            lines = [x for x in self.log.read().splitlines() if x.strip()]
            raise RuntimeError(lines[-1] if lines else f"worker exit {self.proc.returncode}")
        return json.loads(line)

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write('{"cmd": "quit"}\n')
                self.proc.stdin.close()
            except OSError:
                pass
            self.proc.wait(timeout=30)
        self.log.close()


def _close_all(workers: dict) -> None:
    for w in workers.values():
        w.close()


def _blocks(workers: dict, calls: int, budget_s: float, first: dict, block: int) -> dict:
    """Timed calls [s] per side: blocks of at most ``block`` calls alternating between the
    sides (order swapped every round), each side until ``calls`` calls or ``budget_s``."""
    got = {side: [] for side in workers}
    spent = dict.fromkeys(workers, 0.0)
    order = list(workers)
    while any(len(got[s]) < calls and spent[s] < budget_s for s in order):
        for side in order:
            if len(got[side]) >= calls or spent[side] >= budget_s:
                continue
            per = (spent[side] / len(got[side])) if got[side] else first[side] / 1e3
            k = int(max(1, min(block, calls - len(got[side]),
                               (budget_s - spent[side]) / max(per, 1e-6))))
            t0 = time.perf_counter()
            got[side] += workers[side].ask({"cmd": "time", "calls": k, "warm": 0})["s"]
            spent[side] += time.perf_counter() - t0
        order.reverse()
    return got


def time_side_by_side(label: str, counts, calls: int, budget_s: float, trees: dict,
                      overrides=(), block: int = 100) -> dict[str, list[dict]]:
    """The controller cells of ``label`` in each source tree of ``trees`` ({side: path}),
    measured as :func:`tamedpuma.app.bench_timing.time_controller` does but interleaved block
    by block. The "before" side is timed without the variant's overrides (the variant's
    previous default). Returns {side: rows}."""
    method, extra = method_overrides(label)
    workers = {}
    try:
        for side, tree in trees.items():
            variant = [] if side == "before" else extra
            workers[side] = Worker(Path(tree), "timing", {
                "method": method, "seed": 0, "overrides": [*variant, *overrides]})
        rows = {side: [] for side in trees}
        for n in counts:
            first = {side: w.ask({"cmd": "reset", "n": n})["first_s"] * 1e3
                     for side, w in workers.items()}
            for side, w in workers.items():
                w.ask({"cmd": "time", "calls": 0, "warm": warm_calls(first[side], budget_s)})
            got = _blocks(workers, calls, budget_s, first, block)
            for side in trees:
                rows[side].append(cell(label, n, np.array(got[side]) * 1e3, first[side],
                                       workers[side].model))
        return rows
    finally:
        _close_all(workers)


def _episode_runs(workers: dict, repeats: int) -> dict:
    """``repeats`` rounds of one episode per (recorder, side), the order rotated every round;
    {(side, recorder): [answers]} (recorder=none also with the simulator alone)."""
    for w in workers.values():  # warm-up: imports, model file, first-call allocations
        w.ask({"cmd": "run", "recorder": "none"})
    got = {(side, rec): [] for side in workers for rec in RECORDERS}
    recorders, sides = list(RECORDERS), list(workers)
    for r in range(repeats):
        for rec in recorders[r % len(recorders):] + recorders[:r % len(recorders)]:
            for side in (sides if r % 2 == 0 else sides[::-1]):
                run = workers[side].ask({"cmd": "run", "recorder": rec,
                                         "physics": rec == "none"})
                if rec == "none":
                    run.update(workers[side].read())
                got[(side, rec)].append(run)
    return got


def _median(runs, key) -> float:
    return float(np.median([x[key] for x in runs]))


def episode_row(method: str, rec: str, runs: list[dict]) -> dict:
    """One row of the episode table from the answers of its runs (medians)."""
    wall = np.array([x["loop_s"] for x in runs])
    sim_s = float(runs[-1]["sim_s"])
    row = {"method": method, "recorder": rec, "steps": runs[-1]["steps"],
           "sim_s": round(sim_s, 3), "wall_s": round(float(np.median(wall)), 4),
           "wall_p10_s": round(float(np.percentile(wall, 10)), 4),
           "wall_p90_s": round(float(np.percentile(wall, 90)), 4),
           "run_wall_s": round(_median(runs, "wall_s"), 4),
           "realtime_factor": round(sim_s / float(np.median(wall)), 1),
           "controller_s": round(_median(runs, "controller_s"), 4), "repeats": len(runs)}
    parts = sorted({k for x in runs for k in x.get("own", {})})
    if parts:  # the recorders' own time (medians [s]) and its share of the rest
        own = {k: float(np.median([x["own"].get(k, 0.0) for x in runs])) for k in parts}
        total = float(np.median([sum(x["own"].values()) for x in runs]))
        row["recorder_own_s"] = {k: round(v, 4) for k, v in own.items()}
        row["recorder_own_share"] = round(total / max(float(np.median(wall)) - total, 1e-9), 4)
    if rec == "none":
        row["physics_s"] = round(_median(runs, "physics_s"), 4)
    return row


def _with_before(rows: list[dict], before: list[dict]) -> list[dict]:
    """``before_*`` figures and ``speedup`` (ratio of the speeds, simulated s per wall s)."""
    for row, old in zip(rows, before):
        for key in ("steps", "sim_s", "wall_s", "realtime_factor", "overhead_vs_none"):
            row[f"before_{key}"] = old[key]
        row["speedup"] = round(old["wall_s"] / old["sim_s"] * row["sim_s"] / row["wall_s"], 3)
    return rows


def time_episodes(method: str = "fpm", repeats: int = 3, overrides=(),
                  trees: dict | None = None) -> list[dict]:
    """Episode speed: one default-scenario episode of ``method`` per recorder setting
    (:data:`RECORDERS`), ``repeats`` times, through the sweep's own ``run_one`` in a worker
    process per source tree (``trees`` = {side: path}, default {"now": this checkout}; with a
    "before" side its figures are attached as ``before_*`` and ``speedup``). Every worker runs
    one untimed episode first; then rounds of one episode per (recorder, side).

    Per row (medians): ``wall_s`` = the episode (simulator set-up, controller, recorders, as
    summary.json's ``wall_s.episode``), ``run_wall_s`` = the whole ``run_one``,
    ``realtime_factor`` = simulated s per episode wall s, ``overhead_vs_none`` = episode wall /
    the same side's ``recorder=none`` − 1."""
    from tamedpuma.app.bench_fabrics import ROOT

    trees = trees or {"now": ROOT}
    workers = {}
    try:
        for side, tree in trees.items():
            workers[side] = Worker(Path(tree), "episode", {
                "method": method, "overrides": list(overrides), "recorders": RECORDERS})
        got = _episode_runs(workers, repeats)
    finally:
        _close_all(workers)
    rows = {}
    for side in trees:
        rows[side] = [episode_row(method, rec, got[(side, rec)]) for rec in RECORDERS]
        base = next(r["wall_s"] for r in rows[side] if r["recorder"] == "none")
        for r in rows[side]:
            r["overhead_vs_none"] = round(r["wall_s"] / base - 1.0, 4)
    main_side = next(iter(trees))
    if "before" in rows and main_side != "before":
        return _with_before(rows[main_side], rows["before"])
    return rows[main_side]
