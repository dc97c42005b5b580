"""Benchmark: wall time of one full fabric evaluation against the obstacle count.

One evaluation = kinematics (pinocchio FK, Jacobians, J̇q̇ of the end effector and every body
sphere) + all leaves (every body sphere × obstacle pair, joint limits) + goal attractor +
energization + speed control + the linear solves, i.e. exactly what the ``fabrics`` method does per
control step. Obstacles: seeded random spheres (r = 0.05 m) in the workspace, kept at least
``--clearance`` from every body sphere. The same :class:`~tamedpuma.fabrics.Fabric` object serves
every count (there is no build step; its construction time is reported as ``build_ms``).

The reference planner (the GPL ``fabrics`` package by Spahn et al.) is measured live when a Python
that has it is given (``--reference-python`` or ``TAMEDPUMA_REFERENCE_PYTHON``): the script
``reference_fabrics.py`` beside this module runs under that Python on the very states and
obstacles timed here (by default at 2 and 10 obstacles: its build takes 22 s at 100 and 31 min at
1000). Counts not measured live cite the dated figures :data:`CITED_REFERENCE_MS`.

    python -m tamedpuma.bench_fabrics            # writes benchmarks/fabrics.json and BENCHMARKS.md
    python -m tamedpuma.bench_fabrics --no-write # print only
    python -m tamedpuma.bench_fabrics --reference-python /work/venv-ref/bin/python --no-write

Writes the figures (median, p10, p90 [ms], n_calls, machine) to ``benchmarks/fabrics.json`` and
the "Fabrics" section of ``BENCHMARKS.md`` (other sections are left as they are).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tamedpuma.app.config import default_kinematics, load_group
from tamedpuma.fabrics import Fabric, quaternion_to_rotation
from tamedpuma.methods.fabrics import gains_from_config
from tamedpuma.paths import project_root

#: where the benchmark files are written: the checkout holding this package, else (an installed
#: package has no BENCHMARKS.md of its own) the current folder
ROOT = project_root()
COUNTS = (2, 10, 100, 1000)
Q0 = np.array([-0.702, 0.355, -0.016, -1.212, 0.012, -0.502, -0.010])
GOAL_POSITION = np.array([0.58, -0.214, 0.115])
GOAL_QUATERNION = np.array([-0.5459, 0.5806, -0.4112, 0.4426])
TARGET_MS = {2: 0.1, 100: 0.3, 1000: 1.5}
N_STATES = 16  # joint states cycled through by every timing

#: The reference planner (`fabrics` 0.10.0) measured on this machine once, cited where it is not
#: measured live: whole planner per ``compute_action`` call [ms], and its build [s].
CITED_DATE = "2026-11-25"
CITED_SOURCE = "../shared/docs/architecture.md"
CITED_REFERENCE_MS = {2: 0.23, 10: 0.71, 100: 5.1, 1000: 47.0}
CITED_REFERENCE_BUILD_S = {2: 0.3, 10: 1.0, 100: 22.0, 1000: 31 * 60.0}
#: Counts measured live by default: building the reference takes 22 s at 100, 31 min at 1000.
REFERENCE_COUNTS = (2, 10)
REFERENCE_SCRIPT = Path(__file__).with_name("reference_fabrics.py")
REFERENCE_ENV = "TAMEDPUMA_REFERENCE_PYTHON"
#: The reference's rollout sanity check: steps × dt [s] of its own action from the first state.
MOTION_STEPS, MOTION_DT = 2000, 0.01
#: the control period [s] of the reference's PyBullet episode: a default scenario's
EPISODE_DT = 0.02


def code_line(machine: dict) -> str:
    """"Code: `<revision>`." of a report's machine block (reports that predate it: unrecorded)."""
    from tamedpuma.app.provenance import short_revision

    rev = machine.get("code_revision")
    return f"Code: `{short_revision(rev)}`." if rev else "Code: not recorded in this report."


