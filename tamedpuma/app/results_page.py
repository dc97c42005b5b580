"""``python -m tamedpuma.app.results_page NAME RUNS``: one experiment's block of ``docs/results.md``
rewritten from what its analysis wrote, with its provenance.

The block between ``<!-- result: NAME -->`` and ``<!-- /result -->`` is replaced as a unit: a
heading, the provenance (the command that ran the experiment, the dates of its runs, the machine,
the code revision, the models' sha256 read from the runs' ``summary.json``), the analysis's own
Markdown tables (``table1.md`` of ``analysis.tables``, ``scaling.md``, ``random_suite.md``,
``disturbance.md``) and its figures, copied into ``docs/img/``. Nothing in the block is typed
by hand, so a table on the page is always the one its command wrote, and the other blocks are
left as they are.

    python -m analysis.tables runs/table1 && python -m tamedpuma.app.results_page table1 runs/table1
    python -m tamedpuma.app.results_page table1 runs/table1 --readme README.md  # and the README's
    python -m analysis.scaling runs/scaling --timing-only runs/mik_timing
    python -m tamedpuma.app.results_page scaling runs/scaling
    python -m analysis.report runs/look && python -m tamedpuma.app.results_page figures runs/look
    python -m analysis.ablation runs/ablation
    python -m tamedpuma.app.results_page ablation runs/ablation

The ablation's block is on the method's own page, ``docs/method.md``; the others on
``docs/results.md``.

The machine and the code revision are those the runs' ``summary.json`` record (schema 2); for
runs that do not record them, those of the host that writes the page, marked so.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

from tamedpuma.app.provenance import lines as provenance_lines
from tamedpuma.app.provenance import machine as host_machine
from tamedpuma.app.provenance import machine_text, short_revision
from tamedpuma.paths import project_root

#: the page, in :func:`tamedpuma.paths.project_root`: the checkout's, else (an installed
#: package) docs/ of the current folder
PAGE = Path("docs") / "results.md"


@dataclass(frozen=True)
class Experiment:
    title: str
    command: str                 # how the runs were made (the default; --command overrides)
    tables: tuple[str, ...]      # the analysis's Markdown files in RUNS
    figures: tuple[str, ...] = ()  # its figures in RUNS (copied into docs/img/)
    page: Path = PAGE            # the page the block is on


EXPERIMENTS = {
    "table1": Experiment("Table 1", "python -m tamedpuma.sweep +experiment=table1",
                         ("table1.md",)),
    "scaling": Experiment("Obstacle-count scaling",
                          "python -m tamedpuma.sweep -m +experiment=scaling recorder=none "
                          "(docs/experiments.md: four commands)", ("scaling.md",),
                          ("scaling.png",)),
    "random": Experiment("Randomized suite",
                         "python -m tamedpuma.sweep -m +experiment=random hydra/launcher=cores",
                         ("random_suite.md", "random_suite_by_start.md")),
    "disturbance": Experiment("Disturbances",
                              "python -m tamedpuma.sweep -m +experiment=disturbance "
                              "recorder=none", ("disturbance.md",)),
    "compare": Experiment("Paired comparison on the randomized suite",
                          "python -m tamedpuma.analysis.compare RUNS [RUNS ...]",
                          ("compare_rates.md", "compare.md"), ("compare.png",)),
    "figures": Experiment("Paths, clearance and ψ, success and timing",
                          "python -m tamedpuma.sweep -m method=puma,fpm,cpm "
                          "scenario=tomato/00,tomato/03,tomato/07 without_obstacles=false,true "
                          "recorder=mcap output_root=runs/look", (),
                          ("figures/paths_tomato.png", "figures/clearance_psi_tomato.png",
                           "figures/success_timing.png")),
    "ablation": Experiment("The ablation",
                           "python -m tamedpuma.ablation (the sweeps +experiment=ablation and "
                           "+experiment=ablation_random into one output_root, then python -m "
                           "tamedpuma.analysis.ablation on it)",
                           ("ablation.md",), ("ablation.png",), Path("docs") / "method.md"),
}


@dataclass(frozen=True)
class Measured:
    """A block written from a measuring command's stamped JSON (``{"provenance", "rows"}``)
    instead of a folder of runs: its title, the page it belongs on, the module whose
    ``markdown(rows)`` renders the rows, and what the command measures."""

    title: str
    page: Path
    renderer: str
    about: str


MEASURED = {
    "lasa": Measured("LASA shapes (PUMA alone, 2-D)", PAGE, "tamedpuma.puma.lasa_benchmark",
                     "A second-order 2-D PUMA trained and evaluated on each LASA handwriting "
                     "shape (per-shape table: `benchmarks/lasa.md`)."),
    "learner": Measured("PUMA training", Path("BENCHMARKS.md"), "tamedpuma.puma.learner_table",
                        "Every demonstration set at hand trained with the default recipe and "
                        "evaluated (`report.json` of each training): imitation, the converged "
                        "share of the random starts, ψ compatibility, the gates, and the time."),
}
MARKERS = ("<!-- result: {} -->", "<!-- /result -->")
HOST = " (the host writing the page: the runs record none)"


class PageError(Exception):
    """A user mistake: one line, status 2."""


# ----------------------------------------------------------------------------- provenance


def summaries(runs: Path) -> list[dict]:
    """Every readable ``summary.json`` below ``runs`` (a resumed sweep's set-aside attempts
    excluded)."""
    found = []
    for path in sorted(runs.rglob("summary.json")):
        if "previous_attempt" in path.parts:
            continue
        try:
            found.append({**json.loads(path.read_text()), "_mtime": path.stat().st_mtime})
        except (OSError, ValueError):
            continue
    return found


def run_dates(found: list[dict]) -> str:
    days = sorted({dt.datetime.fromtimestamp(s["_mtime"], dt.timezone.utc).date().isoformat()
                   for s in found})
    if not days:
        return "unknown (no summary.json)"
    return days[0] if len(days) == 1 else f"{days[0]} to {days[-1]}"


def models(found: list[dict]) -> str:
    """The models the runs used: name, sha256 prefix, origin (from each run's summary)."""
    seen = {}
    for s in found:
        model = s.get("model") or {}
        if model.get("model_sha256"):
            seen[(model.get("model_name") or "?", model["model_sha256"][:12])] = (
                model.get("model_origin") or "?")
    if not seen:
        return "none (methods without a learned model)"
    return ", ".join(f"{name} `{sha}` ({origin})" for (name, sha), origin in sorted(seen.items()))


def machine() -> str:
    """The host's machine in one line (CPU, cores, Python, torch)."""
    return machine_text(host_machine())


def run_revisions(found: list[dict]) -> str | None:
    """The code revisions the runs record (``summary.json``'s ``code_revision``: a git hash cut
    to 7 characters, ``-dirty`` kept; an installed package's version, ``tamedpuma 0.1.0``, as
    recorded), or None where no run records one (layout 1)."""
    revs = sorted({short_revision(str(s["code_revision"])) for s in found
                   if s.get("code_revision")})
    return ", ".join(f"`{r}`" for r in revs) if revs else None


def run_machines(found: list[dict]) -> str | None:
    """The machines the runs record (``summary.json``'s ``machine``), or None."""
    seen = {machine_text(s["machine"]) for s in found
            if isinstance(s.get("machine"), dict) and s["machine"].get("cpu")}
    return "; ".join(sorted(seen)) or None


def revision() -> str:
    """This code's revision (:func:`tamedpuma.app.models.code_revision`, what runs record), its
    git hash cut to 7 characters as :func:`run_revisions` cuts the runs'."""
    from tamedpuma.app.models import code_revision

    return short_revision(code_revision())


# ----------------------------------------------------------------------------- the block


def block(name: str, runs: Path, command: str | None, img: Path) -> str:
    """The result block of experiment ``name`` from the analysis outputs in ``runs``."""
    exp = EXPERIMENTS[name]
    found = summaries(runs)
    lines = [MARKERS[0].format(name), f"## {exp.title}", "",
             f"- command: `{command or exp.command}`, analysed from `{runs}`",
             f"- date: {run_dates(found)} ({len(found)} runs)",
             f"- machine: {run_machines(found) or machine() + HOST}",
             f"- code: {run_revisions(found) or '`' + revision() + '`' + HOST}",
             f"- models (sha256): {models(found)}", ""]
    for table in exp.tables:
        path = runs / table
        if not path.is_file():
            raise PageError(f"{path} not found: run the experiment's analysis on {runs} first "
                            "(docs/experiments.md)")
        lines += [path.read_text().strip(), ""]
    for figure in exp.figures:
        path = runs / figure
        if not path.is_file():
            raise PageError(f"{path} not found: run the experiment's analysis on {runs} first")
        img.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, img / path.name)
        lines += [f"![{Path(figure).stem.replace('_', ' ')}](img/{path.name})", ""]
    return "\n".join(lines).rstrip("\n") + "\n" + MARKERS[1]


