"""Demonstrations in the formats users have, each checked before training.

``load_any(path)`` reads, by what ``path`` is:

- a folder of the authors' ``ee_state_*.pk`` (``x_pos`` (N,3) [m], ``x_rot`` (N,3,3), ``delta_t``
  (N,) [s]; :func:`tamedpuma.puma.data.load_pickle_demos`);
- CSV files, one demonstration per file, a header row and the columns
  ``t, x, y, z, qx, qy, qz, qw`` (time [s], position [m], unit quaternion (x, y, z, w)); the four
  quaternion columns may be left out (position-only demonstrations);
- NPZ files, one demonstration per file, arrays ``t`` (N,) [s], ``position`` (N,3) [m] and
  optionally ``quaternion`` (N,4) (x, y, z, w);
- MCAP logs of recorded runs (``episode.mcap``; teach from a log): the end-effector path
  ``/ee_pose`` as read by :func:`tamedpuma.runlog.read_mcap` (``log.ee``: t, x, y, z, qx..qw).

A folder may hold one kind of file (``*.pk``, ``*.csv``, ``*.npz`` or ``*.mcap``, searched one
level down for MCAP run folders). Every demonstration is checked by :func:`check_demo`; bad data
raises :class:`~tamedpuma.errors.DataError` with a one-line message naming the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataError
from .data import RawDemo, _natural_key, load_pickle_demos

MIN_SAMPLES = 10
QUAT_NORM_TOL = 1e-3     # | ||q|| - 1 | allowed in a file's quaternions
MAX_POSITION_M = 5.0     # an arm's end effector stays within this of its base [m]
MAX_PERIOD_S = 1.0       # a sample period above this is not a recorded motion [s]
UNIT_RATIO = 20.0        # demonstrations whose sizes differ by more than this: mixed units
CSV_COLUMNS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")


def check_demo(t: np.ndarray, pos: np.ndarray, quat: np.ndarray | None, where: str) -> RawDemo:
    """Validate one timestamped pose sequence and return it as a :class:`RawDemo`.

    t: (N,) [s], strictly increasing; pos: (N, 3) [m]; quat: (N, 4) (x, y, z, w) of unit norm
    (within ``QUAT_NORM_TOL``) or None. Refuses too few samples, NaN/inf, non-monotonic time,
    unnormalised quaternions and data in the wrong unit (positions beyond ``MAX_POSITION_M``:
    millimetres; periods beyond ``MAX_PERIOD_S``: milliseconds).
    """
    t, pos = np.asarray(t, float).ravel(), np.asarray(pos, float)
    if pos.ndim != 2 or pos.shape[1] != 3 or len(t) != len(pos):
        raise DataError(f"{where}: positions must be (N, 3) with one time per row, got "
                        f"{pos.shape} and {t.shape[0]} times")
    n = len(t)
    if n < MIN_SAMPLES:
        raise DataError(f"{where}: too short, {n} samples (need at least {MIN_SAMPLES})")
    arrays = {"t": t, "position": pos} | ({} if quat is None else {"quaternion": quat})
    for name, arr in arrays.items():
        bad = ~np.isfinite(np.asarray(arr, float))
        if bad.any():
            row = int(np.flatnonzero(bad.reshape(n, -1).any(axis=1))[0])
            raise DataError(f"{where}: NaN or infinite {name} at sample {row}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0])
        raise DataError(f"{where}: time is not increasing at sample {k + 1} "
                        f"(t = {t[k]:.6g} then {t[k + 1]:.6g} s)")
    if np.median(dt) > MAX_PERIOD_S:
        raise DataError(f"{where}: median sample period {np.median(dt):.4g} s: time looks like "
                        "milliseconds, give seconds")
    reach = float(np.abs(pos).max())
    if reach > MAX_POSITION_M:
        raise DataError(f"{where}: positions reach {reach:.4g} from the base: looks like "
                        f"millimetres, give metres (limit {MAX_POSITION_M} m)")
    if quat is not None:
        quat = np.asarray(quat, float)
        if quat.shape != (n, 4):
            raise DataError(f"{where}: quaternions must be (N, 4) (x, y, z, w), got {quat.shape}")
        err = np.abs(np.linalg.norm(quat, axis=1) - 1.0)
        if err.max() > QUAT_NORM_TOL:
            k = int(np.argmax(err))
            raise DataError(f"{where}: quaternion at sample {k} is not unit length "
                            f"(norm {np.linalg.norm(quat[k]):.6g}, tolerance {QUAT_NORM_TOL})")
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return RawDemo(pos, quat, np.concatenate(([0.0], dt)), where)


def check_units_agree(raws: list[RawDemo]) -> None:
    """Refuse a set whose demonstrations differ in size by more than ``UNIT_RATIO`` (one in mm,
    another in m): size = the largest extent of each demonstration's positions."""
    if len(raws) < 2:
        return
    sizes = np.array([np.ptp(r.pos, axis=0).max() for r in raws])
    sizes = np.maximum(sizes, 1e-9)
    big, small = int(np.argmax(sizes)), int(np.argmin(sizes))
    if sizes[big] / sizes[small] > UNIT_RATIO:
        raise DataError(f"mixed units: {raws[big].source} spans {sizes[big]:.4g} but "
                        f"{raws[small].source} only {sizes[small]:.4g} "
                        f"(ratio {sizes[big] / sizes[small]:.0f} > {UNIT_RATIO:g})")


