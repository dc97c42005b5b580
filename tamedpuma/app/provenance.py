"""Where a measurement came from: the command, the date, the machine, the code and the load.

A command that measures (the learner table, the LASA benchmark) stamps its JSON with
:func:`stamp`; the page that shows the figures (:mod:`tamedpuma.app.results_page`) prints the
stamp with :func:`lines`, so no provenance is typed by hand.
"""

from __future__ import annotations

import datetime as dt
import functools
import os
import platform
import re
import shlex
from pathlib import Path


@functools.cache
def machine() -> dict:
    """What ran the command: OS, CPU, core count, Python and the numerical packages' versions
    (results of one suite from two machines differ in time, never in scenarios)."""
    from importlib import metadata

    def version(name: str) -> str | None:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    cpu = platform.processor() or platform.machine()
    try:  # Linux names the model; platform gives only the architecture there
        cpu = next(line.split(":", 1)[1].strip() for line in
                   Path("/proc/cpuinfo").read_text().splitlines()
                   if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"system": f"{platform.system()} {platform.release()}", "cpu": cpu,
            "cores": os.cpu_count(),
            "python": platform.python_version(),
            "packages": {n: version(n) for n in ("numpy", "pin", "pybullet", "torch")}}


def machine_text(m: dict) -> str:
    """``machine()`` in one line: CPU, cores, Python and torch."""
    torch = (m.get("packages") or {}).get("torch")
    return (f"{m.get('cpu', '?')}, {m.get('cores', '?')} cores, Python {m.get('python', '?')}"
            + (f", torch {torch}" if torch else ""))


def command_line(module: str, argv: list[str]) -> str:
    """``python -m MODULE ARGS`` as the user typed it (quoted for a shell)."""
    return " ".join(["python", "-m", module, *(shlex.quote(a) for a in argv)])


def stamp(command: str) -> dict:
    """The provenance of a measurement that starts now: ``command``, the UTC date and time, the
    machine, the code revision and the load average (1, 5, 15 min) at the start."""
    from tamedpuma.app.models import code_revision

    return {"command": command,
            "started": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "machine": machine(), "code_revision": code_revision(),
            "load_start": [round(x, 2) for x in os.getloadavg()]}


def with_end(s: dict) -> dict:
    """``s`` with the time and load average of now, as the measurement's end (after every
    row of a table, so a stopped run's file says when its last row came)."""
    return {**s, "finished": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "load_end": [round(x, 2) for x in os.getloadavg()]}


def lines(s: dict) -> list[str]:
    """The stamp as the Markdown bullets of a results block."""
    load = f"load average (1/5/15 min) {' / '.join(map(str, s.get('load_start', [])))} at start"
    if s.get("load_end"):
        load += f", {' / '.join(map(str, s['load_end']))} at the end"
    return [f"- command: `{s['command']}`",
            f"- date: {s['started']}" + (f" to {s['finished']}" if s.get("finished", s["started"])
                                          != s["started"] else ""),
            f"- machine: {machine_text(s['machine'])}; {load}",
            f"- code: `{short_revision(str(s['code_revision']))}`"]


def short_revision(rev: str) -> str:
    """``rev`` with each git hash in it cut to 7 characters (``-dirty`` and versions kept)."""
    return re.sub(r"(?<![0-9a-f])([0-9a-f]{7})[0-9a-f]{5,}(?![0-9a-f])", r"\1", rev)
