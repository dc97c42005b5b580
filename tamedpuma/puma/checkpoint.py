"""Checkpoints: everything inference needs, saved with ``torch.save`` and loaded strictly.

Contents (format ``tamedpuma.puma``, version ``FORMAT_VERSION``): the state spec, network sizes,
weights (including the normalisation buffers), the normalisation constants in readable form, the
model step Δt [s], the goal convention and the task's nominal goal, the data unit, the workspace,
the resolved training config, the sha256 of the training data and its source, and the evaluation
report. Loading uses ``torch.load(weights_only=True)`` (no code execution) and rejects, with a
one-line :class:`CheckpointError`, a missing file, a corrupt file, another format or version, a
missing key, a missing/unexpected parameter or a parameter of the wrong shape.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path

import torch

from ..errors import CheckpointError
from .network import NetConfig, PumaNet, StateSpec
from .training import Workspace

FORMAT = "tamedpuma.puma"
FORMAT_VERSION = 1
REQUIRED_KEYS = ("format", "format_version", "spec", "network", "state_dict", "normalisation",
                 "dt", "goal_convention", "goal", "unit", "workspace", "config", "data_hash",
                 "data_source", "report")


@dataclass(frozen=True)
class Meta:
    """Everything but the weights: Δt [s], conventions, provenance."""

    dt: float
    goal_convention: str
    goal: dict
    unit: str
    workspace: Workspace
    config: dict
    data_hash: str
    data_source: str
    report: dict


def _plain(obj):
    """JSON-like Python values only (numpy scalars/arrays → float/list), for weights_only loads."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if obj is None or isinstance(obj, str):
        return str(obj) if obj is not None else None
    for kind in (bool, int, float):  # also numpy scalars (np.float64 subclasses float)
        if isinstance(obj, kind):
            return kind(obj)
    if hasattr(obj, "tolist"):
        return obj.tolist()
    return str(obj)