def read_measured(path: Path) -> tuple[dict, list[dict]]:
    """(provenance, rows) of a measuring command's JSON; PageError if it has no provenance."""
    try:
        found = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise PageError(f"{path} is not readable JSON: {exc}") from None
    if not isinstance(found, dict) or not found.get("provenance") or not found.get("rows"):
        raise PageError(f"{path} holds no stamped rows: write it again with its command "
                        "(python -m tamedpuma.lasa, python -m tamedpuma.train --table ...)")
    return found["provenance"], found["rows"]


def measured_block(name: str, path: Path) -> str:
    """The block of ``name`` (:data:`MEASURED`) from the stamped JSON at ``path``."""
    import importlib

    spec = MEASURED[name]
    stamp, rows = read_measured(path)
    render = importlib.import_module(spec.renderer)
    lines = [MARKERS[0].format(name), f"## {spec.title}", "", spec.about, "",
             *provenance_lines(stamp), "- models: trained by the command",
             f"- figures: `{path}`", "", render.markdown(rows).strip()]
    summary = getattr(render, "targets", None)
    if summary is not None:
        lines += ["", summary(rows)]
    return "\n".join(lines).rstrip("\n") + "\n" + MARKERS[1]


def replace_block(text: str, name: str, new: str) -> str:
    """``text`` with the block of ``name`` replaced (appended when the page has none yet)."""
    start, end = MARKERS[0].format(name), MARKERS[1]
    i = text.find(start)
    if i < 0:
        return text.rstrip("\n") + "\n\n" + new + "\n"
    j = text.find(end, i)
    if j < 0:
        raise PageError(f"the page's block {start} has no closing {end}")
    return text[:i] + new + text[j + len(end):]


