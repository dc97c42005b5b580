"""The benchmark's report: the "## Controller step" section of BENCHMARKS.md, from the saved
``benchmarks/bench.json`` alone (so ``--render`` rewrites it without measuring)."""

from __future__ import annotations

from tamedpuma.app import bench_runs, bench_sweeps
from tamedpuma.app.bench_baseline import label
from tamedpuma.app.bench_fabrics import code_line

#: the timed sweeps a report may hold (:mod:`tamedpuma.app.bench_sweeps`), in their order
SWEEP_KEYS = tuple(bench_sweeps.SWEEPS)

SECTION = "Controller step"
#: The speed targets: median [ms] per (method, obstacle count).
TARGET_MS = {("fpm", 2): 0.2, ("cpm", 2): 0.3, ("fpm", 1000): 0.6, ("cpm", 1000): 0.8,
             ("fabrics", 2): 0.05, ("fabrics", 1000): 0.2, ("modulation_ik", 2): 1.0,
             ("fabrics+numpy", 2): 0.05, ("fabrics+numpy", 1000): 0.2,
             ("fpm+numpy", 2): 0.2, ("fpm+numpy", 1000): 0.6}
#: The paper's laptop figures [ms] (i7-12700H): Table 1 (2 obstacles) and the 1000-obstacle claim.
PAPER_MS = {("puma", 2): 4.41, ("modulation_ik", 2): 7.08, ("fabrics", 2): 0.39,
            ("fpm", 2): 5.22, ("cpm", 2): 6.55, ("fpm", 1000): 5.9, ("cpm", 1000): 7.0,
            ("modulation_ik", 1000): 3.5e3}

#: Why a target is out of reach where the profile alone does not say it.
WHY = {
    "fabrics": "All of it is kinematics plus the fused fabric: about 20 pinocchio and 60 numpy "
               "calls of ~0.5 µs each at 2 obstacles; at 1000 obstacles one pass of ~10 calls "
               "over the 5000 pairs' distances, then rows, kernel and products of the pairs "
               "within the activation distance x_a only (~2% of them on the bench's states: "
               "`fused.LayoutBuffers._gathered_pair_rows`; the others have metric 0). "
               "Where numba is installed the kinematics and that pass, the kernel and the "
               "products are compiled (`fabric.kernel: auto`); `fabrics+numpy` computes the "
               "fabric with the numpy reference.",
    "fpm": "Kinematics, fabric and network are the vanilla costs above; the rest is FPM's "
           "forcing (PUMA's obstacle-free pull, the directional metric, the "
           "weighted pullback, the control-rate barrier step over the barrier rows "
           "within the activation distance, the far pairs bounded by `discrete.FarRows`), "
           "each a few small-array numpy calls; at 1000 obstacles the fabric's pass over the "
           "5000 pairs' distances. "
           "What is left at 2 obstacles is per-call overhead spread over ~290 function calls "
           "(cProfile; no part above the network's and the fabric's ~30 µs; where numba is "
           "installed the network's encoder, decoder and backward pass are one compiled call "
           "each, `puma/single_kernels.py`); the "
           "`+numpy` variant computes the fabric with the numpy reference instead of the "
           "compiled kernels.",
    "cpm": "As FPM, plus ψ and ∂ψ (the rest row of the network's pass and a hand-written "
           "backward pass) and the regulator.",
    "modulation_ik": "The IK solve (SNOPT through Drake, one program per world reused by "
                     "every solve, SNOPT's major print level 0) is the step: SNOPT's own ~20 "
                     "evaluations of Drake's kinematics and signed-distance query are ~1 ms "
                     "of it on this machine, which no change that keeps its answers can "
                     "remove; the modulation, the network, the problem's checks and the "
                     "distance check of the answer are the rest (~0.2 ms).",
}


def fmt(x: float) -> str:
    return f"{x:.3f}" if x < 10 else f"{x:.0f}"


def ratio(x: float) -> str:
    return f"{x:.1f}×" if x < 10 else f"{x:.0f}×"


def loads(m: dict, key: str) -> str:
    values = m.get(key)
    return " / ".join(f"{x:.2f}" for x in values) if values else "?"


