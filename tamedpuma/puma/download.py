"""The authors' KUKA demonstrations: where they are on this machine, fetching them, checking them.

They are published in the authors' public repository ``tud-amr/pumafabrics`` (no licence, so they
are never copied into this repository or its package). This module pins the commit and every
file's sha256 (``demos_sha256.txt``, the same list as ``../shared/data/pumafabrics-demos/
SHA256SUMS``), downloads the files from ``<base URL>/<folder>/ee_state_<i>.pk`` (default base:
raw.githubusercontent.com at the pinned commit; ``--base-url`` or ``$TAMEDPUMA_DEMOS_URL`` to use a
mirror) into the user cache, and checks each file's sha256 before anything reads it.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import urllib.error
import urllib.request
from pathlib import Path

from .. import paths
from ..errors import DataError
from . import store

COMMIT = "c0b4392a94b204cdd648c11e432eb55cea9099ca"
REPO_PATH = "pumafabrics/puma_extension/datasets/kuka"
DEFAULT_BASE_URL = f"https://raw.githubusercontent.com/tud-amr/pumafabrics/{COMMIT}/{REPO_PATH}"
SUMS_FILE = Path(__file__).resolve().parent / "demos_sha256.txt"
#: the demonstration folder each task trains on (README, "Reproduce the paper's Table 1")
TASK_FOLDERS = {"tomato": "pick_tomato_31may", "pouring": "pouring_v2"}
DEFAULT_FOLDERS = tuple(TASK_FOLDERS.values())


def pinned_sums() -> dict[str, str]:
    """``{"<folder>/ee_state_<i>.pk": sha256}`` of every published file at the pinned commit."""
    sums = {}
    for line in SUMS_FILE.read_text().splitlines():
        if line.strip():
            digest, name = line.split(maxsplit=1)
            sums[name.strip().lstrip("*")] = digest
    return sums


def default_dest() -> Path:
    """Where ``download`` puts the files: ``<cache>/demos/pumafabrics-<commit>``."""
    return store.cache_root() / "demos" / f"pumafabrics-{COMMIT[:12]}"


def candidate_roots() -> list[Path]:
    """Folders searched for the demonstrations, in order: ``$TAMEDPUMA_DEMOS``, ``../shared/
    data/pumafabrics-demos`` beside the repository and beside the working directory, and the
    download folder."""
    roots = []
    if os.environ.get("TAMEDPUMA_DEMOS"):
        roots.append(Path(os.environ["TAMEDPUMA_DEMOS"]).expanduser())
    rel = Path("..") / "shared" / "data" / "pumafabrics-demos"
    roots += [(paths.CHECKOUT_ROOT / rel).resolve(), (Path.cwd() / rel).resolve(), default_dest()]
    return roots


def file_sha256(path: Path) -> str:
    return store.file_sha256(path)


def verify_folder(root: Path, folder: str) -> list[Path]:
    """The pinned files of ``root/folder``, each checked against its sha256; DataError if one is
    missing or differs (the data is then not used)."""
    names = sorted((n for n in pinned_sums() if n.startswith(folder + "/")),
                   key=lambda n: int(n.rsplit("_", 1)[1].split(".")[0]))
    if not names:
        raise DataError(f"unknown demonstration folder {folder!r}")
    sums = pinned_sums()
    files = []
    for name in names:
        path = root / name
        if not path.is_file():
            raise DataError(f"missing {path}: run `python -m tamedpuma.models download`")
        if file_sha256(path) != sums[name]:
            raise DataError(f"{path} differs from the authors' file at commit {COMMIT[:12]} "
                            "(sha256 mismatch): not used")
        files.append(path)
    return files


def find_root(folders=DEFAULT_FOLDERS) -> Path | None:
    """The first candidate root holding every file of ``folders`` (presence only; callers verify
    with :func:`verify_folder` before use)."""
    names = [n for n in pinned_sums() if n.split("/")[0] in folders]
    for root in candidate_roots():
        if all((root / n).is_file() for n in names):
            return root
    return None


def download(dest: Path | None = None, base_url: str | None = None,
             folders=DEFAULT_FOLDERS, log=print, timeout: float = 60.0) -> Path:
    """Fetch every pinned file of ``folders`` into ``dest`` (files already there with the right
    sha256 are kept), checking each sha256 before it is moved into place. Returns ``dest``."""
    dest = Path(dest) if dest else default_dest()
    base = (base_url or os.environ.get("TAMEDPUMA_DEMOS_URL") or DEFAULT_BASE_URL).rstrip("/")
    sums = pinned_sums()
    unknown = sorted(set(folders) - {n.split("/")[0] for n in sums})
    if unknown:
        raise DataError(f"unknown demonstration folder(s) {unknown}; known: "
                        f"{sorted({n.split('/')[0] for n in sums})}")
    names = [n for n in sums if n.split("/")[0] in folders]
    fetched = kept = 0
    for name in names:
        target = dest / name
        if target.is_file() and file_sha256(target) == sums[name]:
            kept += 1
            continue
        url = f"{base}/{name}"
        target.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=target.parent, delete=False) as tmp:
            try:
                with urllib.request.urlopen(url, timeout=timeout) as resp:
                    shutil.copyfileobj(resp, tmp)
            except (urllib.error.URLError, OSError) as exc:
                Path(tmp.name).unlink(missing_ok=True)
                why = getattr(exc, "reason", None) or exc
                raise DataError(f"cannot download {url}: {why}") from None
        digest = hashlib.sha256(Path(tmp.name).read_bytes()).hexdigest()
        if digest != sums[name]:
            Path(tmp.name).unlink(missing_ok=True)
            raise DataError(f"{url}: sha256 {digest[:12]}... differs from the pinned "
                            f"{sums[name][:12]}...: not used")
        os.replace(tmp.name, target)
        fetched += 1
    log(f"demonstrations in {dest}: {fetched} downloaded, {kept} already there, all {len(names)} "
        f"checked against the sha256 pinned at {COMMIT[:12]}")
    return dest
