"""Shipped models, the model resolution order, the real-data cache key, the download of the
authors' demonstrations (against a local HTTP server only) and what git and the wheel contain."""

from __future__ import annotations

import functools
import http.server
import json
import shutil
import subprocess
import sys
import threading
import zipfile
from pathlib import Path

import pytest

from tamedpuma import paths
from tamedpuma.errors import CheckpointError, DataError
from tamedpuma.puma import download, store

REPO = Path(__file__).resolve().parents[1]
NAMES = ("tomato", "tomato_position", "pouring", "pouring_position")


@pytest.fixture
def isolated(tmp_path, monkeypatch):
    """An empty user cache and a working directory without runs/."""
    monkeypatch.setenv("TAMEDPUMA_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(paths, "CHECKOUT_ROOT", tmp_path)  # no ../shared beside the checkout
    return tmp_path


@pytest.mark.parametrize("name", NAMES)
def test_shipped_model_has_a_manifest_that_matches_it(name):
    folder = store.SHIPPED_DIR / name
    man = json.loads((folder / "manifest.json").read_text())
    pt = folder / "puma.pt"
    assert man["model"]["sha256"] == store.file_sha256(pt)
    assert man["model"]["bytes"] == pt.stat().st_size < 1_500_000
    assert man["data"]["kind"] == "synthetic" and man["data"]["source"].startswith("synthetic:")
    assert man["command"].startswith("python -m tamedpuma.train task=")
    assert ("puma=position" in man["command"]) == name.endswith("_position")
    assert man["config"]["task"]["demos"] is None  # trained on the seeded synthetic demos
    assert man["code_revision"] and man["code_version"]
    ev = man["report"]["evaluation"]  # the evaluation report travels with the model
    assert ev["convergence"]["starts"] == 1000 and 0 <= ev["convergence"]["converged_fraction"] <= 1
    # the checkpoint's own header agrees with the manifest
    from tamedpuma.puma import checkpoint

    net, meta = checkpoint.load(pt)
    assert meta.data_hash == man["data"]["sha256"] and meta.data_source == man["data"]["source"]
    assert net.spec.order == (1 if name.endswith("_position") else 2)


#: sha256 of the seeded synthetic tomato demonstrations rounded to 1e-8 (signed zeros folded):
#: the same data on any CPU, where the exact bytes are not (numpy's SIMD sin/cos/exp differ in
#: the last bit between CPUs: the manifest's exact hash was taken on an AMD EPYC and does not
#: match on an Intel Xeon with AVX-512)
SYNTHETIC_TOMATO_ROUNDED = "85ef937d6912bd7f12eae7f235cbeed225055be7352b789c8dc416750274cc51"


def _rounded_fingerprint(raws) -> str:
    import hashlib

    import numpy as np

    h = hashlib.sha256()
    for r in raws:
        for a in (r.pos, r.quat, r.delta_t):
            if a is not None:
                h.update((np.round(np.asarray(a, dtype=np.float64), 8) + 0.0).tobytes())
    return h.hexdigest()


def test_shipped_data_hash_is_that_of_the_seeded_synthetic_demonstrations():
    """The shipped model was trained on the seeded synthetic demonstrations: their exact hash is
    the manifest's on the machine that built it; on any machine they round to the same data."""
    from tamedpuma.app.train import compose
    from tamedpuma.puma import data, pipeline

    man = json.loads((store.SHIPPED_DIR / "tomato" / "manifest.json").read_text())
    cfg = compose("train", ["task=tomato"])
    raws, source, _ = pipeline.load_raws(cfg["task"], cfg["puma"])
    assert source == man["data"]["source"] == "synthetic:tomato"
    assert (data.data_hash(raws) == man["data"]["sha256"]
            or _rounded_fingerprint(raws) == SYNTHETIC_TOMATO_ROUNDED)
    assert pipeline.load_demos(cfg["task"], cfg["puma"]).data_hash == data.data_hash(raws)


@pytest.mark.parametrize("task, order", [("tomato", 2), ("pouring", 1)])
def test_fresh_install_resolves_to_the_shipped_model(isolated, task, order):
    c = store.resolve(task, order)
    assert c.origin == "shipped" and c.path == store.shipped_path(task, order).resolve()
    assert c.sha256 == store.file_sha256(c.path) and c.data_kind == "synthetic"
    meta = c.metadata()
    assert meta["model_sha256"] == c.sha256 and meta["model_data"] == "synthetic"
    with pytest.raises(CheckpointError, match="python -m tamedpuma.models build"):
        store.resolve(task, order, model="real")


def _fake_real(folder: Path, name: str, src: Path, code: str | None = None) -> Path:
    folder.mkdir(parents=True)
    shutil.copy(src, folder / "puma.pt")
    man = {"name": name, "data": {"kind": "real", "source": "/data/pick_tomato_31may",
                                  "sha256": "ab" * 32},
           "code_version": code or store.training_code_version()}
    (folder / "manifest.json").write_text(json.dumps(man))
    return folder / "puma.pt"


def test_order_is_explicit_then_cache_then_user_then_shipped(isolated):
    shipped = store.shipped_path("tomato", 2)
    # a user-trained model on synthetic data does not count as a real-data model
    user = isolated / "runs" / "puma" / "tomato"
    user.mkdir(parents=True)
    shutil.copy(shipped, user / "puma.pt")
    (user / "report.json").write_text(json.dumps({"data_source": "synthetic:tomato",
                                                  "data_hash": "00"}))
    assert store.resolve("tomato", 2).origin == "shipped"
    (user / "report.json").write_text(json.dumps({"data_source": "../shared/x/pick_tomato_31may",
                                                  "data_hash": "cd" * 32}))
    c = store.resolve("tomato", 2)
    assert c.origin == "user" and c.data_kind == "real" and c.data_sha256 == "cd" * 32
    old = _fake_real(store.models_dir() / "old", "tomato", shipped, code="0" * 64)
    new = _fake_real(store.models_dir() / "new", "tomato", shipped)
    _fake_real(store.models_dir() / "pos", "tomato_position", shipped)
    c = store.resolve("tomato", 2)
    assert c.origin == "cache" and c.path == new.resolve()  # the current training code first
    (new.parent / "manifest.json").unlink()
    assert store.resolve("tomato", 2).path == old.resolve()
    assert store.resolve("tomato", 2, model="shipped").origin == "shipped"
    c = store.resolve("tomato", 2, checkpoint=str(shipped))
    assert c.origin == "explicit"
    with pytest.raises(CheckpointError, match="python -m tamedpuma.train task=tomato"):
        store.resolve("tomato", 2, checkpoint="runs/nowhere/puma.pt")


def test_the_current_recipe_s_model_is_taken_not_the_newest(isolated):
    """Models of two recipes in the cache: a run takes the one ``models build`` last planned for
    the recipe (``current.json``), however recently the other was built; where that one is gone
    or the file unreadable, the newest."""
    import os

    shipped = store.shipped_path("tomato", 2)
    mine = _fake_real(store.models_dir() / "mine", "tomato", shipped)
    other = _fake_real(store.models_dir() / "other", "tomato", shipped)
    os.utime(mine, (1, 1))  # built long before the other recipe's
    assert store.resolve("tomato", 2).path == other.resolve()
    store.set_current_keys({"tomato": "mine", "pouring": "p"})
    assert store.resolve("tomato", 2).path == mine.resolve()
    store.set_current_keys({"tomato_position": "q"})  # merged with the others
    assert store.current_keys() == {"tomato": "mine", "pouring": "p", "tomato_position": "q"}
    assert store.resolve("tomato", 2).path == mine.resolve()
    (store.models_dir() / store.CURRENT_FILE).write_text("{not json")
    assert store.current_keys() == {} and store.resolve("tomato", 2).path == other.resolve()
    store.set_current_keys({"tomato": "gone"})
    assert store.resolve("tomato", 2).path == other.resolve()


def test_cache_key_follows_data_config_and_code_not_bookkeeping():
    cfg = {"task": {"name": "tomato", "demos": "/a/pick_tomato_31may"}, "puma": {"dt": 0.03},
           "seed": 0, "out_dir": "x", "progress": True, "command": "python -m ..."}
    key = store.model_key("d" * 64, cfg, "c" * 64)
    moved = {**cfg, "task": {**cfg["task"], "demos": "/b/copy"}, "out_dir": "y",
             "progress": False, "command": "other"}
    assert store.model_key("d" * 64, moved, "c" * 64) == key
    assert store.model_key("e" * 64, cfg, "c" * 64) != key
    assert store.model_key("d" * 64, {**cfg, "seed": 1}, "c" * 64) != key
    assert store.model_key("d" * 64, cfg, "f" * 64) != key


def test_every_method_using_a_model_records_which(isolated, kinematics):
    from tamedpuma.app.schema import method_settings, run_config
    from tamedpuma.app.train import compose

    def model(overrides):
        method = run_config(compose("sweep", overrides)).method
        return store.resolve_for_method(method.name, method_settings(method))

    for method in ("puma", "fpm", "cpm", "modulation_ik"):
        c = model([f"method={method}", "task=pouring"])
        assert c.name == ("pouring_position" if method == "modulation_ik" else "pouring")
    assert model(["method=fabrics"]) is None


# -- what is committed and packaged -----------------------------------------------------------

def _no_authors_data(names_and_bytes):
    pinned = set(download.pinned_sums().values())
    for name, blob in names_and_bytes:
        assert not name.endswith(".pk"), name
        assert store.hashlib.sha256(blob).hexdigest() not in pinned, name
        if name.endswith(".pt"):
            assert "/puma/shipped/" in "/" + name, f"model outside shipped/: {name}"
        if name.endswith("manifest.json"):
            man = json.loads(blob)
            assert man["data"]["kind"] == "synthetic", f"{name}: {man['data']}"
            assert man["config"]["task"]["demos"] is None, name


def test_git_holds_no_demonstration_and_no_model_trained_on_one():
    proc = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip("not a git checkout")
    files = [f for f in proc.stdout.splitlines() if (REPO / f).is_file()]
    _no_authors_data((f, (REPO / f).read_bytes()) for f in files)
    assert sum(f.endswith("/puma.pt") for f in files) == len(NAMES)


@pytest.mark.slow
def test_wheel_ships_the_synthetic_models_and_no_demonstration(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                           "--no-build-isolation", "-q", "-w", str(tmp_path), str(REPO)],
                          capture_output=True, text=True, timeout=300)
    if proc.returncode != 0:
        pytest.skip(f"cannot build a wheel here: {proc.stderr.strip()[-200:]}")
    (wheel,) = tmp_path.glob("tamedpuma-*.whl")
    with zipfile.ZipFile(wheel) as z:
        entries = [(n, z.read(n)) for n in z.namelist() if not n.endswith("/")]
    names = {n for n, _ in entries}
    for name in NAMES:
        assert f"tamedpuma/puma/shipped/{name}/puma.pt" in names
        assert f"tamedpuma/puma/shipped/{name}/manifest.json" in names
    assert "tamedpuma/puma/demos_sha256.txt" in names
    _no_authors_data(entries)
    # every file of the package in git (configs, data) is in the wheel: a non-editable install
    # has nothing else (pyproject.toml's package-data names the files that are not modules)
    tracked = subprocess.run(["git", "-C", str(REPO), "ls-files", "tamedpuma"],
                             capture_output=True, text=True).stdout.split()
    missing = [t for t in tracked if t not in names]
    assert not missing, f"not in the wheel (pyproject.toml's package-data): {missing[:5]}"


