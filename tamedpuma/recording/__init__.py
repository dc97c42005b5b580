"""Recording layer: passive per-step sinks (MCAP, Rerun) and readers for analysis.

Use in an episode loop::

    recorders = make_recorders(["mcap", "rerun"], run_dir)   # or McapRecorder(path), ...
    for r in recorders: r.open(info)
    try:
        for ...: for r in recorders: r.write(step_record)
    except BaseException:
        for r in recorders: r.close(complete=False, summary={...}); raise
    for r in recorders: r.close(complete=True, summary={...})

Readers: :func:`read_mcap` (-> :class:`RunLog` of DataFrames, also for a killed run's
``.active`` file), :func:`recover_mcap`, :func:`read_rrd_scalars`, :func:`read_rrd_joints`.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from .mcap_writer import McapRecorder, active_path
from .reader import (
    RunLog,
    read_mcap,
    read_rrd_joints,
    read_rrd_scalars,
    read_rrd_series,
    recover_mcap,
)
from .records import Recorder, RunInfo, StepRecord
from .rerun_writer import RerunRecorder

#: recorder kind -> (class, file name inside the run directory)
RECORDERS = {"mcap": (McapRecorder, "episode.mcap"), "rerun": (RerunRecorder, "episode.rrd")}


def recorder_files(kinds: Iterable[str], run_dir: str | os.PathLike) -> dict[str, Path]:
    """The file each recorder kind writes: ``{"mcap": run_dir/episode.mcap, "rrd": ...}``."""
    out = {}
    for kind in kinds:
        if kind not in RECORDERS:
            raise ValueError(f"unknown recorder {kind!r}; choose from {sorted(RECORDERS)}")
        name = RECORDERS[kind][1]
        out[Path(name).suffix[1:]] = Path(run_dir) / name
    return out


def make_recorders(kinds: Iterable[str], run_dir: str | os.PathLike,
                   flush_every: int = 100) -> list[Recorder]:
    """One recorder per kind (``"mcap"`` -> ``run_dir/episode.mcap``, ``"rerun"`` ->
    ``run_dir/episode.rrd``); ``flush_every``: the MCAP chunk period [steps]. Raises ValueError
    for an unknown kind."""
    kinds = list(kinds)
    out = []
    for kind, path in zip(kinds, recorder_files(kinds, run_dir).values()):
        cls = RECORDERS[kind][0]
        out.append(cls(path, flush_every=flush_every) if kind == "mcap" else cls(path))
    return out


__all__ = [
    "RECORDERS",
    "McapRecorder",
    "Recorder",
    "RerunRecorder",
    "RunInfo",
    "RunLog",
    "StepRecord",
    "active_path",
    "make_recorders",
    "recorder_files",
    "read_mcap",
    "read_rrd_joints",
    "read_rrd_scalars",
    "read_rrd_series",
    "recover_mcap",
]
