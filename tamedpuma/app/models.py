"""The trained PUMA models: ``python -m tamedpuma.models {list,build,download,ship}``.

``list``      which model each task's methods use now (origin, file, sha256, training data);
``build``     train the four real-data models (tomato, pouring; second order R³×S³ and first-order
              position for Modulation-IK) on the authors' demonstrations, in parallel
              (``--jobs``, default: all cores), into the user cache
              ``${XDG_CACHE_HOME:-~/.cache}/tamedpuma/models/<key>/`` (``$TAMEDPUMA_CACHE``
              overrides the root), ``key`` = sha256 of data, training config and training-code
              version; models already there are kept, and the keys planned are recorded as
              the current recipe's (``models/current.json``: the models every run then takes,
              whichever recipe was built last). The demonstrations are read from
              ``--data DIR``, ``$TAMEDPUMA_DEMOS``, ``../shared/data/pumafabrics-demos`` or the
              download folder, each file checked against its pinned sha256 first;
``download``  fetch the authors' demonstrations at the pinned commit (``--base-url`` for a mirror),
              checking every sha256;
``ship``      retrain the synthetic-data models shipped in ``tamedpuma/puma/shipped/`` with the
              committed commands (maintainers; deterministic for a machine).

Every model folder holds ``puma.pt``, ``report.json`` (its evaluation) and ``manifest.json``
(command, resolved config, code revision, data source and sha256, model sha256, the report).
User errors print one line ``error: ...`` and exit with status 2.
"""

from __future__ import annotations

import argparse
import datetime
import fcntl
import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from tamedpuma import paths
from tamedpuma.errors import TamedPumaError
from tamedpuma.parallel import usable_cores
from tamedpuma.puma import download, store

TASKS = ("tomato", "pouring")
#: the shipped models use the default training config
SHIPPED_OVERRIDES: tuple[str, ...] = ()
ORDERS = (2, 1)


@dataclass(frozen=True)
class Job:
    """One model to train: ``python -m tamedpuma.train <overrides> out_dir=<out_dir>``."""

    name: str            # tomato | tomato_position | ...
    task: str
    order: int
    overrides: tuple[str, ...]
    out_dir: Path        # final folder (puma.pt, report.json, manifest.json)
    command: str         # the command as a user types it
    data: dict = field(default_factory=dict)  # kind, source, sha256 (+ files for real data)
    key: str | None = None


def _train_overrides(task: str, order: int, demos: str | None) -> list[str]:
    ov = [f"task={task}"]
    if demos is not None:
        ov.append(f"task.demos={demos}")
    if order == 1:
        ov.append("puma=position")
    return ov


def _compose(overrides: list[str]) -> dict:
    from tamedpuma.app.compose import compose_dict

    return compose_dict("train", list(overrides))


def _data_of(cfg: dict) -> tuple[str, str]:
    """(source, sha256) of the demonstrations a training config reads (loads them, no training)."""
    from tamedpuma.puma import pipeline

    demos = pipeline.load_demos(cfg["task"], cfg["puma"])
    return demos.source, demos.data_hash


def code_revision() -> str:
    """``git describe`` of the checkout (with ``-dirty``), else (an installed package: git would
    describe whatever repository holds site-packages) the package version."""
    if paths.in_checkout():
        try:
            out = subprocess.run(["git", "-C", str(paths.CHECKOUT_ROOT), "describe", "--always",
                                  "--dirty", "--abbrev=40"], capture_output=True, text=True,
                                 timeout=10)
            if out.returncode == 0 and out.stdout.strip():
                return out.stdout.strip()
        except (OSError, subprocess.SubprocessError):
            pass
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"tamedpuma {version('tamedpuma')}"
    except PackageNotFoundError:
        return "unknown"


def plan_real(root: Path, tasks=TASKS, orders=ORDERS) -> list[Job]:
    """The real-data models, keyed for the cache; every data file checked first."""
    jobs = []
    for task in tasks:
        folder = download.TASK_FOLDERS[task]
        files = download.verify_folder(root, folder)
        for order in orders:
            ov = _train_overrides(task, order, str(root / folder))
            cfg = _compose(ov)
            source, digest = _data_of(cfg)
            key = store.model_key(digest, cfg)
            name = store.model_name(task, order)
            cmd = " ".join(["python -m tamedpuma.train", *ov,
                            f"out_dir={store.models_dir() / key}"])
            data = {"kind": "real", "source": source, "sha256": digest,
                    "origin": f"tud-amr/pumafabrics@{download.COMMIT}/{download.REPO_PATH}/"
                              f"{folder}",
                    "files": {f.name: download.file_sha256(f) for f in files}}
            jobs.append(Job(name, task, order, tuple(ov), store.models_dir() / key, cmd, data,
                            key))
    return jobs


