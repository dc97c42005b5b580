"""The one place a configured path becomes a file system path (demonstrations, checkpoints,
output folders, tables).

Rules: ``~`` is expanded; an absolute path is used as given; a relative path is relative to the
working directory, or, if it does not exist there but does inside the installed package (shipped
data), to the package. Never to a checkout: an installed package has none. Entry points and the
loaders call :func:`resolve`; everything below them receives resolved paths.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

from tamedpuma.errors import ConfigError

PACKAGE_DIR = Path(__file__).resolve().parent
CONF_DIR = PACKAGE_DIR / "conf"  # the config groups ship inside the package
#: the folder above the package: a checkout's root in a checkout (its git revision, the benchmark
#: files, ``../shared`` beside it); in an installed package site-packages, where nothing is needed
CHECKOUT_ROOT = PACKAGE_DIR.parent


def candidates(path: str | os.PathLike) -> list[Path]:
    """Where ``path`` is looked for, in order."""
    p = Path(path).expanduser()
    if p.is_absolute():
        return [p]
    return [Path.cwd() / p, PACKAGE_DIR / p]


def writable_problem(folder: str | os.PathLike) -> str | None:
    """Why ``folder`` (created if missing) cannot be written, in a few words, or None: checked
    by writing and removing a probe file, before any work whose result would be lost."""
    path = Path(folder)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".write-test-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        return f"output folder {folder} is not writable: {exc.strerror or exc}"
    return None


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
