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
from .records import IIWA_JOINT_NAMES, IIWA_LINK_NAMES, Recorder, RunInfo, StepRecord
from .rerun_writer import RerunRecorder

#: recorder kind -> (class, file name inside the run directory)
RECORDERS = {"mcap": (McapRecorder, "episode.mcap"), "rerun": (RerunRecorder, "episode.rrd")}


def make_recorders(kinds: Iterable[str], run_dir: str | os.PathLike) -> list[Recorder]:
    """One recorder per kind (``"mcap"`` -> ``run_dir/episode.mcap``, ``"rerun"`` ->
    ``run_dir/episode.rrd``), with default options. Raises ValueError for an unknown kind."""
    out = []
    for kind in kinds:
        if kind not in RECORDERS:
            raise ValueError(f"unknown recorder {kind!r}; choose from {sorted(RECORDERS)}")
        cls, name = RECORDERS[kind]
        out.append(cls(Path(run_dir) / name))
    return out


__all__ = [
    "IIWA_JOINT_NAMES",
    "IIWA_LINK_NAMES",
    "RECORDERS",
    "McapRecorder",
    "Recorder",
    "RerunRecorder",
    "RunInfo",
    "RunLog",
    "StepRecord",
    "active_path",
    "make_recorders",
    "read_mcap",
    "read_rrd_joints",
    "read_rrd_scalars",
    "read_rrd_series",
    "recover_mcap",
]
