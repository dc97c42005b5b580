"""The whole pipeline with the tiny config, and the entry point's one-line errors."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tamedpuma.app import train
from tamedpuma.puma import checkpoint
from tamedpuma.puma.primitive import PosePrimitive, VectorPrimitive, load_primitive

ROOT = Path(__file__).resolve().parents[1]


def test_tiny_pipeline_end_to_end(tmp_path, capsys):
    """Generate synthetic demos, train, save, load, evaluate: seconds, offline."""
    out = tmp_path / "tiny"
    assert train.main(["task=pouring", "puma=tiny", f"out_dir={out}", "progress=false"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["data_source"] == "synthetic:pouring" and len(report["data_hash"]) == 64
    ev = report["evaluation"]
    assert ev["convergence"]["starts"] >= 1000
    assert set(ev["imitation"]) >= {"rmse", "dtw", "frechet", "dtw_angle"}
    assert 0.0 <= ev["compatibility"]["compatible_fraction"] <= 1.0
    net, meta = checkpoint.load(out / "puma.pt")
    assert meta.dt == 0.03 and meta.goal_convention == "final_pose"
    assert meta.config["task"]["name"] == "pouring" and meta.report["evaluation"]
    assert isinstance(load_primitive(out / "puma.pt"), PosePrimitive)
    # on-demand evaluation of the saved checkpoint reproduces the report
    capsys.readouterr()
    assert train.main(["--evaluate", str(out / "puma.pt")]) == 0
    text = capsys.readouterr().out
    again = json.loads(text[text.index("{"):])
    assert again["evaluation"]["convergence"] == ev["convergence"]
    assert again["gates"]["failures"] == report["gates"]["failures"]  # judged alike


def test_the_summary_names_the_iterations_run():
    """An early stop prints the iterations the run took, not only the schedule's cap."""
    line = train._summary({"train_seconds": 12.5, "iterations": 2400, "iterations_run": 1700})
    assert line.splitlines()[0] == "trained in 12.5 s (1700 of at most 2400 iterations)"
    line = train._summary({"train_seconds": 3.0, "iterations": 30, "iterations_run": 30})
    assert line.splitlines()[0] == "trained in 3.0 s (30 iterations)"


def test_first_order_position_and_seeded(tmp_path):
    reports = []
    for name in ("a", "b"):
        out = tmp_path / name
        assert train.main(["task=tomato", "puma=tiny", "puma.orientation=false", "puma.order=1",
                           f"out_dir={out}", "progress=false", "evaluate=false"]) == 0
        reports.append(json.loads((out / "report.json").read_text()))
    assert reports[0]["final_losses"] == reports[1]["final_losses"]  # seeded
    prim = load_primitive(tmp_path / "a" / "puma.pt")
    assert isinstance(prim, VectorPrimitive) and prim.velocity([0.6, 0.0, 0.3],
                                                               [0.58, -0.214, 0.115]).shape == (3,)


@pytest.mark.parametrize("args, match", [
    (["task=nope"], "Could not find 'task/nope'"),
    (["puma.train.iterations=["], "no viable alternative"),
    (["task.demos=/no/such/folder"], "demonstration folder not found"),
    (["+puma.train.bogus=1"], "unknown key"),
    (["--evaluate", "/no/such.pt"], "file not found"),
])
def test_cli_errors_are_one_line(args, match):
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.train", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    err = proc.stderr.strip()
    assert err.startswith("error: ") and match in err and "\n" not in err
    assert "Traceback" not in proc.stderr


def test_cli_corrupt_checkpoint(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"\x00not a checkpoint")
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.train", "--evaluate", str(bad)],
                          cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.startswith("error: checkpoint")
    assert proc.stderr.count("\n") == 1


@pytest.mark.parametrize("how", ["--config-dir", "searchpath"])
def test_train_finds_a_task_in_a_users_config_folder(tmp_path, how):
    folder = tmp_path / "my_conf"
    (folder / "task").mkdir(parents=True)
    (folder / "task" / "my_pouring.yaml").write_text(
        "defaults:\n  - pouring\n  - _self_\nsynthetic: {n_demos: 3, seed: 1}\n")
    where = ["--config-dir", str(folder)] if how == "--config-dir" else [
        f"hydra.searchpath=[file://{folder}]"]
    out = tmp_path / "out"
    assert train.main([*where, "task=my_pouring", "puma=tiny", f"out_dir={out}",
                       "progress=false", "evaluate=false"]) == 0
    assert json.loads((out / "report.json").read_text())["n_demos"] == 3