# -- download of the authors' demonstrations (local server only) ------------------------------

@pytest.fixture
def mirror(tmp_path, shared_dir):
    """A local HTTP server laid out like the authors' repository at the pinned commit."""
    demos = shared_dir / "data" / "pumafabrics-demos"
    root = tmp_path / "www"
    kuka = root / download.COMMIT / download.REPO_PATH
    kuka.mkdir(parents=True)
    for folder in ("pick_tomato_31may", "pouring_v2"):
        (kuka / folder).symlink_to(demos / folder)
    handler = functools.partial(_QuietHandler, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_port}/{download.COMMIT}/{download.REPO_PATH}", kuka
    server.shutdown()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def test_download_checks_every_file_and_skips_what_is_there(mirror, tmp_path):
    base, _ = mirror
    dest = tmp_path / "demos"
    lines = []
    download.download(dest, base, ("pick_tomato_31may",), log=lines.append)
    assert "10 downloaded, 0 already there" in lines[-1]
    assert len(download.verify_folder(dest, "pick_tomato_31may")) == 10
    download.download(dest, base, ("pick_tomato_31may",), log=lines.append)
    assert "0 downloaded, 10 already there" in lines[-1]


def test_a_corrupt_or_missing_file_is_refused(mirror, tmp_path):
    base, kuka = mirror
    (kuka / "pick_tomato_31may").unlink()
    (kuka / "pick_tomato_31may").mkdir()
    for i in range(10):
        (kuka / "pick_tomato_31may" / f"ee_state_{i}.pk").write_bytes(b"not the authors' file")
    dest = tmp_path / "demos"
    with pytest.raises(DataError, match="sha256"):
        download.download(dest, base, ("pick_tomato_31may",), log=lambda m: None)
    assert not list(dest.rglob("*.pk"))  # nothing unchecked is left in place
    with pytest.raises(DataError, match="cannot download"):
        download.download(dest, base + "/nowhere", ("pick_tomato_31may",), log=lambda m: None)


