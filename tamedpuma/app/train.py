"""Train a PUMA primitive: ``python -m tamedpuma.train task=tomato [overrides...]``.

Composes ``conf/train.yaml`` with Hydra overrides (``task=pouring``, ``puma=tiny``,
``task.demos=../shared/data/pumafabrics-demos/pick_tomato_31may``, ``seed=1``, ``out_dir=...``),
trains with a progress bar, writes ``<out_dir>/puma.pt`` and ``<out_dir>/report.json`` and prints
a summary. ``python -m tamedpuma.train --evaluate runs/puma/tomato/puma.pt`` re-evaluates a
checkpoint on demand. ``python -m tamedpuma.train --table OUT.md [--sets tomato,pouring_v2]
[--seeds 0,1,2] [--orders 2,1] [--runs DIR] [--data DIR] [overrides...]`` trains and evaluates every
demonstration set at hand (:data:`TABLE_SETS`) and writes one table (:mod:`tamedpuma.puma.
learner_table`). A user's own config folder: ``--config-dir DIR`` or
``hydra.searchpath=[file://DIR]`` (its ``task/*.yaml`` next to the shipped ones).
User errors print one line ``error: ...`` on stderr and exit with status 2.
"""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

from tamedpuma.app.cli import command
from tamedpuma.app.compose import compose_dict as compose
from tamedpuma.app.config import workspace_starts
from tamedpuma.errors import ConfigError


def _summary(report: dict) -> str:
    ev = report.get("evaluation", {})
    im, cv, cp = ev.get("imitation", {}), ev.get("convergence", {}), ev.get("compatibility", {})
    run, cap = report.get("iterations_run"), report.get("iterations")
    done = f"{cap} iterations" if run in (None, cap) else f"{run} of at most {cap} iterations"
    lines = [f"trained in {report.get('train_seconds')} s ({done})"]
    if ev:
        lines.append(f"imitation: DTW/point {im.get('dtw'):.4g}, RMSE {im.get('rmse'):.4g}, "
                     f"Frechet {im.get('frechet'):.4g}"
                     + (f", DTW angle {im['dtw_angle']:.4g} rad" if "dtw_angle" in im else ""))
        lines.append(f"convergence: {100 * cv.get('converged_fraction', 0):.1f}% of "
                     f"{cv.get('starts')} random starts (max final error "
                     f"{cv.get('final_pos_error_max'):.3g}, angle "
                     f"{cv.get('final_angle_error_max'):.3g} rad)")
        lines.append(f"psi-compatible: {100 * cp.get('compatible_fraction', 0):.1f}% of "
                     f"{cp.get('samples')} states; inference {report.get('inference')}")
    lines.append(f"checkpoint: {report.get('checkpoint')}")
    return "\n".join(lines)


def evaluate_checkpoint(path: str, overrides: list[str]) -> dict:
    """Re-evaluate a saved checkpoint with its own data config (``--evaluate PATH``)."""
    from tamedpuma.paths import resolve
    from tamedpuma.puma import checkpoint, evaluation, pipeline

    net, meta = checkpoint.load(resolve(path))
    from tamedpuma.app.schema import as_dict, train_config

    cfg = as_dict(train_config({k: v for k, v in meta.config.items() if k != "command"}))
    if overrides:
        raise ConfigError("--evaluate takes no overrides")
    demos = pipeline.load_demos(cfg["task"], cfg["puma"])
    if demos.data_hash != meta.data_hash:
        raise ConfigError(f"the configured demonstrations ({demos.source}) differ from the "
                          "checkpoint's training data (hash mismatch)")
    eval_kw = dict(cfg["puma"]["eval"])
    stored = (meta.report.get("evaluation") or {}).get("convergence") or {}
    eval_kw.update({k: stored[k] for k in ("pos_tol", "ang_tol") if k in stored})
    eval_cfg = evaluation.EvalConfig(**eval_kw)
    report = {"checkpoint": path, "evaluation": evaluation.evaluate(net, demos, meta.workspace,
                                                                    eval_cfg)}
    from tamedpuma.puma import gates

    spread, nearest = gates.nearest_demos(demos)
    failures = gates.check(report["evaluation"], spread, gates.demo_names(demos), eval_cfg,
                           demos.unit, nearest, gates.demo_extent(demos),
                           gates.routes_followed_by(net, demos),
                           gates.first_order_field(demos, net.spec.order, eval_cfg))
    report["gates"] = gates.as_report(failures, spread, eval_cfg)
    for f in failures:
        print(f"warning: gate {f.gate}: {f.line}", file=sys.stderr)
    return report


#: the demonstration sets of ``--table``: name -> overrides ({root}: the authors' demonstrations)
TABLE_SETS = {
    "tomato": ["task=tomato", "task.demos={root}/pick_tomato_31may"],
    "pouring_v2": ["task=pouring", "task.demos={root}/pouring_v2"],
    "pouring_other": ["task=from_demos", "task.demos={root}/pouring", "task.name=pouring_other"],
    "synthetic_tomato": ["task=tomato"],
    "synthetic_pouring": ["task=pouring"],
}
TABLE_DEFAULT = "tomato,pouring_v2,pouring_other,synthetic_tomato,synthetic_pouring,lasa"


def _table_overrides(name: str, order: int, root) -> list[str]:
    """The overrides of one set (``lasa`` = all 30 shapes, ``lasa:Angle`` one) and order."""
    if name.startswith("lasa:"):
        return ["task=lasa", "puma=lasa", f"task.shape={name[5:]}", "task.name=lasa"]
    if name not in TABLE_SETS:
        raise ConfigError(f"unknown set {name!r} (one of: {', '.join(TABLE_SETS)}, lasa, "
                          "lasa:SHAPE)")
    ov = [o.format(root=root) for o in TABLE_SETS[name]]
    if "{root}" in " ".join(TABLE_SETS[name]) and root is None:
        raise ConfigError(f"set {name!r} needs the authors' demonstrations: fetch them with "
                          "`python -m tamedpuma.models download`")
    return ov + (["puma=position"] if order == 1 else [])