def write_readme(readme: Path, runs: Path) -> None:
    """Replace the README's Table-1 block (:mod:`tamedpuma.app.readme_table`) with the table
    the analysis wrote into ``runs``, beside the paper's; PageError if the README has none."""
    from tamedpuma.app import readme_table

    text = readme.read_text() if readme.is_file() else ""
    start = MARKERS[0].format(readme_table.BLOCK)
    if start not in text:
        raise PageError(f"{readme} has no block {start} ... {MARKERS[1]} to rewrite")
    found = summaries(runs)
    provenance = (f"Measured {run_dates(found)} ({len(found)} runs; code "
                  f"{run_revisions(found) or '`' + revision() + '`'}; models (sha256) "
                  f"{models(found)}; every column and the machine: "
                  "[docs/results.md](docs/results.md#table-1)), beside the paper's:")
    body = readme_table.summary_block((runs / "table1.md").read_text(), provenance)
    readme.write_text(replace_block(text, readme_table.BLOCK,
                                    f"{start}\n{body}\n{MARKERS[1]}"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("name", choices=sorted([*EXPERIMENTS, *MEASURED]),
                        help="the experiment's block")
    parser.add_argument("runs", type=Path, help="the folder its analysis wrote into (lasa, "
                        "learner: the JSON their command wrote)")
    parser.add_argument("--command", default=None, help="how the runs were made (default: the "
                        "experiment's command)")
    parser.add_argument("--page", type=Path, default=None, help=f"default: {PAGE} of the "
                        "checkout (learner: BENCHMARKS.md; installed: of the current folder)")
    parser.add_argument("--readme", type=Path, default=None, help="table1 only: also rewrite "
                        "this README's Table-1 block (the current rates beside the paper's)")
    args = parser.parse_args(argv)
    page = (MEASURED[args.name] if args.name in MEASURED else EXPERIMENTS[args.name]).page
    args.page = args.page or project_root() / page
    try:
        if args.readme is not None and args.name != "table1":
            raise PageError("--readme goes with the table1 block only")
        if args.name in MEASURED:
            new = measured_block(args.name, args.runs)
        elif not args.runs.is_dir():
            raise PageError(f"{args.runs} is not a folder of runs")
        else:
            new = block(args.name, args.runs, args.command, args.page.parent / "img")
        text = args.page.read_text() if args.page.is_file() else "# Results\n"
        args.page.parent.mkdir(parents=True, exist_ok=True)
        args.page.write_text(replace_block(text, args.name, new))
        if args.readme is not None:
            write_readme(args.readme, args.runs)
    except PageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"rewrote the {args.name} block of {args.page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
