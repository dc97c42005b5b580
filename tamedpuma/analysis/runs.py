"""Load every run below a folder from its MCAP log alone: one row of metrics per run.

The metrics are recomputed from the logged per-step values with the same function the episode
loop uses (:func:`tamedpuma.metrics.run_metrics`); ``summary.json`` is not read.
"""

from __future__ import annotations

import argparse
import logging
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from tamedpuma.errors import LogError
from tamedpuma.metrics import ERROR_VECTOR_FIELDS, ROTATION_VECTOR_FIELDS, run_metrics
from tamedpuma.parallel import process_map
from tamedpuma.paths import SET_ASIDE, set_aside  # noqa: F401 - re-exported
from tamedpuma.recording import read_mcap

log = logging.getLogger(__name__)

#: PyYAML's safe loader, in C where PyYAML has libyaml (the same values, ~10x faster: a run's
#: config is 300 lines)
SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

#: the trained model a run used (RunInfo.model in the MCAP metadata; empty for model-free methods)
MODEL_KEYS = ("model_name", "model_origin", "model_data", "model_data_source", "model_sha256")


def runs_parser(doc: str | None, out_help: str = "output folder (default: RUNS)"
                ) -> argparse.ArgumentParser:
    """The analysis commands' shared arguments: RUNS (a folder of run folders) and ``--out``."""
    first = (doc or "").splitlines()[0] if doc else None
    if first:  # the checkout's ``analysis/`` shims are not installed: name the package's module
        first = first.replace("python -m analysis.", "python -m tamedpuma.analysis.")
    module = re.search(r"python -m (tamedpuma\.analysis\.\w+)", first or "")
    parser = argparse.ArgumentParser(prog=f"python -m {module.group(1)}" if module else None,
                                     description=first)
    parser.add_argument("runs", type=Path, help="folder holding run folders (searched recursively)")
    parser.add_argument("--out", type=Path, default=None, help=out_help)
    return parser


def runs_or_error(folder: Path, *, summaries: bool = False, allow_empty: bool = False):
    """The runs below ``folder`` for an analysis command: :func:`load_runs` (the logs) or, with
    ``summaries``, :func:`tamedpuma.analysis.summaries.load_summaries`. A missing folder, or
    nothing readable (unless ``allow_empty``), prints one line ``error: ...`` and returns None:
    the command then exits with status 2."""
    if not folder.is_dir():
        print(f"error: {folder} is not a folder", file=sys.stderr)
        return None
    if summaries:
        from tamedpuma.analysis.summaries import load_summaries

        loaded, what = load_summaries(folder), "run summaries (summary.json)"
    else:
        loaded, what = load_runs(folder, jobs=None), "readable run logs (episode.mcap)"
    if loaded[0].empty and not allow_empty:
        print(f"error: no {what} below {folder}", file=sys.stderr)
        return None
    return loaded


def parse_and_load(parser: argparse.ArgumentParser, argv: list[str] | None, **load):
    """An analysis command's input: ``(arguments, runs)`` with the runs from
    :func:`runs_or_error` (``load``: its options), or None after its one-line error (the
    command then exits with status 2)."""
    args = parser.parse_args(argv)
    loaded = runs_or_error(args.runs, **load)
    return None if loaded is None else (args, loaded)


