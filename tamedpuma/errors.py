"""One exception base class for every user-facing error.

Entry points catch :class:`TamedPumaError`, print its message on one line and exit non-zero; any
other exception is a bug and keeps its traceback.
"""

from __future__ import annotations


class TamedPumaError(Exception):
    """A user mistake or bad input (config, data, checkpoint, log file): one-line message."""


class ConfigError(TamedPumaError):
    """An unknown or invalid configuration value."""


class ScenarioError(TamedPumaError):
    """A scenario that cannot be run (e.g. a start outside the joint limits)."""


class DataError(TamedPumaError):
    """Demonstrations that are missing, malformed, of the wrong shape or not finite."""


class CheckpointError(TamedPumaError):
    """A checkpoint that is missing, corrupt, of another format version or of the wrong shape."""


class LogError(TamedPumaError):
    """A run log that is missing, unreadable or truncated beyond recovery."""


class LogExistsError(LogError, FileExistsError):
    """A log file (or its ``.active`` partial) already exists where a new run would write."""


class DiskFullError(TamedPumaError):
    """A file could not be written because its file system is full (ENOSPC, or a writer
    library's failure while the file system has no room left). ``path``: the file;
    ``free``: bytes free on its file system [B]; ``needed``: bytes the write needs [B] (an
    estimate) or None; ``per_step``: bytes one step of a log takes [B/step] or None."""

    def __init__(self, path, free: int | None, needed: int | None = None,
                 per_step: float | None = None):
        self.path, self.free, self.needed, self.per_step = path, free, needed, per_step
        free_text = "unknown bytes free" if free is None else f"{free} bytes free"
        need_text = "" if needed is None else f", about {needed} bytes needed"
        super().__init__(f"disk full: cannot write {path} ({free_text}{need_text})")

    def for_steps(self, steps: int) -> DiskFullError:
        """The same error with ``needed`` = the bytes a log of ``steps`` steps takes at the
        rate written so far (``per_step``); unchanged without a rate."""
        if self.per_step is None:
            return self
        return DiskFullError(self.path, self.free, int(self.per_step * steps), self.per_step)