def profile(report: dict, method: str, n: int, top: int = 4) -> str:
    """The largest parts of ``method``'s step at ``n`` obstacles (the parts table), in words."""
    rows = [r for r in report.get("parts", []) if r["method"] == method
            and r["n_obstacles"] == n]
    step = next((r["us"] for r in rows if r["part"] == "step"), None)
    rows = sorted((r for r in rows if r["part"] != "step"), key=lambda r: -r["us"])[:top]
    if not rows:
        return ""
    where = ", ".join(f"{r['part']} {r['us']:.0f} µs" for r in rows)
    whole = f"the step timed alone {step:.0f} µs; " if step else ""
    return f" Profile at {n} obstacles ({whole}largest parts): {where}."


def controller_targets(report: dict) -> list[str]:
    """Each controller target: met, or its figure and the profile that explains it."""
    by = {(r["method"], r["n_obstacles"]): r for r in report.get("controller", [])}
    out = []
    for (method, n), target in TARGET_MS.items():
        row = by.get((method, n))
        if row is None:
            continue
        med, p10 = row["median_ms"], row["p10_ms"]
        faster = f", {ratio(row['speedup'])} faster than before" if "speedup" in row else ""
        if med <= target:
            out.append(f"- {method}, {n} obstacles, median ≤ {target} ms: **met** "
                       f"({fmt(med)} ms{faster}).")
            continue
        verdict = ("met at p10, not at the median (the shared machine's load)"
                   if p10 <= target else "not met")
        base = method.partition("+")[0]
        out.append(f"- {method}, {n} obstacles, median ≤ {target} ms: **{verdict}**: "
                   f"{fmt(med)} ms (p10 {fmt(p10)}){faster}."
                   + profile(report, method, n) + (f" {WHY[base]}" if base in WHY else ""))
    return out


def recorder_target(rec: str, r: dict) -> str:
    """The recorder target (≤ 10% of the episode) of one recorder's row."""
    over, share = r["overhead_vs_none"], r.get("recorder_own_share")
    if share is None:
        return (f"- recorder {rec} adds ≤ 10% to the episode: "
                f"**{'met' if over <= 0.10 else 'not met'}** ({100 * over:+.1f}%).")
    parts = ", ".join(f"{k.replace('_', ' ')} {1e6 * v / r['steps']:.0f} µs"
                      for k, v in r["recorder_own_s"].items())
    verdict = "met" if share <= 0.10 and over <= 0.10 else (
        "not met" if share > 0.10 else "met by its own time, not by the wall time")
    return (f"- recorder {rec} adds ≤ 10% to the episode: **{verdict}**: its own "
            f"time is {100 * share:+.1f}% of the rest of the episode (per step: "
            f"{parts}); the wall time vs recorder=none {100 * over:+.1f}% (the "
            f"difference of two medians of a loaded machine: noisier).")


def realtime_target(none: dict) -> str:
    """FPM episodes ≥ 50× real time, with the physics bound when missed."""
    rtf = none["realtime_factor"]
    line = (f"- FPM episodes ≥ 50× real time: **{'met' if rtf >= 50 else 'not met'}** "
            f"({rtf:.1f}× with recorder=none).")
    if rtf < 50 and "physics_s" in none:
        phys, ctrl, sim_s = none["physics_s"], none["controller_s"], none["sim_s"]
        line += (f" Bound: PyBullet's physics alone (1 ms substeps, unchanged: they decide "
                 f"every result) takes {phys:.3f} s, {sim_s / phys:.0f}× real time at "
                 f"most; with the controller's {ctrl:.3f} s inside the episode "
                 f"({1e3 * ctrl / none['steps']:.3f} ms per step, slower than the hot-loop "
                 f"step above: the physics evicts its caches) "
                 f"{sim_s / (phys + ctrl):.0f}× at most, before any state read or record.")
    return line


def target_lines(report: dict) -> list[str]:
    """The speed targets, each: met, or its figure and the profile that explains it."""
    out = controller_targets(report)
    eps = {r["recorder"]: r for r in report.get("episodes", [])}
    if "none" in eps:
        out += [recorder_target(rec, r) for rec, r in eps.items() if rec != "none"]
        out.append(realtime_target(eps["none"]))
    training = bench_runs.training_target_line(report.get("training") or [])
    out += [training] if training else []
    out += [bench_sweeps.verdict_line(report[k]) for k in SWEEP_KEYS if report.get(k)]
    bound = bench_sweeps.bound_line([report.get(k) for k in SWEEP_KEYS])
    out += [bound] if bound else []
    if not out:
        return []
    return ["", "Speed targets (medians of this run; the machine is shared, so the p10 "
            "is given too):", "", *out]