def test_download_command_against_the_local_mirror(mirror, tmp_path):
    base, _ = mirror
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.models", "download", "--base-url",
                           base, "--dest", str(tmp_path / "d"), "--folders", "pouring_v2"],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "38 downloaded" in proc.stdout
    bad = subprocess.run([sys.executable, "-m", "tamedpuma.models", "download", "--base-url",
                          base, "--dest", str(tmp_path / "d"), "--folders", "no_such"],
                         cwd=REPO, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.startswith("error: unknown demonstration folder")


# -- the real-data build (tiny networks here; the real ones take minutes) --------------------

def test_build_plans_four_keyed_models_and_caches_what_it_trains(isolated, shared_dir):
    import dataclasses

    from tamedpuma.app import models

    root = shared_dir / "data" / "pumafabrics-demos"
    jobs = models.plan_real(root)
    assert sorted(j.name for j in jobs) == sorted(NAMES)
    assert len({j.key for j in jobs}) == 4 and all(j.out_dir.parent == store.models_dir()
                                                   for j in jobs)
    assert {j.key for j in models.plan_real(root)} == {j.key for j in jobs}  # deterministic
    assert all(j.data["kind"] == "real" and len(j.data["files"]) >= 10 for j in jobs)
    tomato = next(j for j in jobs if j.name == "tomato")
    tiny = dataclasses.replace(tomato, overrides=(*tomato.overrides, "puma=tiny"))
    lines = []
    (folder,) = models.run_jobs([tiny], 1, log=lines.append)
    assert folder == tomato.out_dir and not folder.with_name(folder.name + ".partial").exists()
    man = json.loads((folder / "manifest.json").read_text())
    assert man["key"] == tomato.key and man["data"]["sha256"] == tomato.data["sha256"]
    assert man["model"]["sha256"] == store.file_sha256(folder / "puma.pt")
    assert "evaluation" in man["report"] and man["report"]["checkpoint"] == "puma.pt"
    assert models.missing(jobs) == [j for j in jobs if j.name != "tomato"]
    c = store.resolve("tomato", 2)
    assert c.origin == "cache" and c.data_kind == "real" and c.path == (folder / "puma.pt")
    assert store.resolve("tomato", 1).origin == "shipped"  # not built: the shipped one


def test_the_default_parallelism_follows_the_cores_the_process_may_use(monkeypatch, tmp_path,
                                                                     isolated):
    """``taskset -c 0 python -m tamedpuma.sweep +experiment=table1`` trains one model at a time
    on that core, not one per core of the machine on it."""
    from tamedpuma.app import models

    monkeypatch.setattr(models.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    monkeypatch.setattr(models.os, "cpu_count", lambda: 64)
    assert models.usable_cores() == 1
    jobs = [models.Job(f"m{i}", "tomato", 2, (), tmp_path / f"m{i}", "cmd", {}, f"k{i}")
            for i in range(4)]
    seen = []
    monkeypatch.setattr(models, "plan_real", lambda root: jobs)
    monkeypatch.setattr(models, "data_root", lambda data: tmp_path)
    monkeypatch.setattr(models, "run_jobs", lambda todo, parallel, log: seen.append(parallel))
    models.ensure_real_models(log=lambda line: None)
    assert seen == [1]
    assert store.current_keys() == {f"m{i}": f"k{i}" for i in range(4)}  # what runs now take
    models.ensure_real_models(parallel=3, log=lambda line: None)
    assert seen == [1, 3]


def test_a_model_folder_is_locked_across_processes(tmp_path):
    """``key_lock``: while one process holds a model folder's lock, another cannot take it
    without waiting; once released it can."""
    from tamedpuma.app.models import key_lock

    folder = tmp_path / "models" / "abc"
    probe = ("import sys; from pathlib import Path; from tamedpuma.app.models import key_lock; "
             "print(key_lock(Path(sys.argv[1]), wait=False) is None)")

    def busy() -> bool:
        out = subprocess.run([sys.executable, "-c", probe, str(folder)], capture_output=True,
                             text=True, check=True)
        return out.stdout.strip() == "True"

    held = key_lock(folder)
    assert busy()
    held.close()
    assert not busy()


def test_a_build_waits_for_another_process_building_the_same_model(tmp_path):
    """Two builds of one cache key: the second waits for the first's lock and takes its model
    instead of training into the same ``.partial`` folder (no training is started)."""
    from tamedpuma.app.models import Job, key_lock, run_jobs

    folder = tmp_path / "models" / "key"
    job = Job("tomato", "tomato", 2, ("task=tomato",), folder, "python -m tamedpuma.train")
    held = key_lock(folder)  # "the other process"
    lines, result = [], {}
    builder = threading.Thread(
        target=lambda: result.update(done=run_jobs([job], 1, log=lines.append)))
    builder.start()
    builder.join(timeout=2.0)
    assert builder.is_alive() and lines and lines[0].startswith("waiting for another process")
    folder.mkdir(parents=True)
    (folder / "puma.pt").write_bytes(b"model")
    (folder / "manifest.json").write_text("{}")
    held.close()
    builder.join(timeout=30.0)
    assert not builder.is_alive() and result["done"] == [folder]
    assert not any(line.startswith("training") for line in lines), lines
    assert not folder.with_name("key.partial").exists()