def table_main(argv: list[str]) -> int:
    """``--table OUT.md [--sets ...] [--seeds ...] [--orders ...] [--runs DIR] [overrides]``."""
    from tamedpuma.paths import resolve
    from tamedpuma.puma import data, download, learner_table

    opts = {"--sets": TABLE_DEFAULT, "--seeds": "0,1,2", "--orders": "2",
            "--runs": "runs/learner_table", "--data": ""}
    out, rest, i = Path(argv[0]), [], 1
    while i < len(argv):
        if argv[i] in opts:
            if i + 1 >= len(argv):
                raise ConfigError(f"{argv[i]} needs a value")
            opts[argv[i]], i = argv[i + 1], i + 2
        elif argv[i].startswith("--"):
            raise ConfigError(f"unknown option {argv[i]} (--table takes --sets, --seeds, "
                              "--orders, --runs, --data and overrides)")
        else:
            rest, i = rest + [argv[i]], i + 1
    try:
        seeds = [int(s) for s in opts["--seeds"].split(",")]
        orders = [int(s) for s in opts["--orders"].split(",")]
    except ValueError:
        raise ConfigError("--seeds and --orders take comma-separated integers") from None
    sets = [s for name in opts["--sets"].split(",")
            for s in (["lasa:" + n for n in data.lasa_names()] if name == "lasa" else [name])]
    root = Path(opts["--data"]).expanduser() if opts["--data"] else download.find_root()
    jobs = []  # seed by seed: every set's first seed comes first
    for seed in seeds:
        for name in sets:
            for order in orders if not name.startswith("lasa:") else [2]:
                run_dir = Path(opts["--runs"]) / name.replace(":", "_") / f"o{order}_s{seed}"
                cfg = compose("train", [*_table_overrides(name, order, root), f"seed={seed}",
                                        f"out_dir={run_dir}", "overwrite=true",
                                        "progress=false", *rest])
                jobs.append(learner_table.Job(name, order, seed, cfg,
                                              tuple(workspace_starts(cfg["task"]))))
    from tamedpuma.app import provenance

    start = provenance.stamp(provenance.command_line("tamedpuma.train", ["--table", *argv]))
    rows = learner_table.run(jobs, resolve(str(out)), log=lambda m: print(m, file=sys.stderr),
                             stamp=lambda: provenance.with_end(start))
    print(learner_table.markdown(rows))
    return 0


def _interrupted_line(cfg: dict) -> str:
    """Where an interrupted training's resumable state is (or that there is none yet)."""
    from tamedpuma.paths import resolve
    from tamedpuma.puma.pipeline import STATE_FILE

    state = resolve(str(cfg["out_dir"])) / STATE_FILE
    if state.is_file():
        return (f"interrupted: the training's last save is {state} (every {cfg['save_every']} "
                "iterations); run the same command again to resume from it")
    return (f"interrupted before the first save (save_every={cfg['save_every']}): nothing to "
            f"resume, no model written in {state.parent}")


@command(__doc__)
def main(argv: list[str]) -> int:
    if argv and argv[0] == "--table":
        if len(argv) < 2:
            raise ConfigError("--table needs an output file, e.g. --table learner.md")
        return table_main(argv[1:])
    if argv and argv[0] == "--evaluate":
        if len(argv) < 2:
            raise ConfigError("--evaluate needs a checkpoint path")
        report = evaluate_checkpoint(argv[1], argv[2:])
        print(json.dumps(report, indent=2))
        return 0
    from tamedpuma.app.cli import split_argv, with_search_path

    overrides, search, flags = split_argv(argv)  # --config-dir DIR, hydra.searchpath=[...]
    for name in ("--config-dir", "-cd"):
        if name in flags and not Path(flags[name]).expanduser().is_dir():
            raise ConfigError(f"config folder not found: {flags[name]!r} ({name})")
    unknown = sorted(set(flags) - {"--config-dir", "-cd"})
    if unknown:
        raise ConfigError(f"unknown option(s) {', '.join(unknown)} (train takes overrides, "
                          "--config-dir DIR and --evaluate CKPT)")
    cfg = compose("train", with_search_path(overrides, search))
    cfg["command"] = " ".join(["python -m tamedpuma.train", *argv])
    from tamedpuma.paths import resolve
    from tamedpuma.puma import pipeline

    # SIGTERM unwinds like Ctrl-C, so both say where the resumable state is
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    out_dir = resolve(str(cfg["out_dir"]))
    created = not out_dir.exists()
    try:
        report = pipeline.run(cfg, log=lambda m: print(m, file=sys.stderr),
                              starts=workspace_starts(cfg["task"]))
    except (KeyboardInterrupt, SystemExit) as exc:
        _remove_if_empty(out_dir, created)
        if isinstance(exc, SystemExit) and exc.code in (0, None):
            raise
        print(_interrupted_line(cfg), file=sys.stderr)
        return 130 if isinstance(exc, KeyboardInterrupt) else 143
    except Exception:
        _remove_if_empty(out_dir, created)  # a failed training leaves no empty folder
        raise
    print(_summary(report))
    return 0


def _remove_if_empty(folder: Path, created: bool) -> None:
    """Remove ``folder`` if this training created it and left nothing in it."""
    if created and folder.is_dir() and not any(folder.iterdir()):
        folder.rmdir()


if __name__ == "__main__":
    sys.exit(main())