def load_csv(path: Path) -> RawDemo:
    """One demonstration from a CSV file with a header row (see the module docstring)."""
    try:
        with open(path, encoding="utf-8") as fh:
            header = [h.strip().lower() for h in fh.readline().strip().split(",")]
        rows = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float, ndmin=2)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DataError(f"{path}: cannot read CSV: {exc}") from None
    missing = [c for c in CSV_COLUMNS[:4] if c not in header]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(missing)}; the header must be "
                        f"{','.join(CSV_COLUMNS)} (quaternion columns optional)")
    if rows.size == 0:
        rows = np.zeros((0, len(header)))
    if rows.shape[1] != len(header):
        raise DataError(f"{path}: {rows.shape[1]} values per row but {len(header)} columns")
    col = {name: rows[:, i] for i, name in enumerate(header)}
    has_q = [c in col for c in CSV_COLUMNS[4:]]
    if any(has_q) and not all(has_q):
        raise DataError(f"{path}: give all of qx, qy, qz, qw or none")
    quat = np.stack([col[c] for c in CSV_COLUMNS[4:]], axis=1) if all(has_q) else None
    pos = np.stack([col[c] for c in ("x", "y", "z")], axis=1)
    return check_demo(col["t"], pos, quat, str(path))


def load_npz(path: Path) -> RawDemo:
    """One demonstration from an NPZ file: ``t``, ``position`` and optionally ``quaternion``."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in z.files}
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read NPZ: {exc}") from None
    for key in ("t", "position"):
        if key not in arrays:
            raise DataError(f"{path}: missing array '{key}' (needs t, position[, quaternion])")
    try:
        t = arrays["t"].astype(float)
        pos = arrays["position"].astype(float)
        quat = arrays["quaternion"].astype(float) if "quaternion" in arrays else None
    except (TypeError, ValueError):
        raise DataError(f"{path}: arrays must be numeric") from None
    return check_demo(t, pos, quat, str(path))


def load_mcap(path: Path) -> RawDemo:
    """The end-effector path of one recorded run (``/ee_pose`` of an ``episode.mcap``)."""
    from tamedpuma.runlog import read_mcap

    try:
        log = read_mcap(path)
    except Exception as exc:  # a damaged or foreign file
        raise DataError(f"{path}: cannot read MCAP: {' '.join(str(exc).split())}") from None
    ee = log.ee
    if ee is None or len(ee) == 0:
        raise DataError(f"{path}: the log has no end-effector poses (/ee_pose)")
    quat = ee[["qx", "qy", "qz", "qw"]].to_numpy(float)
    return check_demo(ee["t"].to_numpy(float), ee[["x", "y", "z"]].to_numpy(float), quat,
                      str(path))


_LOADERS = {".csv": load_csv, ".npz": load_npz, ".mcap": load_mcap}


def _files(folder: Path) -> tuple[str, list[Path]]:
    found = {}
    for ext in (".pk", ".csv", ".npz", ".mcap"):
        files = sorted(folder.glob(f"*{ext}"), key=_natural_key)
        if ext == ".mcap" and not files:  # a folder of run folders
            files = sorted(folder.glob(f"*/*{ext}"), key=lambda p: _natural_key(p.parent))
        if files:
            found[ext] = files
    if not found:
        raise DataError(f"no demonstrations in {folder} (ee_state_*.pk, *.csv, *.npz or "
                        "*.mcap)")
    if len(found) > 1:
        raise DataError(f"{folder} mixes demonstration formats ({', '.join(sorted(found))}); "
                        "keep one kind per folder")
    ((ext, files),) = found.items()
    return ext, files


def load_any(path: str | Path) -> list[RawDemo]:
    """Demonstrations from a folder or a single file (see the module docstring), checked."""
    path = Path(path)
    if path.is_file():
        loader = _LOADERS.get(path.suffix.lower())
        if loader is None:
            raise DataError(f"{path}: unknown demonstration format (use .csv, .npz, .mcap or a "
                            "folder of ee_state_*.pk)")
        raws = [loader(path)]
    elif path.is_dir():
        ext, files = _files(path)
        if ext == ".pk":
            raws = load_pickle_demos(path)
        else:
            raws = [_LOADERS[ext](f) for f in files]
    else:
        raise DataError(f"demonstration folder not found: {path}")
    if len({r.quat is None for r in raws}) > 1:
        raise DataError(f"{path}: some demonstrations have orientations and some do not")
    check_units_agree(raws)
    return raws
