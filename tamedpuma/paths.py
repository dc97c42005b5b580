"""The one place a configured path becomes a file system path (demonstrations, checkpoints,
output folders, tables).

Rules: ``~`` is expanded; an absolute path is used as given; a relative path is relative to the
working directory, or, if it does not exist there but does inside the installed package (shipped
data), to the package. Never to a checkout: an installed package has none. Entry points and the
loaders call :func:`resolve`; everything below them receives resolved paths.
"""

from __future__ import annotations

import errno
import os
import shutil
import uuid
from pathlib import Path

from tamedpuma.errors import ConfigError, DiskFullError

PACKAGE_DIR = Path(__file__).resolve().parent
CONF_DIR = PACKAGE_DIR / "conf"  # the config groups ship inside the package
#: the folder above the package: a checkout's root in a checkout (its git revision, the benchmark
#: files, ``../shared`` beside it); in an installed package site-packages, where nothing is needed
CHECKOUT_ROOT = PACKAGE_DIR.parent


def in_checkout() -> bool:
    """True when this package runs from a checkout (its ``pyproject.toml`` beside the package),
    False for an installed package (the folder above it is site-packages)."""
    return (CHECKOUT_ROOT / "pyproject.toml").is_file()


def project_root() -> Path:
    """Where the project's own pages and benchmark files go (``docs/``, ``BENCHMARKS.md``,
    ``benchmarks/``): the checkout holding this package, else the working directory (an
    installed package has no such files, and its site-packages is no place to write them)."""
    return CHECKOUT_ROOT if in_checkout() else Path.cwd()


def candidates(path: str | os.PathLike) -> list[Path]:
    """Where ``path`` is looked for, in order."""
    p = Path(path).expanduser()
    if p.is_absolute():
        return [p]
    return [Path.cwd() / p, PACKAGE_DIR / p]


#: bytes the output-folder check writes (and removes): a folder without this much room cannot
#: hold a run's config and summary [B]
PROBE_BYTES = 64 * 1024


def writable_problem(folder: str | os.PathLike) -> str | None:
    """Why ``folder`` (created if missing) cannot be written, in a few words, or None: checked
    by writing and removing a probe file, before any work whose result would be lost."""
    path = Path(folder)
    probe = path / f".write-test-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        path.mkdir(parents=True, exist_ok=True)
        with open(probe, "wb") as fh:  # room for one run's smallest files, not just a name
            fh.write(bytes(PROBE_BYTES))
            fh.flush()
            os.fsync(fh.fileno())
        probe.unlink()
    except OSError as exc:
        try:
            probe.unlink(missing_ok=True)
        except OSError:  # the folder itself is not there (a file in its path)
            pass
        if no_space(exc, path):
            return str(DiskFullError(path, free_bytes(path), PROBE_BYTES))
        return f"output folder {folder} is not writable: {exc.strerror or exc}"
    return None


#: below this many free bytes a writer library's error without an errno (the MCAP and Rerun
#: writers report a failed write as a RuntimeError) is taken to be a full disk [B]
LOW_SPACE = 1 << 20


def free_bytes(path: str | os.PathLike) -> int | None:
    """Bytes free for this user on the file system holding ``path`` (or its nearest existing
    parent), None if unknown."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return shutil.disk_usage(p).free
    except OSError:
        return None


def no_space(exc: BaseException, path: str | os.PathLike) -> bool:
    """True if ``exc`` is a write that failed for lack of space: an OSError with ENOSPC or
    EDQUOT, or a writer library's error with no errno while the file system of ``path`` has
    less than :data:`LOW_SPACE` bytes free."""
    if isinstance(exc, DiskFullError):
        return True
    if isinstance(exc, OSError) and exc.errno is not None:
        return exc.errno in (errno.ENOSPC, errno.EDQUOT)
    free = free_bytes(path)
    return isinstance(exc, (OSError, RuntimeError)) and free is not None and free < LOW_SPACE


def write_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` through ``<path>.tmp`` and a rename, so ``path`` is either
    the old file or the whole new one. A full disk removes the partial ``.tmp`` and raises
    :class:`~tamedpuma.errors.DiskFullError` (needed: ``len(data)`` bytes)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_bytes(data)
        tmp.replace(path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if no_space(exc, path):
            raise DiskFullError(path, free_bytes(path), len(data)) from exc
        raise
    return path


def resolve(path: str | os.PathLike, *, must_exist: bool = False, what: str = "path") -> Path:
    """The first existing candidate of ``path`` (see the module), else its working-directory
    form (a file to be written). ``must_exist``: a missing path is a :class:`ConfigError`
    naming where it was looked for."""
    found = candidates(path)
    for c in found:
        if c.exists():
            return c
    if must_exist:
        raise ConfigError(f"{what} not found: {path} (looked in "
                          f"{', '.join(str(c) for c in found)})")
    return found[0]


#: the folder in which a resumed sweep keeps a run's interrupted earlier attempt
#: (``tamedpuma.app.sweep``): kept for inspection, not a run of the sweep
SET_ASIDE = "previous_attempt"


def set_aside(path: str | os.PathLike) -> bool:
    """True for a file inside a run's :data:`SET_ASIDE` folder."""
    return SET_ASIDE in Path(path).parts
