"""Work spread over the cores this process may use: how many there are, and an order-keeping map
over worker processes for CPU-bound work on many independent items (e.g. reading run logs)."""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity: ``taskset -c 0`` gives 1), which
    the default parallelism follows, as joblib's launcher does; ``os.cpu_count`` counts the
    machine's."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity on this platform
        return os.cpu_count() or 1


def process_map(fn: Callable, items: Iterable, jobs: int | None = None,
                min_items: int = 32) -> list:
    """``[fn(x) for x in items]``, in order, over ``jobs`` worker processes (default: every
    usable core). ``fn`` must be a module-level function; its results are pickled back.

    Fewer than ``min_items`` items, or one job, run in this process: a worker's start (a fresh
    interpreter that imports ``fn``'s module, about 1 s) pays only over many items. Workers are
    spawned, not forked: the caller may hold threads (a Hydra callback runs beside joblib's)."""
    items = list(items)
    jobs = usable_cores() if jobs is None else max(1, int(jobs))
    if jobs <= 1 or len(items) < min_items:
        return [fn(x) for x in items]
    chunk = max(1, len(items) // (4 * jobs))
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
        return list(pool.map(fn, items, chunksize=chunk))