def plan_shipped(tasks=TASKS, orders=ORDERS) -> list[Job]:
    jobs = []
    for task in tasks:
        for order in orders:
            name = store.model_name(task, order)
            rel = Path("tamedpuma") / "puma" / "shipped" / name
            ov = [*_train_overrides(task, order, None), *SHIPPED_OVERRIDES, "overwrite=true",
                  f"out_dir={rel}"]
            source, digest = _data_of(_compose(ov))
            jobs.append(Job(name, task, order, tuple(ov), store.SHIPPED_DIR / name,
                            " ".join(["python -m tamedpuma.train", *ov]),
                            {"kind": "synthetic", "source": source, "sha256": digest}))
    return jobs


def missing(jobs: list[Job]) -> list[Job]:
    return [j for j in jobs if not (j.out_dir / "manifest.json").is_file()
            or not (j.out_dir / "puma.pt").is_file()]


def write_manifest(job: Job, folder: Path, seconds: float | None = None) -> dict:
    """``manifest.json`` of a trained model folder."""
    report = json.loads((folder / "report.json").read_text())
    pt = folder / "puma.pt"
    cfg = _compose([*job.overrides] + ([] if any(o.startswith("out_dir=") for o in job.overrides)
                                       else [f"out_dir={job.out_dir}"]))
    report["checkpoint"] = "puma.pt"  # relative: the folder moves (cache rename, package)
    manifest = {
        "name": job.name, "task": job.task, "order": job.order,
        "command": job.command, "config": cfg,
        "code_revision": code_revision(), "code_version": store.training_code_version(),
        "key": job.key,
        "data": job.data,
        "model": {"file": "puma.pt", "sha256": store.file_sha256(pt), "bytes": pt.stat().st_size},
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "build_seconds": None if seconds is None else round(seconds, 1),
        "report": report,
    }
    (folder / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def key_lock(out_dir: Path, wait: bool = True):
    """An exclusive lock on the model folder ``out_dir`` across processes (``<out_dir>.lock``,
    ``flock``): the open lock file, or None when another process holds it and ``wait`` is
    false. Two builds of one cache key (two sweeps, or ``models build`` beside a sweep) would
    otherwise train into the same ``.partial`` folder, each deleting the other's work; the
    second waits for the first and takes its model. Closing the file releases the lock."""
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    handle = open(out_dir.with_name(out_dir.name + ".lock"), "w")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
    except BlockingIOError:
        handle.close()
        return None
    return handle


def run_jobs(jobs: list[Job], parallel: int, log=print, staged: bool = True) -> list[Path]:
    """Train ``jobs`` with at most ``parallel`` at once (one torch thread each). With ``staged``
    each trains into ``<out_dir>.partial`` and is renamed when complete (a killed build leaves
    no half model in the cache), holding the folder's :func:`key_lock`: a job whose model
    another process is building waits for it and takes that model. Returns the model folders;
    a failed training is an error."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(paths.CHECKOUT_ROOT), env.get("PYTHONPATH", "")])
    pending, running, done, failed = list(jobs), [], [], []
    t0 = time.perf_counter()
    while pending or running:
        while pending and len(running) < max(1, parallel):
            job = pending.pop(0)
            lock = None
            if staged:
                lock = key_lock(job.out_dir, wait=False)
                if lock is None:
                    log(f"waiting for another process building {job.name} -> {job.out_dir}")
                    lock = key_lock(job.out_dir)
                if not missing([job]):  # built meanwhile by the process that held the lock
                    lock.close()
                    done.append(job.out_dir)
                    log(f"{job.name}: built by another process ({job.out_dir})")
                    continue
            work = job.out_dir.with_name(job.out_dir.name + ".partial") if staged else job.out_dir
            running.append((job, work, *_launch(job, work, env, fresh=staged),
                            time.perf_counter(), lock))
            log(f"training {job.name} ({job.data.get('kind')} data) -> {job.out_dir}")
        time.sleep(1.0)
        for item in list(running):
            job, work, proc, logf, start, lock = item
            if proc.poll() is None:
                continue
            running.remove(item)
            logf.close()
            try:  # the folder's lock is released however the job ends
                seconds = time.perf_counter() - start
                if proc.returncode != 0:
                    tail = (work / "train.log").read_text().strip().splitlines()[-1:] or ["?"]
                    failed.append(f"{job.name}: {tail[0]} (log: {work / 'train.log'})")
                    log(f"FAILED {job.name} after {seconds:.0f} s: {tail[0]}")
                    continue
                write_manifest(job, work, seconds)
                if staged:
                    if job.out_dir.exists():
                        shutil.rmtree(job.out_dir)
                    work.rename(job.out_dir)
            finally:
                if lock is not None:
                    lock.close()
            done.append(job.out_dir)
            log(f"built {job.name} in {seconds:.0f} s "
                f"({len(done)}/{len(jobs)}, {time.perf_counter() - t0:.0f} s so far)")
            gate_warnings(job.name, job.out_dir, log)
    if failed:
        raise TamedPumaError("training failed: " + "; ".join(failed))
    return done


def _launch(job: Job, work: Path, env: dict, fresh: bool) -> tuple[subprocess.Popen, object]:
    """Start ``job``'s training into ``work`` (emptied first with ``fresh``), its output to
    ``train.log``; returns the process and the open log file."""
    if fresh and work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    ov = [o for o in job.overrides if not o.startswith("out_dir=")]
    logf = open(work / "train.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "tamedpuma.train", *ov,
                             f"out_dir={work}", "progress=false"],
                            stdout=logf, stderr=subprocess.STDOUT, env=env)
    return proc, logf


def gate_warnings(name: str, folder: Path, log=print) -> list[str]:
    """Say which gates the model in ``folder`` failed after its training (its ``report.json``,
    :mod:`tamedpuma.puma.gates`); returns those lines."""
    from tamedpuma.puma.gates import failed_lines

    try:
        report = json.loads((folder / "report.json").read_text())
    except (OSError, ValueError):
        return []
    lines = failed_lines(report)
    if lines:
        log(f"warning: {name} ({folder}) failed {len(lines)} gate(s):")
        for line in lines:
            log(f"  - {line}")
    return lines


def data_root(arg: str | None) -> Path:
    if arg:
        return Path(arg).expanduser()
    root = download.find_root()
    if root is None:
        raise TamedPumaError("the authors' demonstrations were not found (looked in "
                             + ", ".join(str(r) for r in download.candidate_roots())
                             + "): fetch them with `python -m tamedpuma.models download` "
                             "or pass --data DIR")
    return root


def ensure_real_models(data: str | None = None, parallel: int | None = None,
                       log=print) -> list[Path]:
    """Build the real-data models that are missing from the cache (the Table-1 experiment calls
    this first). Returns the four model folders."""
    jobs = plan_real(data_root(data))
    store.set_current_keys({j.name: j.key for j in jobs})  # what a run of this recipe takes
    todo = missing(jobs)
    if todo:
        n = parallel or usable_cores()
        log(f"building {len(todo)} real-data model(s) ({', '.join(j.name for j in todo)}), "
            f"{min(n, len(todo))} at a time, into {store.models_dir()}")
        run_jobs(todo, min(n, len(todo)), log)
    else:
        log(f"real-data models cached in {store.models_dir()}")
        for j in jobs:
            gate_warnings(j.name, j.out_dir, log)
    return [j.out_dir for j in jobs]


def cmd_list() -> int:
    for task in TASKS:
        for order in ORDERS:
            try:
                c = store.resolve(task, order)
                print(f"{store.model_name(task, order):18s} {c.describe()}")
            except TamedPumaError as exc:
                print(f"{store.model_name(task, order):18s} none: {exc}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tamedpuma.models",
                                     description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="which model each task uses")
    b = sub.add_parser("build", help="train the real-data models into the user cache")
    b.add_argument("--data", help="folder holding pick_tomato_31may/ and pouring_v2/")
    b.add_argument("--jobs", type=int, default=None, help="parallel trainings (default: cores)")
    d = sub.add_parser("download", help="fetch the authors' demonstrations (sha256-checked)")
    d.add_argument("--base-url", default=None,
                   help=f"mirror of {download.DEFAULT_BASE_URL} (or $TAMEDPUMA_DEMOS_URL)")
    d.add_argument("--dest", default=None,
                   help=f"target folder (default {download.default_dest()})")
    d.add_argument("--folders", nargs="+", default=list(download.TASK_FOLDERS.values()))
    s = sub.add_parser("ship", help="retrain the shipped synthetic-data models (maintainers)")
    s.add_argument("--jobs", type=int, default=2)
    s.add_argument("--only", nargs="+", default=None, help="model names, e.g. tomato_position")
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        if args.cmd == "list":
            return cmd_list()
        if args.cmd == "build":
            ensure_real_models(args.data, args.jobs)
            return cmd_list()
        if args.cmd == "download":
            download.download(Path(args.dest) if args.dest else None, args.base_url,
                              tuple(args.folders))
            return 0
        if args.cmd == "ship":
            jobs = [j for j in plan_shipped() if not args.only or j.name in args.only]
            run_jobs(jobs, args.jobs, staged=False)
            return 0
    except TamedPumaError as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
