"""``python -m tamedpuma.ablation [OPTIONS] [OVERRIDES...]``: the whole ablation in one command.

Runs FPM and CPM with their defaults, a neutral change and without each addition in turn on
Table 1's 30 scenarios (``+experiment=ablation``) and on the randomized suite
(``+experiment=ablation_random``, 200 generated scenarios per task), one sweep after the other
into ``<output_root>/ablation``, then its analysis (:mod:`tamedpuma.analysis.ablation`: the table
paired on scenarios, the scenarios each removal loses, gains or makes unsafe, the figure).
With ``--page`` the result is then written into ``docs/method.md`` (``python -m
tamedpuma.app.results_page ablation <output_root>/ablation``: its block, with the provenance
the runs record).

The runs use the models at hand, as every sweep does: the real-data models once ``python -m
tamedpuma.models build`` (or Table 1's sweep) has built them, else the shipped ones; the block
names the models' sha256 and origin.

OVERRIDES go to both sweeps (``output_root=DIR``, ``ablation=fpm/none,fpm/stall_pull``,
``hydra.launcher.n_jobs=1``); ``--table1 OVERRIDE`` and ``--random OVERRIDE`` (repeatable) to one
of them (``--table1 case=tomato_00``, ``--random 'scenario.random_seed=range(2000,2010)'``);
``--only table1|random`` runs one half. A sweep resumed into the same folder skips its complete
runs, so an interrupted ablation continues where it stopped. Each sweep runs in its own process
(Hydra composes one multirun per process); a failing sweep stops the command with its status.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HALVES = {"table1": "+experiment=ablation", "random": "+experiment=ablation_random"}
USAGE = ("usage: python -m tamedpuma.ablation [--only table1|random] [--table1 OVERRIDE] "
         "[--random OVERRIDE] [--page] [OVERRIDES...]")


class UsageError(Exception):
    """A mistake on the command line: one line, status 2."""


def parse(argv: list[str]) -> tuple[list[str], dict[str, list[str]]]:
    """(the halves to run, in order; each half's overrides: the common ones, then its own);
    ``--page`` is :func:`main`'s."""
    argv = [a for a in argv if a != "--page"]
    common: list[str] = []
    own: dict[str, list[str]] = {name: [] for name in HALVES}
    only = None
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg in ("--table1", "--random", "--only"):
            if i + 1 >= len(argv):
                raise UsageError(f"{arg} needs a value ({USAGE})")
            value = argv[i + 1]
            if arg == "--only":
                if value not in HALVES:
                    raise UsageError(f"--only takes table1 or random, not {value!r}")
                only = value
            else:
                own[arg[2:]].append(value)
            i += 2
            continue
        if arg.startswith("-"):
            raise UsageError(f"unknown option {arg} ({USAGE})")
        common.append(arg)
        i += 1
    halves = [only] if only else list(HALVES)
    overrides = {name: [*common, *own[name]] for name in halves}
    if len({output_root(o) for o in overrides.values()}) > 1:
        raise UsageError("the two halves need one output_root (give it to both, not with "
                         "--table1 or --random): the analysis pairs them in one folder")
    return halves, overrides


def output_root(overrides: list[str]) -> Path:
    """The ``output_root`` the overrides set (the last one wins), else the run config's
    default (:class:`~tamedpuma.app.schema.RunConfig`)."""
    from tamedpuma.app.schema import RunConfig

    root = RunConfig.output_root
    for item in overrides:
        key, sep, value = item.partition("=")
        if sep and key.lstrip("+~") == "output_root":
            root = value
    return Path(root)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if any(a in ("-h", "--help") for a in argv):
        print(__doc__.strip() + "\n\n" + USAGE)
        return 0
    try:
        halves, overrides = parse(argv)
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for half in halves:
        command = [sys.executable, "-m", "tamedpuma.sweep", "-m", HALVES[half], *overrides[half]]
        print(f"ablation: {half}: {' '.join(command[1:])}", flush=True)
        status = subprocess.call(command)
        if status != 0:
            print(f"error: the {half} sweep of the ablation ended with status {status}",
                  file=sys.stderr)
            return status
    from tamedpuma.analysis.ablation import main as analyse

    root = output_root(overrides[halves[0]]) / "ablation"
    print(f"ablation: analysis of {root} (= python -m tamedpuma.analysis.ablation {root})",
          flush=True)
    status = analyse([str(root)])
    if status != 0 or "--page" not in argv:
        return status
    from tamedpuma.app.results_page import main as write_page

    return write_page(["ablation", str(root)])
