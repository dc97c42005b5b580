"""The sweep's progress line keeps its counts between the jobs of a worker: the done count
equals a walk of the sweep folder at every job, and the total is parsed once per manifest."""

import json
from pathlib import Path

from omegaconf import OmegaConf

from tamedpuma.analysis.runs import set_aside
from tamedpuma.app import callbacks
from tamedpuma.app.sweep import OUTCOMES_FILE


def _walk(root: Path) -> int:
    """The count as a walk of the folder gives it (the definition)."""
    return sum(1 for p in root.rglob("summary.json") if not set_aside(p))


def _run(root: Path, name: str, outcome: str = "complete") -> Path:
    """A job of the sweep: its summary, then its line in the outcomes file (as ``_job``)."""
    run = root / "tomato" / name
    run.mkdir(parents=True, exist_ok=True)
    (run / "summary.json").write_text("{}")
    with open(root / OUTCOMES_FILE, "a") as fh:
        fh.write(json.dumps({"run_dir": str(run), "outcome": outcome, "why": ""}) + "\n")
    return run


def test_the_done_count_follows_the_folder_without_walking_it_again(tmp_path, monkeypatch):
    root = tmp_path / "sweep"
    kept = _run(root, "kept")
    old = root / "tomato" / "rerun" / "previous_attempt"  # an attempt set aside: not counted
    old.mkdir(parents=True)
    (old / "summary.json").write_text("{}")
    callbacks.forget_progress()
    done = callbacks.done_runs(root)
    assert done is callbacks.done_runs(root) and done.count() == _walk(root) == 1
    walks = []
    monkeypatch.setattr(Path, "rglob", lambda *a: walks.append(a) or iter(()))
    for i in range(3):
        _run(root, f"job{i}")
        assert done.count() == 2 + i
    (kept / "summary.json").unlink()  # a rerun sets the kept summary aside until it ends
    assert done.count() == 3
    _run(root, "kept")
    assert done.count() == 4 and not walks
    monkeypatch.undo()
    assert done.count() == _walk(root)
    with open(root / OUTCOMES_FILE, "a") as fh:  # a line still being written is not read yet
        fh.write('{"run_dir": "')
    assert done.count() == 4


def test_a_replaced_outcomes_file_walks_the_folder_again(tmp_path):
    root = tmp_path / "sweep"
    for name in ("a", "b", "c"):
        _run(root, name)
    callbacks.forget_progress()
    done = callbacks.done_runs(root)
    assert done.count() == 3
    (root / OUTCOMES_FILE).write_text("")
    (root / "tomato" / "d").mkdir()
    (root / "tomato" / "d" / "summary.json").write_text("{}")
    assert done.count() == _walk(root) == 4


def test_the_total_is_parsed_once_per_version_of_the_manifest(tmp_path, monkeypatch):
    manifest = tmp_path / "multirun.yaml"
    manifest.write_text("hydra:\n  sweeper:\n    params:\n      method: fpm,cpm\n"
                        "      scenario.random_seed: range(2000,2005)\n  overrides:\n"
                        "    task: []\n")
    callbacks.forget_progress()
    loads = []
    load = OmegaConf.load
    monkeypatch.setattr(OmegaConf, "load", lambda p: loads.append(p) or load(p))
    assert callbacks.sweep_total(manifest) == callbacks.sweep_total(manifest) == 10
    assert len(loads) == 1
    manifest.write_text(manifest.read_text().replace("fpm,cpm", "fpm,cpm,puma"))
    assert callbacks.sweep_total(manifest) == 15 and len(loads) == 2
    assert callbacks.sweep_total(tmp_path / "missing.yaml") == "?"
