"""One exception base class for every user-facing error.

Entry points catch :class:`TamedPumaError`, print its message on one line and exit non-zero; any
other exception is a bug and keeps its traceback.
"""


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
