"""What the benchmark compares against: another source tree timed side by side in the same run
(``--baseline DIR``).

A baseline is a checkout the user prepares, e.g. ``git worktree add /tmp/before <rev>``; the
benchmark never checks out, archives or edits anything. Its workers run that tree's own
``tamedpuma.app.bench_worker``, so the tree must have one.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

WORKER = Path("tamedpuma") / "app" / "bench_worker.py"


class BaselineError(ValueError):
    """A baseline tree the benchmark cannot time (one line for the user)."""


def baseline_tree(path) -> Path:
    """``path`` resolved, checked to be a source tree with the benchmark's worker module."""
    tree = Path(path).expanduser().resolve()
    if not tree.is_dir():
        raise BaselineError(f"{path}: no such folder (a checkout, e.g. made with "
                            "`git worktree add DIR REV`)")
    if not (tree / WORKER).is_file():
        raise BaselineError(f"{path}: no {WORKER.as_posix()} there (not a tamedpuma checkout, "
                            "or one older than the benchmark's worker module)")
    return tree


def describe(tree: Path) -> dict:
    """``{"tree", "commit"}``: the folder and, in a git checkout, its HEAD commit (else None)."""
    proc = subprocess.run(["git", "-C", str(tree), "rev-parse", "HEAD"], capture_output=True,
                          text=True)
    return {"tree": str(tree), "commit": proc.stdout.strip() if proc.returncode == 0 else None}


def label(base: dict) -> str:
    """How a report names its baseline: the commit's short id, else the folder."""
    return f"commit `{base['commit'][:7]}`" if base.get("commit") else f"`{base['tree']}`"


def attach_baseline(rows: list[dict], before: list[dict]) -> None:
    """Add ``before_*`` figures and ``speedup`` (before median / median) to matching rows."""
    by = {(r["method"], r["n_obstacles"]): r for r in before}
    for row in rows:
        old = by.get((row["method"], row["n_obstacles"]))
        if old:
            for key in ("median_ms", "p10_ms", "p90_ms", "n_calls"):
                row[f"before_{key}"] = old[key]
            row["speedup"] = round(old["median_ms"] / row["median_ms"], 3)