def add_scoring_flags(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The flags of the two scoring rules every analysis applies (:func:`scored_runs`):
    ``--include-incomplete`` and ``--mixed-models``."""
    parser.add_argument("--include-incomplete", action="store_true",
                        help="score killed/truncated runs too (default: listed and excluded)")
    parser.add_argument("--mixed-models", action="store_true",
                        help="pool runs of one method made with different trained models "
                             "(default: refused, naming the models)")
    return parser


def split_incomplete(runs: pd.DataFrame, include: bool = False
                     ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The one rule for runs that did not finish, used by every analysis: a run whose log was
    not closed as complete (killed, interrupted, truncated, a full disk) is not scored; it is
    listed. Returns ``(scored, incomplete)``; with ``include`` the scored runs hold the
    incomplete ones too. The frame's ``attrs`` (skipped and failed runs) are kept."""
    if runs.empty or "complete" not in runs:
        return runs, runs.iloc[0:0]
    done = runs["complete"].fillna(False).astype(bool)
    incomplete = runs[~done].copy()
    scored = runs.copy() if include else runs[done].copy()
    scored.attrs.update(runs.attrs)
    return scored, incomplete


def mixed_models(runs: pd.DataFrame) -> list[str]:
    """One line per method label and task whose runs used more than one trained model (a
    sweep resumed after the model changed): the models' sha256 with their run counts. Empty
    when every row of a table comes from one model."""
    if runs.empty or "model_sha256" not in runs:
        return []
    label = runs["method_label"].fillna(runs["method"]) if "method_label" in runs else (
        runs["method"])
    used = runs.assign(_label=label, _sha=runs["model_sha256"].fillna(""))
    used = used[used["_sha"] != ""]
    lines = []
    for (name, task), group in used.groupby(["_label", "task"], dropna=False):
        counts = group["_sha"].value_counts()
        if len(counts) > 1:
            models = ", ".join(f"sha256 {sha[:12]} ({n} run{'' if n == 1 else 's'})"
                               for sha, n in counts.items())
            lines.append(f"{name} on {task}: runs of {len(counts)} models: {models}")
    return lines


def models_problem(runs: pd.DataFrame, allow_mixed: bool = False) -> str | None:
    """Why ``runs`` cannot be pooled into one row per method (:func:`mixed_models`), or None
    (also when ``allow_mixed``, the ``--mixed-models`` flag)."""
    lines = [] if allow_mixed else mixed_models(runs)
    if not lines:
        return None
    return (f"{'; '.join(lines)}: a row pools one model's runs only (rerun the runs of the "
            "other model, or pass --mixed-models to pool them)")


def scored_runs(runs: pd.DataFrame, args: argparse.Namespace
                ) -> tuple[pd.DataFrame, pd.DataFrame] | None:
    """The runs an analysis scores under its :func:`add_scoring_flags`: ``(scored,
    incomplete)`` by :func:`split_incomplete`, or None after a one-line error on stderr when
    the runs pool different models (:func:`models_problem`; the command exits with 2)."""
    scored, incomplete = split_incomplete(runs, getattr(args, "include_incomplete", False))
    problem = models_problem(scored, getattr(args, "mixed_models", False))
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return None
    return scored, incomplete


def write_table(table: pd.DataFrame, out: Path, stem: str) -> str:
    """Write ``out/<stem>.csv`` and ``out/<stem>.md`` (Markdown with the cells as formatted);
    returns the Markdown."""
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / f"{stem}.csv", index=False)
    text = table.to_markdown(index=False, disable_numparse=True) + "\n"
    (out / f"{stem}.md").write_text(text)
    return text



def find_logs(root: str | Path) -> list[Path]:
    """Every ``episode.mcap`` (finished) or ``episode.mcap.active`` (killed) below ``root``, but
    not the earlier attempts a resumed sweep set aside (:data:`SET_ASIDE`)."""
    root = Path(root)
    logs = sorted(root.rglob("episode.mcap")) + sorted(root.rglob("episode.mcap.active"))
    return [p for p in logs if not set_aside(p)]


def method_label(cfg: dict, method: str | None) -> str | None:
    """The table key of a run: the method config's ``label`` (e.g. ``cpm_literal``) or its name."""
    return (cfg.get("method") or {}).get("label") or method


def joint_columns(joints: pd.DataFrame) -> list[str]:
    """The joint position columns ``q_0 .. q_{n-1}`` of a log's joint frame, as many as the
    robot has."""
    n = sum(1 for c in joints.columns if re.fullmatch(r"q_\d+", str(c)))
    return [f"q_{i}" for i in range(n)]