def _controller_head(report: dict) -> list[str]:
    lines = [f"## {SECTION}", "",
             f"Regenerated by `{report.get('command', 'python -m tamedpuma.bench')}` (figures: "
             f"`benchmarks/bench.json`, {report['date']}). One whole `controller.step` "
             "(kinematics, network, fabric, regulator, pullback, solve) on fixed states near the "
             "default tomato start, each method built as the sweep builds it (models: "
             f"{report.get('models', 'the sweep defaults')}); obstacles seeded, clear of the arm.",
             ""]
    base = report.get("baseline")
    if base:
        where = base.get("tree") or base.get("rev")  # a report from before --baseline DIR: rev
        lines += [f"\"before\": the same cells in {label(base)} (`--baseline {where}`), "
                  "in the same run: one timing worker per source tree running its own timing "
                  "code, blocks of at most 100 calls alternating between them (order swapped "
                  "every round), so both sides see the same load; with both numbers and their "
                  "ratio = before median / median.", ""]
    return lines


def _controller_row(row: dict, base) -> str:
    key = (row["method"], row["n_obstacles"])
    target, paper = TARGET_MS.get(key), PAPER_MS.get(key)
    cells = (f"| {row['method']} | {row['n_obstacles']} | {fmt(row['median_ms'])} | "
             f"{fmt(row['p10_ms'])} | {fmt(row['p90_ms'])} | {row['n_calls']} | "
             f"{fmt(row['first_call_ms'])} |")
    if base:
        cells += (f" {fmt(row['before_median_ms'])} | {fmt(row['before_p10_ms'])} | "
                  f"{fmt(row['before_p90_ms'])} | {ratio(row['speedup'])} |"
                  if "speedup" in row else " — | — | — | — |")
    met = "—"
    if target is not None:  # under load the median is inflated; p10 ≈ the unloaded cost
        met = (f"≤ {target}: median {'✓' if row['median_ms'] <= target else '✗'}, "
               f"p10 {'✓' if row['p10_ms'] <= target else '✗'}")
    return cells + f" {met} | {paper if paper else '—'} |"


def controller_table(report: dict) -> list[str]:
    """The heading, the note on the baseline and the table of the controller cells."""
    base = report.get("baseline")
    head = "| method | obstacles | median [ms] | p10 [ms] | p90 [ms] | calls | first call [ms] "
    rule = "|---|---:|---:|---:|---:|---:|---:|"
    if base:
        head += "| before: median [ms] | p10 [ms] | p90 [ms] | ratio "
        rule += "---:|---:|---:|---:|"
    lines = _controller_head(report) + [head + "| target [ms] | paper [ms] |", rule + "---:|---:|"]
    lines += [_controller_row(row, base) for row in report["controller"]]
    lines += [f"| {row['method']} | — | not measured: {row['error']} |"
              for row in report.get("errors", [])]
    return lines


def parts_table(report: dict) -> list[str]:
    """Where the step's time goes, part by part."""
    if not report.get("parts"):
        return []
    lines = ["", "Where the time goes (one state per obstacle count, each part the controller "
             "exposes timed alone: the median of 1000 calls in 10 rounds interleaved with the "
             "other parts [µs]; \"reference network\": the same with the network's reference "
             "path, the batched numpy copy `puma/fastnet.py`, selected by "
             "`primitive.single = None`; the step's remainder is the method's own arithmetic "
             "(for FPM/CPM the forcing, the pullback through the metric and the control-rate "
             "filters) and log scalars, and a step run whole is slower than its parts run "
             "alone, each in a hot loop):", "",
             "| method | obstacles | part | [µs] | reference network [µs] |",
             "|---|---:|---|---:|---:|"]
    for row in report["parts"]:
        ref = row.get("reference_us")
        lines.append(f"| {row['method']} | {row['n_obstacles']} | {row['part']} | "
                     f"{row['us']:.1f} | {f'{ref:.1f}' if ref is not None else ''} |")
    return lines + [
        "", "At a few obstacles every part is per-call overhead, not arithmetic: the "
        "kinematics are about 20 pinocchio calls (one per frame quantity of the end "
        "effector and each body sphere), the fabric about 60 numpy calls on "
        "preallocated buffers (`fabrics/fused.py`), the network about 25 "
        "(`puma/single.py`: constants folded into the weights; with ψ, CPM reuses "
        "the rest-state row of the same pass and adds a hand-written backward pass). "
        "The kinematics are computed once per step and shared by the network's task "
        "map, the null-space term and the fabric."]