def machine_info() -> dict:
    """CPU model, core count, numpy and BLAS versions, load average, and the code revision
    measured (:func:`tamedpuma.app.models.code_revision`)."""
    from tamedpuma.app.models import code_revision
    from tamedpuma.app.provenance import machine

    cpu = machine()["cpu"]
    blas = "unknown"
    try:
        deps = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
        blas = f"{deps.get('name')} {deps.get('version')}"
    except Exception:  # numpy < 2 or unusual builds
        pass
    info = {
        "cpu_model": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "blas": blas,
        "platform": platform.platform(),
        "OPENBLAS_CORETYPE": os.environ.get("OPENBLAS_CORETYPE"),
        "code_revision": code_revision(),
    }
    if hasattr(os, "getloadavg"):
        info["load_average_1min"] = round(os.getloadavg()[0], 2)
    return info


def random_obstacles(rng, n: int, sphere_centers, sphere_radii, clearance: float):
    """n obstacles (r = 0.05 m) in [-1, 1]×[-1, 1]×[0, 1.5] m, ≥ ``clearance`` from the arm."""
    radius = 0.05
    centers = np.empty((0, 3))
    while len(centers) < n:
        cand = rng.uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 1.5], size=(2 * n, 3))
        gap = (np.linalg.norm(cand[:, None] - sphere_centers[None], axis=-1)
               - sphere_radii[None] - radius)
        centers = np.concatenate((centers, cand[gap.min(axis=1) > clearance]))
    return centers[:n], np.full(n, radius), np.zeros((n, 3))


@dataclass(frozen=True)
class Workload:
    """What every timing of one run evaluates, ours and the reference's alike.

    ``states``: (q [rad], q̇ [rad/s]) pairs cycled through; ``obstacles``: per obstacle count,
    (centers [m] (n, 3), radii [m] (n,), velocities [m/s] (n, 3)).
    """

    states: tuple
    obstacles: dict


def make_workload(kin, counts=COUNTS, clearance: float = 0.15, seed: int = 0) -> Workload:
    """The seeded states near :data:`Q0` and obstacles (≥ ``clearance`` [m] from the arm at Q0)."""
    rng = np.random.default_rng(seed)
    states = tuple((Q0 + rng.normal(scale=0.05, size=Q0.size), rng.normal(scale=0.3, size=Q0.size))
                   for _ in range(N_STATES))
    centers0 = kin.evaluate(Q0, np.zeros(Q0.size)).sphere_centers
    obstacles = {n: random_obstacles(rng, n, centers0, kin.spec.sphere_radii, clearance)
                 for n in counts}
    return Workload(states, obstacles)