def run_row(path: str | Path) -> tuple[dict, np.ndarray, np.ndarray]:
    """Metrics of one logged run, its end-effector path (T, 3) [m] and its per-step controller
    times (T,) [ms]."""
    run = read_mcap(path)
    cfg = yaml.load(run.config_yaml, Loader=SAFE_LOADER) or {}
    robot = cfg.get("robot", {})
    scenario = cfg.get("scenario", {})
    sc = run.scalars
    q = run.joints[joint_columns(run.joints)].to_numpy()
    n = q.shape[1]
    ee = run.ee[["x", "y", "z"]].to_numpy()
    dt = float(scenario.get("dt", run.info.get("dt") or 0.02))
    max_steps = scenario.get("max_steps")
    metrics = run_metrics(
        t=sc["t"].to_numpy(), position_error=sc["position_error_m"].to_numpy(),
        orientation_error=sc["orientation_error_rad"].to_numpy(),
        clearance=sc["clearance_m"].to_numpy(), obstacle_contact=sc["obstacle_contact"].to_numpy(),
        ground_contact=sc["ground_contact"].to_numpy(), q=q,
        q_min=np.array(robot.get("q_min", [-np.inf] * n)),
        q_max=np.array(robot.get("q_max", [np.inf] * n)),
        compute_ms=sc["compute_time_ms"].to_numpy(),
        tolerance=float(scenario.get("goal_tolerance", 0.05)),
        time_limit=float(max_steps) * dt if max_steps is not None else float("inf"),
        settle_time=float(cfg.get("settle_time", 0.0)), ee_position=ee,
        disturbance_time=disturbance_onset(cfg), error_vector=error_vector(sc),
        rest_window=float(cfg.get("rest_window", 1.0)),
        rest_distance=float(cfg.get("rest_distance", 0.005)),
        rotation_vector=logged_vector(sc, ROTATION_VECTOR_FIELDS),
        rest_angle=float(cfg.get("rest_angle", float("inf"))),
        compute_cpu_ms=(sc["compute_cpu_time_ms"].to_numpy()
                        if "compute_cpu_time_ms" in sc else None))
    method = run.info.get("method")
    row = {"path": str(path), "run_id": run.info.get("run_id"), "method": method,
           "method_label": method_label(cfg, method),
           "task": run.info.get("task"), "scenario": run.info.get("scenario_name"),
           "seed": run.info.get("seed"),
           "n_obstacles": int(run.obstacles["id"].nunique()) if len(run.obstacles) else 0,
           "complete": run.complete,
           "stop_reason": run.summary.get("stop_reason") or ("" if run.complete else "incomplete"),
           "read_error": run.read_error or "", **metrics.as_dict(),
           **{k: run.info.get(k, "") for k in MODEL_KEYS}}
    return row, ee, sc["compute_time_ms"].to_numpy()


def error_vector(scalars: pd.DataFrame) -> np.ndarray | None:
    """The logged error vector x_ee − x_g (T, 3) [m], or None for a log without it (the rest
    test then takes the hand's position, exact for a goal that does not move)."""
    return logged_vector(scalars, ERROR_VECTOR_FIELDS)


def logged_vector(scalars: pd.DataFrame, names) -> np.ndarray | None:
    """The logged scalars ``names`` as one (T, len(names)) array, or None for a log without
    them (older logs: the error rotation's vector, for the pose's rest test, is then left out
    and the orientation judged at the position's rest, as those runs were)."""
    if not set(names) <= set(scalars.columns):
        return None
    return scalars[list(names)].to_numpy()


def disturbance_onset(cfg: dict) -> float | None:
    """Time [s] the run's configured disturbance begins (``disturbance`` group), or None."""
    dist = cfg.get("disturbance") or {}
    onset = dist.get("onset")
    discrete = dist.get("kind") in ("goal_change", "push")  # Disturbance.onset_time
    return float(onset) if discrete and onset is not None else None


def load_runs(root: str | Path, jobs: int | None = 1
              ) -> tuple[pd.DataFrame, dict[str, np.ndarray], dict[str, np.ndarray]]:
    """All runs below ``root``: a metrics frame (one row per run, in the order of
    :func:`find_logs`), the end-effector paths and the per-step controller times [ms], both by
    run path. Unreadable logs are skipped with a warning (and counted in the frame's ``attrs``).

    ``jobs``: processes reading the logs (None: every usable core; the same frame). The analysis
    commands read on every core; a script that asks for more than one job must run its top
    level only as the main module (the usual ``__main__`` guard), as for any spawned process:
    the workers import the script."""
    rows, paths, times, skipped = [], {}, {}, []
    logs = find_logs(root)
    for path, (result, error) in zip(logs, process_map(_read_row, logs, jobs)):
        if error is not None:
            log.warning("skipping %s: %s", path, error)
            skipped.append(str(path))
            continue
        row, ee, ms = result
        rows.append(row)
        paths[row["path"]] = ee
        times[row["path"]] = ms
    frame = pd.DataFrame(rows)
    frame.attrs["skipped"] = skipped
    frame.attrs["failed"] = failed_runs(root)
    return frame, paths, times


def _read_row(path: Path):
    """(:func:`run_row`, None), or (None, why) for a log it cannot read."""
    try:
        return run_row(path), None
    except (LogError, KeyError) as exc:
        return None, str(exc)


def failed_runs(root: str | Path) -> list[tuple[str, str]]:
    """(run folder, reason) of every run below ``root`` whose ``summary.json`` records a failure
    (a sweep's run that raised: no episode log, see ``tamedpuma.app.sweep``)."""
    import json

    out = []
    for path in sorted(Path(root).rglob("summary.json")):
        if set_aside(path):
            continue
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(summary, dict) and summary.get("status") == "failed":
            out.append((str(path.parent), str(summary.get("reason", ""))))
    return out