def _episode_intro(eps: list[dict], ebase) -> list[str]:
    before = (f"; \"before\": the same in {label(ebase)}, interleaved with these, ratio = speed "
              "/ speed before" if ebase else "")
    return ["", "Episode speed (default tomato scenario, "
            f"{eps[0]['method']}, through the sweep's `run_one` in a worker process, "
            f"median of {eps[0]['repeats']} episodes per row after one warm-up, rows "
            "interleaved round by round; \"episode\": summary.json's `wall_s.episode` (the "
            "simulator's set-up, controller and recorders from open to close), \"run\": the "
            "whole `run_one` (also building config, model and world, writing summary.json); "
            "target: recorders ≤ 10% overhead, FPM ≥ 50× real time" + before + "):", ""]


def _episode_row(r: dict, ebase) -> str:
    cells = (f"| {r['recorder']} | {r['steps']} | {r['sim_s']:.2f} | "
             f"{r['wall_s']:.3f} ({r.get('wall_p10_s', r['wall_s']):.3f}–"
             f"{r.get('wall_p90_s', r['wall_s']):.3f}) | "
             f"{r['realtime_factor']:.1f} | {100 * r['overhead_vs_none']:+.1f}% | "
             f"{r.get('run_wall_s', float('nan')):.3f} |")
    if ebase:
        cells += (f" {r['before_steps']} | {r['before_wall_s']:.3f} | "
                  f"{r['before_realtime_factor']:.1f} | "
                  f"{100 * r['before_overhead_vs_none']:+.1f}% | "
                  f"{ratio(r['speedup'])} |" if "speedup" in r else " — | — | — | — | — |")
    return cells


def episode_table(report: dict) -> list[str]:
    """Episode speed per recorder setting, and where recorder=none's time goes."""
    eps, ebase = report.get("episodes"), report.get("episode_baseline")
    if not eps:
        return []
    head = ("| recorder | steps | simulated [s] | episode wall [s] (p10–p90) | × real time "
            "| overhead vs none | run wall [s] ")
    rule = "|---|---:|---:|---:|---:|---:|---:|"
    if ebase:
        head += "| before: steps | episode wall [s] | × real time | overhead | ratio "
        rule += "---:|---:|---:|---:|---:|"
    lines = _episode_intro(eps, ebase) + [head + "|", rule]
    lines += [_episode_row(r, ebase) for r in eps]
    none = next((r for r in eps if r["recorder"] == "none" and "physics_s" in r), None)
    if none:
        rest = none["wall_s"] - none["physics_s"] - none["controller_s"]
        lines += ["", "Where the episode's time goes (recorder=none, medians): the simulator "
                  f"alone {none['physics_s']:.3f} s (the same {none['steps']} steps with a "
                  "zero command and no state reads: "
                  f"{none['sim_s'] / none['physics_s']:.0f}× real time at most, PyBullet's "
                  "1 ms substeps), the controller "
                  f"{none['controller_s']:.3f} s "
                  f"({1e3 * none['controller_s'] / none['steps']:.3f} ms per step), the "
                  f"rest {rest:.3f} s (the simulator's set-up and state reads, "
                  "contacts, the step records, metrics)."]
    return lines


def machine_line(report: dict) -> list[str]:
    m = report["machine"]
    return ["", f"Machine: {m['cpu_model']}, {m['cores']} cores, Python {m['python']}, "
            f"numpy {m['numpy']}"
            + (f", numba {m['numba']} (the `fast` extra)" if m.get("numba") else
               ", numba not installed")
            + "; load average (1 / 5 / 15 min) "
            f"{loads(m, 'load_averages_start')} at the start, "
            f"{loads(m, 'load_averages_end')} at the end (a shared machine inflates every "
            "figure; compare ratios measured in one run).", "", code_line(m), ""]


def markdown_section(report: dict) -> str:
    """The "## Controller step" section of BENCHMARKS.md, from ``report`` alone."""
    lines = controller_table(report) + parts_table(report) + episode_table(report)
    lines += target_lines(report)
    lines += bench_runs.training_lines(report.get("training") or [],
                                       report.get("training_measured_by"))
    for key in SWEEP_KEYS:  # each timed sweep's per-method table
        lines += bench_sweeps.method_table(report.get(key))
    return "\n".join(lines + machine_line(report))
