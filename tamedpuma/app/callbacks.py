"""Hydra callbacks: every multirun's outcome count (:class:`SweepOutcomes`, ``conf/sweep.yaml``)
and the Table-1 experiment's (``conf/experiment/table1.yaml``).

Before the sweep (main process): build the real-data models that are missing from the cache
(:func:`tamedpuma.app.models.ensure_real_models`), or say that the shipped synthetic models are
used when the authors' demonstrations are not on this machine. After each run (in the worker):
one progress line ``[done/total] ...``. After the sweep (main process): the analysis of the whole
sweep folder, exactly ``python -m tamedpuma.analysis.tables <sweep dir>`` (prints Table 1, writes
``table1.md``, ``table1.tex``, ``runs.csv``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from tamedpuma.analysis import sweep_values
from tamedpuma.paths import set_aside


def sweep_size(config: DictConfig) -> int | None:
    """Number of runs of a basic-sweeper sweep: the product of its value counts (comma lists and
    ``range(...)``; :mod:`tamedpuma.analysis.sweep_values`); None with a ``glob(...)``."""
    try:
        params = {str(k): str(v) for k, v in (config.hydra.sweeper.params or {}).items()}
        overrides = list(config.hydra.overrides.task or [])
    except Exception:
        return None
    for ov in overrides:  # command-line sweeps (-m case=00,01) replace the configured lists
        key, _, value = str(ov).partition("=")
        key = key.lstrip("+~")
        if key in params or "," in value:
            params[key] = value
    return sweep_values.sweep_size(params.values()) if params else None


class SweepOutcomes(Callback):
    """Every multirun (``conf/sweep.yaml``): in the main process, collect the outcome each job
    appended to the sweep folder's ``sweep_outcomes.jsonl`` (jobs may run in other processes)
    into :data:`tamedpuma.app.sweep._OUTCOMES`, which ``main`` reports and turns into the exit
    status."""

    def __init__(self) -> None:
        self._path: Path | None = None
        self._offset = 0

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        from tamedpuma.app import sweep

        sweep._OUTCOMES.clear()
        self._path = Path(str(config.hydra.sweep.dir)) / sweep.OUTCOMES_FILE
        self._offset = self._path.stat().st_size if self._path.is_file() else 0
        sweep._OUTCOMES_SOURCE[:] = [self._path, self._offset]
        refusal, warnings = sweep.resume_check(self._path.parent)
        for line in warnings:
            print(line, file=sys.stderr)
        if refusal:
            raise sweep.SweepStopped(refusal)

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        """One progress line ``[done/total] run: outcome`` (the Table-1 callback, when
        configured, prints its own)."""
        callbacks = OmegaConf.select(config, "hydra.callbacks", default=None) or {}
        multirun = str(OmegaConf.select(config, "hydra.mode", default="")).endswith("MULTIRUN")
        if multirun and "table1" not in callbacks:
            print(progress_line(config, job_return), flush=True)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        from tamedpuma.app import sweep

        if self._path is not None:
            sweep._OUTCOMES[:] = sweep.outcomes_since(self._path, self._offset)


def progress_line(config: DictConfig, job_return: Any) -> str:
    """``[done/total] <run folder>: <outcome>`` after a job: done counts the run folders of
    the sweep with a ``summary.json`` (not the earlier attempts a resumed sweep set aside),
    total the sweep's jobs (``multirun.yaml``). Both are kept by the worker between its jobs
    (:func:`sweep_total`, :class:`DoneRuns`): a job costs what is new since the last one, not a
    walk of the whole sweep folder and a parse of its manifest."""
    root = Path(str(config.hydra.sweep.dir))
    done = done_runs(root).count()
    total = sweep_total(root / "multirun.yaml")
    run_dir = Path(str(config.hydra.runtime.output_dir))
    outcome = "?"
    summary = run_dir / "summary.json"
    if summary.is_file():
        try:
            s = json.loads(summary.read_text())
        except (OSError, ValueError):
            s = {}
        outcome = ("failed" if s.get("status") == "failed" else
                   "success" if s.get("success_whole_body") else
                   "success (paper criterion only)" if s.get("success_paper") else
                   f"no success ({s.get('failure_whole_body') or s.get('stop_reason')})")
    elif getattr(job_return, "status", None) is not None:
        outcome = str(job_return.status.name).lower()
    try:  # the job's output_dir is absolute, the sweep dir as configured (often relative)
        shown = run_dir.resolve().relative_to(root.resolve())
    except ValueError:
        shown = run_dir
    return f"[{done}/{total}] {shown}: {outcome}"


_TOTALS: dict = {}  # (manifest path, mtime [ns], size [B]) -> the sweep's job count or "?"


def sweep_total(manifest: Path) -> int | str:
    """The job count of the sweep whose ``multirun.yaml`` is ``manifest`` (:func:`sweep_size`;
    "?" when unreadable or unknown), parsed once per process and version of the file (a
    manifest parse costs 0.1 s, every job of the sweep asks)."""
    try:
        stat = manifest.stat()
    except OSError:
        return "?"
    key = (str(manifest.resolve()), stat.st_mtime_ns, stat.st_size)
    if key not in _TOTALS:
        try:
            _TOTALS[key] = sweep_size(OmegaConf.load(manifest)) or "?"
        except Exception:  # noqa: BLE001 - an unreadable manifest: progress without a total
            _TOTALS[key] = "?"
    return _TOTALS[key]


class DoneRuns:
    """The run folders of the sweep folder ``root`` that hold a ``summary.json`` (not set aside),
    kept by a worker between its jobs: the folder is walked once, at the first count; later the
    runs the sweep's jobs (any process's) appended to its outcomes file since then are added,
    and each known folder's ``summary.json`` is checked (a rerun sets its summary aside until
    it writes a new one). The same count as a walk of the folder, without walking it."""

    def __init__(self, root: Path):
        from tamedpuma.app.sweep import OUTCOMES_FILE

        self.outcomes = Path(root) / OUTCOMES_FILE
        self.offset = self._size()  # before the walk: a run written meanwhile is seen twice
        self.runs = {p.parent.resolve() for p in Path(root).rglob("summary.json")
                     if not set_aside(p)}

    def _size(self) -> int:
        try:
            return self.outcomes.stat().st_size
        except OSError:
            return 0

    def count(self) -> int:
        """The number of run folders with a ``summary.json`` now."""
        if self._size() < self.offset:  # the outcomes file was replaced: walk again
            self.__init__(self.outcomes.parent)
        try:
            with open(self.outcomes, "rb") as fh:
                fh.seek(self.offset)
                data = fh.read()
        except OSError:
            data = b""
        complete = data[:data.rfind(b"\n") + 1]  # a line still being written waits
        self.offset += len(complete)
        for line in complete.decode("utf-8", errors="replace").splitlines():
            try:
                self.runs.add(Path(json.loads(line)["run_dir"]).resolve())
            except (ValueError, KeyError, TypeError):
                continue
        return sum(1 for run in self.runs if (run / "summary.json").is_file())


_DONE: dict[str, DoneRuns] = {}  # sweep folder -> its DoneRuns in this process


def forget_progress() -> None:
    """Drop what this process kept of earlier sweeps (a new sweep starts)."""
    _TOTALS.clear()
    _DONE.clear()


def done_runs(root: Path) -> DoneRuns:
    """This process's :class:`DoneRuns` of the sweep folder ``root``."""
    key = str(Path(root).resolve())
    if key not in _DONE:
        _DONE[key] = DoneRuns(Path(root))
    return _DONE[key]