def save(path: str | Path, net: PumaNet, meta: Meta) -> Path:
    """Write a checkpoint (parent folders are created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ws = meta.workspace
    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "spec": dataclasses.asdict(net.spec),
        "network": dataclasses.asdict(net.cfg),
        "state_dict": {k: v.detach().clone() for k, v in net.state_dict().items()},
        "normalisation": {k: getattr(net, k).tolist() for k in ("pos_scale", "vel_scale",
                                                                 "out_scale")},
        "dt": float(meta.dt),
        "goal_convention": meta.goal_convention,
        "goal": _plain(meta.goal),
        "unit": meta.unit,
        "workspace": _plain({"low": ws.low, "high": ws.high, "max_angle": float(ws.max_angle)}),
        "config": _plain(meta.config),
        "data_hash": meta.data_hash,
        "data_source": meta.data_source,
        "report": _plain(meta.report),
    }
    return save_atomic(payload, path)


def save_atomic(obj, path: str | Path) -> Path:
    """``torch.save(obj)`` to ``path`` through a temporary file and a rename: ``path`` is the
    old file or the whole new one; a full disk leaves no ``.tmp`` behind and raises a one-line
    :class:`~tamedpuma.errors.DiskFullError` naming the bytes needed."""
    import io

    from ..paths import write_atomic

    buffer = io.BytesIO()
    torch.save(obj, buffer)
    return write_atomic(path, buffer.getvalue())


def _fail(path, msg) -> CheckpointError:
    return CheckpointError(f"checkpoint {path}: {msg}")


_ZIP_MAGIC = b"PK\x03\x04"  # torch.save's archive format
_PICKLE_MAGIC = b"\x80"      # torch.save's legacy format (a pickle, protocol >= 2)


#: modules whose globals a checkpoint's pickle may name (tensors, their storages, plain
#: containers): anything else would be imported and called by a plain unpickler
_SAFE_MODULES = ("torch", "collections", "_codecs", "numpy")


def _pickle_bytes(path: Path) -> bytes:
    """The pickle of a checkpoint: the file itself, or the ``data.pkl`` of a torch archive."""
    import zipfile

    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as zf:
            name = next((n for n in zf.namelist() if n.endswith("data.pkl")), None)
            return zf.read(name) if name else b""
    return path.read_bytes()


def code_globals(path: Path) -> list[str]:
    """The globals (``module.name``) outside :data:`_SAFE_MODULES` that unpickling ``path``
    would import and may call (``posix.system``...), read from its opcodes without running
    them; empty for a clean or unreadable pickle."""
    import pickletools

    found, strings = [], []
    try:
        for op, arg, _ in pickletools.genops(_pickle_bytes(path)):
            if isinstance(arg, str):
                strings.append(arg)
            if op.name in ("GLOBAL", "INST"):
                found.append(str(arg).replace(" ", "."))
            elif op.name == "STACK_GLOBAL" and len(strings) >= 2:
                found.append(f"{strings[-2]}.{strings[-1]}")
    except Exception:  # noqa: BLE001 - a truncated pickle: what was read so far counts
        pass
    return [g for g in found if g.split(".", 1)[0] not in _SAFE_MODULES]


def _read_problem(path: Path, exc: BaseException) -> str:
    """What is wrong with a file ``torch.load`` could not read, in a few words."""
    text = " ".join(str(exc).split())
    with open(path, "rb") as fh:
        head = fh.read(4)
    unsafe = code_globals(path)
    if unsafe:
        return f"refused: loading it would run code (it names {', '.join(unsafe[:3])})"
    if not (head == _ZIP_MAGIC or head.startswith(_PICKLE_MAGIC)):
        return f"not a PyTorch checkpoint (unrecognised content, first bytes {head.hex()})"
    unsafe = [ln.strip() for ln in str(exc).splitlines()
              if "unsupported global" in ln.lower()]  # torch's wording differs by version
    if unsafe:
        found = unsafe[0]
        return f"refused: loading it would run code ({_clip(found, 120)})"
    kind = "archive" if head == _ZIP_MAGIC else "file"
    return f"truncated or corrupt PyTorch {kind} ({_clip(text, 120) or type(exc).__name__})"


def _clip(text: str, n: int) -> str:
    """``text`` cut at a word boundary to at most ``n`` characters (with "..." if cut)."""
    if len(text) <= n:
        return text
    return text[:n].rsplit(" ", 1)[0] + " ..."


def _read(path: Path) -> dict:
    """The checkpoint's payload (``torch.load`` with ``weights_only=True``); every way the file
    can be unreadable is a one-line :class:`CheckpointError` naming the file."""
    if path.is_dir():
        raise _fail(path, "is a folder, not a checkpoint file (the file is its puma.pt)")
    if not path.is_file():
        raise _fail(path, "file not found")
    if path.stat().st_size == 0:
        raise _fail(path, "empty file (0 bytes)")
    try:
        with warnings.catch_warnings():  # e.g. "Detected pickle protocol 5": the error says
            warnings.simplefilter("ignore", UserWarning)
            ck = torch.load(path, map_location="cpu", weights_only=True)
    except PermissionError as exc:
        raise _fail(path, f"cannot be read ({exc.strerror or exc})") from None
    except Exception as exc:  # noqa: BLE001 - corrupt, truncated or not a torch file
        raise _fail(path, _read_problem(path, exc)) from None
    if not isinstance(ck, dict) or ck.get("format") != FORMAT:
        fmt = ck.get("format") if isinstance(ck, dict) else type(ck).__name__
        raise _fail(path, f"not a PUMA checkpoint (format {fmt!r})")
    if ck.get("format_version") != FORMAT_VERSION:
        raise _fail(path, f"format version {ck.get('format_version')!r} is not supported "
                          f"(expected {FORMAT_VERSION}); retrain or convert it")
    missing = [k for k in REQUIRED_KEYS if k not in ck]
    if missing:
        raise _fail(path, f"missing key(s) {', '.join(missing)}")
    return ck


def load(path: str | Path) -> tuple[PumaNet, Meta]:
    """Load strictly; the network is returned in eval mode with its goal output cached."""
    path = Path(path)
    ck = _read(path)
    try:
        spec = StateSpec(**ck["spec"])
        cfg = NetConfig(**ck["network"])
        ws = ck["workspace"]
        workspace = Workspace(tuple(ws["low"]), tuple(ws["high"]), float(ws["max_angle"]))
        norm = ck["normalisation"]
        net = PumaNet(spec, cfg, norm["pos_scale"], norm["vel_scale"], norm["out_scale"])
        meta = Meta(float(ck["dt"]), str(ck["goal_convention"]), ck["goal"], str(ck["unit"]),
                    workspace, ck["config"], str(ck["data_hash"]), str(ck["data_source"]),
                    ck["report"])
    except Exception as exc:  # noqa: BLE001 - any malformed header value
        raise _fail(path, f"invalid header ({type(exc).__name__}: "
                          f"{' '.join(str(exc).split())[:120]})") from None
    sd = ck["state_dict"]
    want = net.state_dict()
    if not isinstance(sd, dict):
        raise _fail(path, "state_dict is not a dict")
    lost = sorted(set(want) - set(sd))
    extra = sorted(set(sd) - set(want))
    if lost:
        raise _fail(path, f"missing parameter(s) {', '.join(lost[:5])}")
    if extra:
        raise _fail(path, f"unexpected parameter(s) {', '.join(extra[:5])}")
    for k, v in want.items():
        if not isinstance(sd[k], torch.Tensor) or tuple(sd[k].shape) != tuple(v.shape):
            got = tuple(sd[k].shape) if isinstance(sd[k], torch.Tensor) else type(sd[k]).__name__
            raise _fail(path, f"parameter {k} has shape {got}, expected {tuple(v.shape)}")
        if not torch.all(torch.isfinite(sd[k])):
            raise _fail(path, f"parameter {k} is not finite")
    net.load_state_dict(sd, strict=True)
    net.eval()
    net.cache_goal()
    return net, meta
