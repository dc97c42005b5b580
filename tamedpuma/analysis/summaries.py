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


def step_stats(runs) -> dict:
    """The controller's time per step pooled over every step of ``runs`` (per run, its steps'
    times [ms]; runs without steps are left out):

    - ``steps``: the number of steps pooled;
    - ``median_ms``, ``p99_ms``, ``p99_9_ms``, ``max_ms``: their median, 99th and 99.9th
      percentile and largest [ms];
    - ``mean_ms``, ``std_ms``: their mean and standard deviation (ddof 0) [ms];
    - ``first_mean_ms``, ``first_max_ms``: each run's first step (the warm-up), mean and largest
      over the runs [ms];
    - ``over_period``, ``over_bound``: the steps longer than :data:`PERIOD_MS` and
      :data:`BOUND_MS`.

    With no step at all, ``{"steps": 0}`` alone."""
    arrays = [a for a in (np.asarray(r, dtype=float) for r in runs) if len(a)]
    if not arrays:
        return {"steps": 0}
    every = np.concatenate(arrays)
    first = np.array([a[0] for a in arrays])
    return {"steps": int(len(every)), "median_ms": float(np.median(every)),
            "p99_ms": float(np.percentile(every, 99)),
            "p99_9_ms": float(np.percentile(every, 99.9)), "max_ms": float(every.max()),
            "mean_ms": float(every.mean()), "std_ms": float(every.std()),
            "first_mean_ms": float(first.mean()), "first_max_ms": float(first.max()),
            "over_period": int(np.sum(every > PERIOD_MS)),
            "over_bound": int(np.sum(every > BOUND_MS))}


def bootstrap_ci(values, level: float = 0.95, samples: int = 10_000,
                 seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the mean of ``values`` (e.g. 0/1 success),
    ``samples`` resamples with replacement, seeded. (nan, nan) for no values.
    (:func:`tamedpuma.analysis.stats.bootstrap_ci`, as a (low, high) pair.)"""
    iv = stats.bootstrap_ci(values, level=level, resamples=samples, seed=seed)
    return iv.low, iv.high
