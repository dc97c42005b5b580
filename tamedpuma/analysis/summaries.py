"""Load runs from their ``summary.json`` files (written by ``tamedpuma.sweep`` whatever the
recorder, so it serves ``recorder=none`` sweeps: scaling, disturbance), one row per run.

Each summary holds the run's metrics (:func:`tamedpuma.metrics.run_metrics`, computed in the
episode loop from the same per-step values the logs hold), its method label, obstacle count,
disturbance and every step's controller time [ms].
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd

from tamedpuma.analysis import stats
from tamedpuma.analysis.runs import set_aside
from tamedpuma.errors import LogError
from tamedpuma.runlog import upgrade_summary

log = logging.getLogger(__name__)

PERIOD_MS = 20.0  #: the control period [ms] (Δt = 0.02 s in every scenario)
BOUND_MS = 10.0  #: the bound every step of FPM, CPM, Fabrics and PUMA is asked to keep [ms]


def load_summaries(root: str | Path) -> tuple[pd.DataFrame, dict[str, np.ndarray]]:
    """Every ``summary.json`` below ``root``: a frame (one row per run, ``path`` = the run folder)
    and the per-step controller times [ms] by run folder, every summary in the current layout
    (:func:`tamedpuma.runlog.upgrade_summary`). Unreadable files are skipped with a warning
    (counted in the frame's ``attrs['skipped']``)."""
    rows, times, skipped = [], {}, []
    for path in sorted(Path(root).rglob("summary.json")):
        if set_aside(path):  # a resumed sweep's earlier attempt, not a run
            continue
        try:
            summary = upgrade_summary(json.loads(path.read_text()))
            steps = np.asarray(summary.pop("step_compute_ms"), dtype=float)
            summary.pop("step_compute_cpu_ms", None)
            summary.pop("files", None)
        except (OSError, ValueError, KeyError, LogError) as exc:
            log.warning("skipping %s: %s", path, exc)
            skipped.append(str(path))
            continue
        summary["path"] = str(path.parent)
        summary.setdefault("method_label", summary.get("method"))
        rows.append(summary)
        times[summary["path"]] = steps
    frame = pd.DataFrame(rows)
    frame.attrs["skipped"] = skipped
    return frame, times


def pooled_step_times(paths, times: dict[str, np.ndarray]) -> dict:
    """Controller time over every step of the runs ``paths`` [ms]: median, p99, mean, std, the
    step count, and the first step of each run (mean) shown apart."""
    arrays = [times[p] for p in paths if p in times and len(times[p])]
    if not arrays:
        return {"median": np.nan, "p99": np.nan, "mean": np.nan, "std": np.nan, "steps": 0,
                "first_mean": np.nan}
    every = np.concatenate(arrays)
    return {"median": float(np.median(every)), "p99": float(np.percentile(every, 99)),
            "mean": float(every.mean()), "std": float(every.std()), "steps": int(len(every)),
            "first_mean": float(np.mean([a[0] for a in arrays]))}


def step_stats(ms) -> dict:
    """Median, p99, p99.9, max [ms] of per-step times ``ms``, the step count and the steps over
    :data:`PERIOD_MS` and :data:`BOUND_MS`."""
    ms = np.asarray(ms, dtype=float)
    if not len(ms):
        return {"steps": 0}
    return {"steps": int(len(ms)), "median_ms": float(np.median(ms)),
            "p99_ms": float(np.percentile(ms, 99)), "p99_9_ms": float(np.percentile(ms, 99.9)),
            "max_ms": float(ms.max()), "over_period": int(np.sum(ms > PERIOD_MS)),
            "over_bound": int(np.sum(ms > BOUND_MS))}


def bootstrap_ci(values, level: float = 0.95, samples: int = 10_000,
                 seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the mean of ``values`` (e.g. 0/1 success),
    ``samples`` resamples with replacement, seeded. (nan, nan) for no values.
    (:func:`tamedpuma.analysis.stats.bootstrap_ci`, as a (low, high) pair.)"""
    iv = stats.bootstrap_ci(values, level=level, resamples=samples, seed=seed)
    return iv.low, iv.high