class Table1(Callback):
    """``build_models``: build missing real-data models first; ``data``: their demonstrations
    folder (default: found as ``python -m tamedpuma.models build`` finds it); ``jobs``: parallel
    trainings (default: all cores)."""

    def __init__(self, build_models: bool = True, data: str | None = None,
                 jobs: int | None = None) -> None:
        self.build_models, self.data, self.jobs = bool(build_models), data, jobs

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        total = sweep_size(config)
        print(f"table1: {total} runs into {config.hydra.sweep.dir}", flush=True)
        if not self.build_models:
            return
        from tamedpuma.app import models
        from tamedpuma.errors import TamedPumaError
        from tamedpuma.puma import download

        if self.data is None and download.find_root() is None:
            print("table1: the authors' demonstrations are not on this machine (`python -m "
                  "tamedpuma.models download` fetches them): the methods use the best model at "
                  "hand (shipped: synthetic data); the table says which", flush=True)
            return
        try:
            models.ensure_real_models(self.data, self.jobs,
                                      log=lambda m: print(f"table1: {m}", flush=True))
        except TamedPumaError as exc:
            print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
            sys.exit(2)

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        print(progress_line(config, job_return), flush=True)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        from tamedpuma.analysis.tables import main as tables

        root = str(config.hydra.sweep.dir)
        print(f"table1: analysis of {root} (= python -m tamedpuma.analysis.tables {root})",
              flush=True)
        tables([root])
