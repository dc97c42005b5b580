"""Where trained PUMA models live, and which one a method uses (no torch here).

A method driven by PUMA (``puma``, ``fpm``, ``cpm``: the second-order R³×S³ model of the task;
``modulation_ik``: the first-order position model ``<task>_position``) takes, in this order:

1. ``explicit``: ``method.checkpoint=PATH`` (found as every configured path is:
   :func:`tamedpuma.paths.resolve`, the working directory, then the package);
2. ``cache``: a real-data model built by ``python -m tamedpuma.models build`` in the user cache
   (``$TAMEDPUMA_CACHE`` or ``${XDG_CACHE_HOME:-~/.cache}/tamedpuma``, folder
   ``models/<key>/`` with ``puma.pt`` and ``manifest.json``; ``key`` = sha256 of the data hash,
   the training config and the training-code version, see :func:`model_key`); among several, the
   one of the current recipe first (the key the last ``models build``, or the sweep that built
   the models before Table 1, planned for it: ``models/current.json``), then one built by the
   current training code, then the newest;
3. ``user``: a model the user trained on real data with the README's command
   (``runs/puma/<task>[_position]/puma.pt`` below the working directory, whose ``report.json``
   names non-synthetic data);
4. ``shipped``: the model trained on the seeded synthetic demonstrations that ships with the
   package (``tamedpuma/puma/shipped/<task>[_position]/``).

``method.model`` narrows the choice: ``auto`` (the order above), ``real`` (2 or 3, else an
error saying how to build one) or ``shipped`` (4). Every run records the choice
(:meth:`ModelChoice.metadata`: path, sha256 of the file, data source and its sha256, origin).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from ..errors import CheckpointError, ConfigError

PACKAGE_DIR = Path(__file__).resolve().parent
SHIPPED_DIR = PACKAGE_DIR / "shipped"
POSITION_METHODS = frozenset({"modulation_ik"})  # use the first-order position model
ORIGINS = ("explicit", "cache", "user", "shipped")


def cache_root() -> Path:
    """``$TAMEDPUMA_CACHE``, else ``$XDG_CACHE_HOME/tamedpuma``, else ``~/.cache/tamedpuma``."""
    if os.environ.get("TAMEDPUMA_CACHE"):
        return Path(os.environ["TAMEDPUMA_CACHE"]).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg).expanduser() / "tamedpuma"


def models_dir() -> Path:
    return cache_root() / "models"


def model_name(task: str, order: int) -> str:
    """``tomato`` (second order, R³×S³) or ``tomato_position`` (first order, R³)."""
    return f"{task}_position" if int(order) == 1 else str(task)


def data_kind(source: str) -> str:
    """``synthetic`` (seeded, shipped), ``lasa`` or ``real`` (recorded demonstrations)."""
    source = str(source or "")
    if source.startswith("synthetic:"):
        return "synthetic"
    if source.startswith("lasa:"):
        return "lasa"
    return "real" if source else "unknown"


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def training_code_version() -> str:
    """sha256 over the sources of the training code (``tamedpuma/puma/*.py`` except this module,
    the builder, the downloader and the one-state inference path, which training never calls):
    a change there changes every cache key, so models are rebuilt."""
    h = hashlib.sha256()
    for path in sorted(PACKAGE_DIR.glob("*.py")):
        if path.name in ("store.py", "build.py", "download.py", "single.py", "single_kernels.py"):
            continue
        h.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def key_config(train_cfg: dict) -> dict:
    """The training config as it enters the cache key: bookkeeping (output folder, progress bar,
    command line) and the data path (the data enters through its hash) left out."""
    cfg = json.loads(json.dumps(train_cfg))
    for k in ("out_dir", "progress", "bench_out", "command"):
        cfg.pop(k, None)
    if isinstance(cfg.get("task"), dict):
        cfg["task"].pop("demos", None)
    return cfg


def model_key(data_hash: str, train_cfg: dict, code_version: str | None = None) -> str:
    """sha256 of (data hash, training config, training-code version): the cache folder name."""
    blob = json.dumps({"data": data_hash, "config": key_config(train_cfg),
                       "code": code_version or training_code_version()}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


@dataclass(frozen=True)
class ModelChoice:
    """The model a run used: file, its sha256, the training data (source, sha256), origin."""

    path: Path
    sha256: str
    data_source: str
    data_sha256: str
    origin: str  # explicit | cache | user | shipped
    name: str = ""  # tomato | tomato_position | ...

    @property
    def data_kind(self) -> str:
        return data_kind(self.data_source)

    def metadata(self) -> dict[str, str]:
        """Flat string map (MCAP metadata, summary.json)."""
        return {"model_name": self.name, "model_path": str(self.path), "model_sha256": self.sha256,
                "model_origin": self.origin, "model_data": self.data_kind,
                "model_data_source": self.data_source, "model_data_sha256": self.data_sha256}

    def describe(self) -> str:
        return (f"{self.origin} model {self.path} (sha256 {self.sha256[:12]}, "
                f"{self.data_kind} data: {self.data_source})")


def read_manifest(folder: Path) -> dict | None:
    """``manifest.json`` (or, for a user-trained model, ``report.json``) of a model folder."""
    for name in ("manifest.json", "report.json"):
        path = folder / name
        if path.is_file():
            try:
                return json.loads(path.read_text())
            except (OSError, ValueError):
                return None
    return None


def _provenance(path: Path) -> tuple[str, str]:
    """(data source, data sha256) of a checkpoint: from its manifest/report, else its header."""
    man = read_manifest(path.parent) or {}
    data = man.get("data") if isinstance(man.get("data"), dict) else {}
    source = data.get("source") or man.get("data_source")
    digest = data.get("sha256") or man.get("data_hash")
    if source and digest:
        return str(source), str(digest)
    from .checkpoint import load  # torch: only for a bare checkpoint without a manifest

    _, meta = load(path)
    return meta.data_source, meta.data_hash


def choice(path: Path, origin: str, name: str = "") -> ModelChoice:
    source, digest = _provenance(path)
    return ModelChoice(path.resolve(), file_sha256(path), source, digest, origin, name)


def resolve_explicit(path: str) -> Path:
    """An explicit checkpoint path (:func:`tamedpuma.paths.resolve`: absolute, else relative to
    the working directory, else to the package)."""
    from ..paths import resolve

    return resolve(path)


def shipped_path(task: str, order: int) -> Path:
    return SHIPPED_DIR / model_name(task, order) / "puma.pt"


CURRENT_FILE = "current.json"  # {model name: cache key of the current recipe}, in models_dir()


def current_keys() -> dict[str, str]:
    """The cache key of each model name under the current recipe, as the last ``models build``
    planned it ({} where none has run or the file is unreadable)."""
    try:
        keys = json.loads((models_dir() / CURRENT_FILE).read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): str(v) for k, v in keys.items()} if isinstance(keys, dict) else {}


def set_current_keys(keys: dict[str, str]) -> None:
    """Record ``keys`` ({model name: cache key}) as the current recipe's, beside the others
    (written whole through a temporary file, so a reader never sees half of it)."""
    root = models_dir()
    root.mkdir(parents=True, exist_ok=True)
    merged = {**current_keys(), **keys}
    tmp = root / f".{CURRENT_FILE}.{os.getpid()}"
    tmp.write_text(json.dumps(merged, indent=2, sort_keys=True) + "\n")
    os.replace(tmp, root / CURRENT_FILE)


def cached_models(task: str, order: int) -> list[tuple[Path, dict]]:
    """Real-data models of ``task``/``order`` in the cache, best first: the current recipe's
    (:func:`current_keys`), then the current training code's, then the newest. A run's model
    then follows its recipe, not which recipe was built last."""
    root = models_dir()
    if not root.is_dir():
        return []
    code = training_code_version()
    wanted = current_keys().get(model_name(task, order))
    found = []
    for man_path in root.glob("*/manifest.json"):
        try:
            man = json.loads(man_path.read_text())
        except (OSError, ValueError):
            continue
        pt = man_path.parent / "puma.pt"
        if (man.get("name") == model_name(task, order) and pt.is_file()
                and data_kind((man.get("data") or {}).get("source", "")) == "real"):
            rank = (man_path.parent.name == wanted, man.get("code_version") == code)
            found.append((pt, man, rank, pt.stat().st_mtime))
    found.sort(key=lambda f: (f[2], f[3]), reverse=True)
    return [(pt, man) for pt, man, _, _ in found]


def user_model(task: str, order: int) -> Path | None:
    """``runs/puma/<name>/puma.pt`` below the working directory, trained on real data."""
    pt = Path.cwd() / "runs" / "puma" / model_name(task, order) / "puma.pt"
    if pt.is_file():
        rep = read_manifest(pt.parent) or {}
        if data_kind(rep.get("data_source", "")) == "real":
            return pt
    return None


def resolve(task: str, order: int, checkpoint: str | None = None,
            model: str = "auto") -> ModelChoice:
    """The model a method of ``task`` needing a model of ``order`` uses (see module doc)."""
    if model not in ("auto", "real", "shipped"):
        raise ConfigError(f"method.model must be auto, real or shipped, got {model!r}")
    if checkpoint:
        path = resolve_explicit(str(checkpoint))
        if path.is_dir():
            raise CheckpointError(f"checkpoint {checkpoint}: is a folder, not a checkpoint file "
                                  "(the file is its puma.pt)")
        if not path.is_file():
            hint = (f"python -m tamedpuma.train task={task}"
                    + (" puma=position" if int(order) == 1 else "")
                    + f" out_dir={path.parent}")
            raise CheckpointError(f"no PUMA checkpoint at {checkpoint}: train one with `{hint}` "
                                  "(or leave method.checkpoint unset to use the best at hand)")
        return choice(path, "explicit", model_name(task, order))
    if model in ("auto", "real"):
        cached = cached_models(task, order)
        if cached:
            return choice(cached[0][0], "cache", model_name(task, order))
        user = user_model(task, order)
        if user is not None:
            return choice(user, "user", model_name(task, order))
        if model == "real":
            raise CheckpointError(f"no real-data model of {model_name(task, order)}: build them "
                                  "with `python -m tamedpuma.models build` (or set "
                                  "method.model=auto)")
    path = shipped_path(task, order)
    if not path.is_file():
        raise CheckpointError(f"no trained model of {model_name(task, order)} (none cached, "
                              f"none in runs/puma/, none shipped): train one with `python -m "
                              f"tamedpuma.train task={task}"
                              + (" puma=position" if int(order) == 1 else "")
                              + "` and pass method.checkpoint=<out_dir>/puma.pt")
    return choice(path, "shipped", model_name(task, order))


def resolve_for_method(name: str, settings) -> ModelChoice | None:
    """The model of method ``name`` with ``settings`` (its settings dataclass; None for methods
    without a ``checkpoint`` setting)."""
    if not hasattr(settings, "checkpoint"):
        return None
    task = settings.task
    if not task:
        raise ConfigError("method.task is not set (it names the task whose model to use)")
    order = 1 if name in POSITION_METHODS else 2
    return resolve(str(task), order, settings.checkpoint, str(settings.model))