def calls_at(n_obstacles: int, calls: int) -> int:
    """Timed calls at one count: ``calls``, a quarter of them (≥ 100) from 1000 obstacles on."""
    return calls if n_obstacles < 1000 else max(calls // 4, 100)


def _stats(ms: np.ndarray) -> dict:
    """Median, p10, p90, mean [ms] of per-call times [ms]."""
    return {"median_ms": round(float(np.median(ms)), 5),
            "p10_ms": round(float(np.percentile(ms, 10)), 5),
            "p90_ms": round(float(np.percentile(ms, 90)), 5),
            "mean_ms": round(float(ms.mean()), 5)}


def time_counts(counts=COUNTS, calls: int = 3000, clearance: float = 0.15, seed: int = 0,
                workload: Workload | None = None, kin=None):
    """Time ``kinematics.evaluate`` + ``Fabric.evaluate`` at each obstacle count.

    ``workload`` (default: :func:`make_workload` with ``clearance`` and ``seed``) holds the states
    and each count's obstacles. Returns (rows, build_ms, kinematics_ms): per count a dict of
    median/p10/p90/mean [ms], n_calls and first_call_ms (the first call at that count, which
    allocates the count's work buffers); the Fabric's construction time [ms]; the median of the
    kinematics alone [ms].
    """
    kin = kin or default_kinematics()
    workload = workload or make_workload(kin, counts, clearance, seed)
    gains = gains_from_config(load_group("method", "fabrics"))
    start = time.perf_counter()
    fabric = Fabric(gains, kin.spec.q_min, kin.spec.q_max)
    build_ms = (time.perf_counter() - start) * 1e3
    goal_r = quaternion_to_rotation(GOAL_QUATERNION)
    states = workload.states
    evaluate = kin.evaluate
    fab_eval, buffers = fabric.evaluate, fabric.buffers()  # the buffers a controller keeps

    def timed(fn, n_calls):
        for i in range(min(200, n_calls)):
            fn(*states[i % len(states)])
        out = np.empty(n_calls)
        for i in range(n_calls):
            q, qd = states[i % len(states)]
            t0 = time.perf_counter()
            fn(q, qd)
            out[i] = time.perf_counter() - t0
        return out * 1e3

    kin_ms = float(np.median(timed(evaluate, calls)))
    rows = []
    for n in counts:
        obs = workload.obstacles[n]

        def one(q, qd, obs=obs):
            return fab_eval(evaluate(q, qd), q, qd, *obs, GOAL_POSITION, goal_r, buffers)

        n_calls = calls_at(n, calls)
        t0 = time.perf_counter()  # the first call at this count allocates its work buffers
        one(*states[0])
        first_ms = (time.perf_counter() - t0) * 1e3
        ms = timed(one, n_calls)
        rows.append({"n_obstacles": n, **_stats(ms), "n_calls": n_calls,
                     "first_call_ms": round(first_ms, 5)})
    return rows, build_ms, kin_ms


# ---- the reference planner, run live under another Python ----------------------------------


def reference_payload(workload: Workload, spec, counts, calls: int,
                      motion_steps: int = MOTION_STEPS, motion_dt: float = MOTION_DT,
                      episode_steps: int = 0) -> dict:
    """The JSON input of ``reference_fabrics.py``: the robot (``spec``, a RobotSpec), the goal,
    the workload's states and, per count in ``counts``, its obstacles and timed-call count; with
    ``episode_steps`` > 0 also an episode of that many control periods in PyBullet, with the
    control period and the simulator's settings of a default run (:func:`episode_settings`)."""
    payload = {
        "urdf_path": str(spec.urdf_path),
        "root_link": spec.link_names[0],
        "ee_link": spec.ee_link,
        "q_min": np.asarray(spec.q_min, float).tolist(),
        "q_max": np.asarray(spec.q_max, float).tolist(),
        "spheres": [{"link": s.link, "radius": float(s.radius)} for s in spec.spheres],
        "goal_position": GOAL_POSITION.tolist(),
        "goal_weight": 1.0,
        "states": [{"q": q.tolist(), "qd": qd.tolist()} for q, qd in workload.states],
        "counts": [{"n_obstacles": n, "centers": workload.obstacles[n][0].tolist(),
                    "radii": workload.obstacles[n][1].tolist(), "n_calls": calls_at(n, calls)}
                   for n in counts],
        "warmup": min(200, calls),
        "motion": {"steps": motion_steps, "dt": motion_dt},
    }
    if episode_steps > 0:
        payload["episode"] = episode_settings(spec, episode_steps)
    return payload


def episode_settings(spec, steps: int) -> dict:
    """The reference's PyBullet episode as a default run sets its world: the scenario's control
    period (``conf/scenario/default.yaml``), the simulator's substep and motor force
    (:class:`~tamedpuma.worlds.settings.SimConfig`), the robot's joints and speed limits."""
    from tamedpuma.worlds.settings import SimConfig

    sim = SimConfig()
    return {"steps": int(steps), "dt": EPISODE_DT, "substep": sim.substep,
            "max_joint_force": sim.max_joint_force, "joint_names": list(spec.joint_names),
            "qd_max": np.asarray(spec.qd_max, float).tolist()}


def reference_timeout(counts) -> float:
    """A generous wall-time limit [s] for building and timing the reference at ``counts``."""
    return 600.0 + 4.0 * float(sum(counts))


def _last_line(text: str) -> str:
    """The last non-empty line of ``text`` (a traceback's is its exception), or "no output"."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else "no output"


def _parse_lines(stdout: str) -> dict:
    """The result lines of ``reference_fabrics.py`` (JSON objects with ``n_obstacles``) by count."""
    live = {}
    for line in stdout.splitlines():
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if isinstance(row, dict) and "n_obstacles" in row:
            live[str(row.pop("n_obstacles"))] = row
    return live


def run_reference(python, payload: dict, timeout: float | None = None):
    """Run ``reference_fabrics.py`` under ``python`` on ``payload``.

    Returns (live, note): the figures per count (str keys, as the script prints them) and None,
    or whatever was measured and a one-line note of what went wrong. Never raises for a missing,
    failing or slow reference Python.
    """
    counts = [c["n_obstacles"] for c in payload["counts"]]
    timeout = reference_timeout(counts) if timeout is None else timeout
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    with tempfile.TemporaryDirectory(prefix="tamedpuma-reference-") as tmp:
        path = Path(tmp) / "workload.json"
        path.write_text(json.dumps(payload))
        try:
            proc = subprocess.run([str(python), str(REFERENCE_SCRIPT), "--input", str(path)],
                                  capture_output=True, text=True, timeout=timeout, env=env)
        except subprocess.TimeoutExpired as exc:
            out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else exc.stdout or ""
            return _parse_lines(out), f"reference timed out after {timeout:.0f} s ({python})"
        except OSError as exc:
            return {}, f"reference not run: {python}: {exc.strerror or exc}"
    live = _parse_lines(proc.stdout)
    if proc.returncode != 0:
        return live, (f"reference failed: {python} exited with code {proc.returncode}: "
                      f"{_last_line(proc.stderr)}")
    missing = [n for n in counts if str(n) not in live]
    if missing:
        return live, f"reference gave no figures for {missing} obstacles ({python})"
    return live, None


def reference_shown(report: dict, n: int):
    """(median [ms], live?) of the reference at ``n`` obstacles: live if measured, else cited, else
    (None, False)."""
    live = report.get("reference_live", {}).get(str(n))
    if live:
        return live["median_ms"], True
    cited = report.get("reference_cited", {}).get("median_ms", {}).get(str(n))
    return cited, False


# ---- the report -------------------------------------------------------------------------------


def cited_block() -> dict:
    """The dated reference figures as they go into the report (str keys)."""
    return {"date": CITED_DATE, "source": CITED_SOURCE,
            "median_ms": {str(k): v for k, v in CITED_REFERENCE_MS.items()},
            "build_s": {str(k): v for k, v in CITED_REFERENCE_BUILD_S.items()}}


def run(counts=COUNTS, calls: int = 3000, clearance: float = 0.15, reference_python=None,
        reference_counts=REFERENCE_COUNTS, seed: int = 0,
        reference_timeout_s: float | None = None, episode_steps: int = 0) -> dict:
    """Time our fabric at ``counts`` and, given ``reference_python``, the reference planner live at
    the ``reference_counts`` among them (same states and obstacles; with ``episode_steps``, also
    driving the robot in PyBullet for that many periods, :func:`episode_settings`). Returns the
    report dict (``benchmarks/fabrics.json``); a reference failure is a one-line
    ``reference_note``."""
    machine = machine_info()
    kin = default_kinematics()
    workload = make_workload(kin, counts, clearance, seed)
    rows, build_ms, kin_ms = time_counts(counts, calls, clearance, seed, workload=workload,
                                         kin=kin)
    live, note = {}, None
    if reference_python:
        wanted = [n for n in dict.fromkeys(reference_counts) if n in workload.obstacles]
        skipped = [n for n in reference_counts if n not in workload.obstacles]
        if wanted:
            payload = reference_payload(workload, kin.spec, wanted, calls,
                                        episode_steps=episode_steps)
            live, note = run_reference(reference_python, payload, reference_timeout_s)
        if skipped:
            extra = f"reference counts {skipped} skipped: not among the timed counts"
            note = f"{note}; {extra}" if note else extra
        if note:
            print(f"bench_fabrics: {note}", file=sys.stderr)
    if hasattr(os, "getloadavg"):
        machine["load_average_1min_end"] = round(os.getloadavg()[0], 2)
    return {
        "benchmark": "one fabric evaluation (kinematics + leaves + energization + speed control "
                     "+ solve), vanilla Fabrics, KUKA iiwa, 5 body spheres",
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "results": rows,
        "build_ms": round(build_ms, 5),
        "kinematics_median_ms": round(kin_ms, 5),
        "reference_python": str(reference_python) if reference_python else None,
        "reference_live": live,
        "reference_note": note,
        "reference_cited": cited_block(),
        "target_median_ms": {str(k): v for k, v in TARGET_MS.items()},
        "machine": machine,
    }


def write(report: dict, root: Path = ROOT) -> tuple:
    """Write ``report`` to ``root``/benchmarks/fabrics.json and its section of BENCHMARKS.md;
    returns the two paths."""
    out = Path(root) / "benchmarks" / "fabrics.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    md = Path(root) / "BENCHMARKS.md"
    update_markdown(md, markdown_section(report))
    return out, md


def _ms(value: float) -> str:
    """A reference time [ms] for the table: 3 decimals below 10 ms, 1 above."""
    return f"{value:.3f}" if value < 10 else f"{value:.1f}"


def _seconds(value: float) -> str:
    """A build time [s] in words: "0.47 s", "22 s", "31 min"."""
    if value >= 120:
        return f"{value / 60:.0f} min"
    return f"{value:.2g} s" if value < 10 else f"{value:.0f} s"


def reference_prose(report: dict) -> list:
    """The paragraph under the table saying which reference figures are live and which cited
    (lines of at most 96 characters)."""
    counts = [row["n_obstacles"] for row in report["results"]]
    live = report.get("reference_live", {})
    cited = report.get("reference_cited", cited_block())
    measured = [n for n in counts if str(n) in live]
    quoted = [n for n in counts if str(n) not in live and str(n) in cited["median_ms"]]
    sentences = []
    if measured:
        first = live[str(measured[0])]
        builds = ", ".join(f"{_seconds(live[str(n)]['build_s'])} ({n})" for n in measured)
        spread = ", ".join(f"{live[str(n)]['p10_ms']:.3f}–{live[str(n)]['p90_ms']:.3f} ms ({n})"
                           for n in measured)
        sentences.append(
            f"Reference measured live in this run at {_counts(measured)} obstacles (`fabrics` "
            f"{first.get('fabrics_version', '?')} under `{report.get('reference_python')}`, "
            "`tamedpuma/app/reference_fabrics.py`, on the same states and obstacles as ours; "
            f"median of {'/'.join(str(live[str(n)]['n_calls']) for n in measured)} "
            f"`compute_action` calls, p10–p90 {spread}); its build: {builds}.")
        sentences += _motion_sentences(live, measured)
    if quoted:
        values = ", ".join(f"{cited['median_ms'][str(n)]} ms ({n})" for n in quoted)
        builds = ", ".join(f"{_seconds(cited['build_s'][str(n)])} ({n})" for n in quoted
                           if str(n) in cited["build_s"])
        sentences.append(
            f"Reference cited, not measured in this run, at {_counts(quoted)} obstacles: "
            f"{values}; build {builds}. These were measured on this machine on "
            f"{cited['date']} ({cited['source']}).")
    if report.get("reference_note"):
        sentences.append(f"Reference note: {report['reference_note']}.")
    elif not measured:
        sentences.append("No reference Python was given (`--reference-python` or "
                         f"`${REFERENCE_ENV}`), so no reference figure is live.")
    return textwrap.wrap(" ".join(sentences), width=96, break_long_words=False,
                         break_on_hyphens=False)


def _counts(counts) -> str:
    """2 → "2"; (2, 10) → "2 and 10"; (2, 10, 100) → "2, 10 and 100"."""
    text = [str(n) for n in counts]
    return text[0] if len(text) == 1 else ", ".join(text[:-1]) + " and " + text[-1]


def _motion_sentences(live: dict, measured) -> list:
    """The reference's rollout check (end-effector distance to the goal, clearance), if present."""
    parts = []
    for n in measured:
        m = live[str(n)].get("motion")
        if not m:
            continue
        gap = m.get("min_clearance_m")
        parts.append(f"{m['ee_distance_start_m']:.3f} → {m['ee_distance_end_m']:.3f} m"
                     + (f", body clearance ≥ {gap:.3f} m" if gap is not None else "")
                     + ("" if m.get("finite", True) else ", NON-FINITE actions") + f" ({n})")
    if not parts:
        return []
    m = next(live[str(n)]["motion"] for n in measured if live[str(n)].get("motion"))
    return [f"Its action integrated {m['steps']} × {m['dt']} s from the first state at rest "
            f"(end-effector distance to the goal): {'; '.join(parts)}."]


def markdown_section(report: dict) -> str:
    """The "## Fabrics" section of BENCHMARKS.md."""
    m = report["machine"]
    lines = [
        "## Fabrics",
        "",
        "One full evaluation of the vanilla Fabrics method per control step: kinematics",
        "(pinocchio) + every (body sphere × obstacle) pair + joint limits + goal attractor +",
        "energization + speed control + linear solves, timed by",
        f"`{report.get('command', 'python -m tamedpuma.bench_fabrics')}` (figures: "
        f"`benchmarks/fabrics.json`, {report['date']}).",
        "",
        "| obstacles | median [ms] | p10 [ms] | p90 [ms] | calls | target [ms] | reference [ms] "
        "| reference / ours |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    cited = report.get("reference_cited", cited_block())
    for row in report["results"]:
        n = row["n_obstacles"]
        ref, is_live = reference_shown({**report, "reference_cited": cited}, n)
        target = TARGET_MS.get(n)
        ratio, shown = "—", "—"
        if ref:
            r = ref / row["median_ms"]
            ratio = f"{r:.1f}×" if r < 10 else f"{r:.0f}×"
            shown = _ms(ref) if is_live else f"{ref} (dated {cited['date']}, {cited['source']})"
        lines.append(
            f"| {n} | {row['median_ms']:.3f} | {row['p10_ms']:.3f} | {row['p90_ms']:.3f} | "
            f"{row['n_calls']} | {f'≤ {target}' if target else '—'} | {shown} | {ratio} |")
    first = max((row.get("first_call_ms", 0.0) for row in report["results"]), default=0.0)
    lines += [
        "",
        f"Build time: {report['build_ms']:.3f} ms (constructing the `Fabric`; nothing depends on",
        "the obstacle count). The first call at a new obstacle count also allocates that count's",
        f"work buffers (no geometry is built): at most {first:.3f} ms here, once.",
        *reference_prose(report),
        "",
        f"Kinematics alone (median): {report['kinematics_median_ms']:.3f} ms; the rest is the",
        "fabric. At small counts the time is per-call overhead, not arithmetic: every leaf is a",
        "row block of one design matrix in preallocated buffers (`tamedpuma/fabrics/fused.py`),",
        "about 60 numpy calls and 20 pinocchio calls per evaluation whatever the count; at 1000",
        "obstacles (5000 pairs) the pair arithmetic dominates.",
        "",
        f"Machine: {m['cpu_model']}, {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}",
        f"({m['blas']}), load average {m.get('load_average_1min', '?')} at start and "
        f"{m.get('load_average_1min_end', '?')} at the end",
        "(the machine is shared; other jobs inflate every figure).",
        "",
        code_line(m),
        "",
    ]
    return "\n".join(lines)


def update_markdown(path: Path, section: str, title: str = "Fabrics") -> None:
    """Replace (or append) the "## <title>" section of ``path``, keeping every other section
    and every block another command writes (``<!-- result: NAME -->``)."""
    text = path.read_text() if path.exists() else "# Benchmarks\n\n"
    pattern = re.compile(rf"^## {re.escape(title)}\n.*?(?=^## |^<!-- result: |\Z)", re.M | re.S)
    if pattern.search(text):
        text = pattern.sub(lambda _: section + "\n", text, count=1)
    else:
        text = text.rstrip("\n") + "\n\n" + section + "\n"
    path.write_text(text.rstrip("\n") + "\n")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=3000, help="timed calls per count")
    parser.add_argument("--counts", type=int, nargs="+", default=list(COUNTS))
    parser.add_argument("--clearance", type=float, default=0.15,
                        help="minimum obstacle distance to the arm [m]")
    parser.add_argument("--reference-python", default=os.environ.get(REFERENCE_ENV) or None,
                        metavar="PATH", help="a Python with the `fabrics` package: measure the "
                        f"reference live (default: ${REFERENCE_ENV}, else cite dated figures)")
    parser.add_argument("--reference-counts", type=int, nargs="+",
                        default=list(REFERENCE_COUNTS), metavar="N",
                        help="obstacle counts to measure the reference at (building it takes "
                        "22 s at 100 and 31 min, 5.7 GB at 1000)")
    parser.add_argument("--reference-timeout", type=float, default=None, metavar="S",
                        help="wall-time limit of the reference run [s] "
                        "(default 600 + 4 per obstacle)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--root", type=Path, default=ROOT, help="repository root to write into")
    args = parser.parse_args(argv)
    report = run(args.counts, args.calls, args.clearance, args.reference_python,
                 args.reference_counts, reference_timeout_s=args.reference_timeout)
    report["command"] = "python -m tamedpuma.bench_fabrics " + " ".join(
        argv if argv is not None else sys.argv[1:])
    print(json.dumps(report, indent=2))
    if not args.no_write:
        out, md = write(report, args.root)
        print(f"wrote {out} and {md}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
