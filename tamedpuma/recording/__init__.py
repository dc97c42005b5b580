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

import importlib
import os
from collections.abc import Iterable
from pathlib import Path

from tamedpuma.records import Recorder, RunInfo, StepRecord

from .mcap_writer import McapRecorder, active_path

#: names imported on first use: the readers need pandas, the Rerun recorder rerun and pyarrow
#: (2 s CPU of a process's start together), which a run that records MCAP alone never uses
_LAZY = {"RunLog": ".reader", "read_mcap": ".reader", "read_rrd_joints": ".reader",
         "read_rrd_scalars": ".reader", "read_rrd_series": ".reader",
         "recover_mcap": ".reader", "RerunRecorder": ".rerun_writer"}
#: recorder kind -> file name inside the run directory
_FILES = {"mcap": "episode.mcap", "rerun": "episode.rrd"}


def __getattr__(name: str):
    """The lazily imported names (:data:`_LAZY`) and ``RECORDERS``: recorder kind -> (class,
    file name inside the run directory)."""
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    if name == "RECORDERS":
        return {kind: (_recorder_class(kind), file) for kind, file in _FILES.items()}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _recorder_class(kind: str) -> type:
    return McapRecorder if kind == "mcap" else __getattr__("RerunRecorder")


def recorder_files(kinds: Iterable[str], run_dir: str | os.PathLike) -> dict[str, Path]:
    """The file each recorder kind writes: ``{"mcap": run_dir/episode.mcap, "rrd": ...}``."""
    out = {}
    for kind in kinds:
        if kind not in _FILES:
            raise ValueError(f"unknown recorder {kind!r}; choose from {sorted(_FILES)}")
        name = _FILES[kind]
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
        cls = _recorder_class(kind)
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
