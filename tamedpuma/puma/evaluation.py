"""Evaluation of a trained primitive: imitation accuracy, convergence, ψ-compatibility.

- Imitation: roll out from each demonstration's start (at rest) for the demonstration's length and
  compare with it: RMSE (time-aligned), DTW distance per demonstration point, discrete Fréchet
  distance; positions [unit of the data, m for the robot] and orientations [rad, geodesic angle].
- Convergence: ``n`` random starts at rest in the workspace, integrated for ``horizon`` [s];
  converged when the final position error < ``pos_tol`` and the final angle < ``ang_tol``.
- Compatibility: on ``n`` random rest states at least ``min_dist`` from the goal, the fraction
  where ``−∂ψᵀ f(x, 0) > 0`` (∂ψ w.r.t. (e, δθ), f = (ë, ω̇) at ẋ = 0).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from ..robot.rotations import orientation_errors_between
from . import dynamics, manifold
from .data import Demonstrations
from .network import PumaNet, potential
from .settings import EvalConfig
from .training import Workspace, beyond_goal


def _dp(cost: np.ndarray, frechet: bool) -> float:
    """DTW (sum) or discrete Fréchet (max) over monotone couplings; anti-diagonal vectorised."""
    n, m = cost.shape
    acc = np.full((n + 1, m + 1), np.inf)
    acc[0, 0] = 0.0 if not frechet else -np.inf
    for k in range(n + m - 1):
        i = np.arange(max(0, k - m + 1), min(k, n - 1) + 1)
        j = k - i
        best = np.minimum(np.minimum(acc[i, j + 1], acc[i + 1, j]), acc[i, j])
        acc[i + 1, j + 1] = np.maximum(cost[i, j], best) if frechet else cost[i, j] + best
    return float(acc[n, m])


def dtw_per_point(a: np.ndarray, b: np.ndarray) -> float:
    """DTW distance between paths a (N, d) and b (M, d), divided by M (the reference's length)."""
    return _dp(np.linalg.norm(a[:, None] - b[None], axis=-1), False) / len(b)


def _dp_batch(costs: list[np.ndarray], frechet: bool) -> np.ndarray:
    """:func:`_dp` of every cost matrix (N_i, M_i): each by the compiled recurrence
    (:func:`_dp_cells`) where numba is installed, else all in one anti-diagonal sweep
    (:func:`_dp_sweep`); the same numbers to the bit."""
    kernel = _dp_kernel()
    if kernel is None:
        return _dp_sweep(costs, frechet)
    return np.array([kernel(np.ascontiguousarray(c, dtype=np.float64), frechet) for c in costs])


def _dp_sweep(costs: list[np.ndarray], frechet: bool) -> np.ndarray:
    """:func:`_dp` of every cost matrix (N_i, M_i) in one anti-diagonal sweep: the matrices are
    padded with infinite cost, which a coupling ending at (N_i, M_i) never reaches."""
    d = len(costs)
    n = np.array([c.shape[0] for c in costs])
    m = np.array([c.shape[1] for c in costs])
    big_n, big_m = int(n.max()), int(m.max())
    cost = np.full((d, big_n, big_m), np.inf)
    for i, c in enumerate(costs):
        cost[i, : n[i], : m[i]] = c
    acc = np.full((d, big_n + 1, big_m + 1), np.inf)
    acc[:, 0, 0] = -np.inf if frechet else 0.0
    for k in range(big_n + big_m - 1):
        i = np.arange(max(0, k - big_m + 1), min(k, big_n - 1) + 1)
        j = k - i
        best = np.minimum(np.minimum(acc[:, i, j + 1], acc[:, i + 1, j]), acc[:, i, j])
        acc[:, i + 1, j + 1] = np.maximum(cost[:, i, j], best) if frechet else cost[:, i, j] + best
    return acc[np.arange(d), n, m]


def _nan_min(a: float, b: float) -> float:
    """``np.minimum(a, b)`` of two floats: NaN if either is NaN."""
    return a if a < b or a != a else b


def _nan_max(a: float, b: float) -> float:
    """``np.maximum(a, b)`` of two floats: NaN if either is NaN."""
    return a if a > b or a != a else b


def _dp_cells(cost: np.ndarray, frechet: bool) -> float:
    """:func:`_dp` of one cost matrix (N, M) cell by cell (row by row; each cell's minimum over
    its three predecessors in :func:`_dp`'s order, then ``cost + best`` (DTW) or
    ``max(cost, best)`` (Fréchet)): the same operations on the same values, as a loop that
    numba compiles (:func:`_dp_kernel`)."""
    n, m = cost.shape
    acc = np.full((n + 1, m + 1), np.inf)
    acc[0, 0] = -np.inf if frechet else 0.0
    for i in range(n):
        for j in range(m):
            best = _nan_min(_nan_min(acc[i, j + 1], acc[i + 1, j]), acc[i, j])
            acc[i + 1, j + 1] = _nan_max(cost[i, j], best) if frechet else cost[i, j] + best
    return acc[n, m]


_DP_KERNEL: list = []


def _dp_kernel():
    """:func:`_dp_cells` compiled (once per process, from numba's on-disk cache after the first
    time; None without numba or where it fails to compile, with a warning)."""
    from tamedpuma.jit import compile_once

    return compile_once(_DP_KERNEL, _compile_dp, importlib.util.find_spec("numba") is not None,
                        "the DTW recurrence", "it runs in numpy")


def _compile_dp():
    """:func:`_dp_cells` compiled, calling compiled copies of its helpers."""
    from tamedpuma.jit import compile_kernels

    return compile_kernels(globals(), (_dp_cells,), (_nan_min, _nan_max))["_dp_cells"]


def dtw_per_point_batch(paths: list[np.ndarray], refs: list[np.ndarray]) -> np.ndarray:
    """``dtw_per_point(paths[i], refs[i])`` for every i in one sweep (:func:`_dp_batch`)."""
    costs = [np.linalg.norm(a[:, None] - b[None], axis=-1) for a, b in zip(paths, refs)]
    return _dp_batch(costs, False) / np.array([len(b) for b in refs])


def frechet(a: np.ndarray, b: np.ndarray) -> float:
    """Discrete Fréchet distance between paths a (N, d) and b (M, d)."""
    return _dp(np.linalg.norm(a[:, None] - b[None], axis=-1), True)


def _t(x):
    return None if x is None else torch.as_tensor(np.asarray(x), dtype=torch.float32)


@torch.inference_mode()
def rollout_paths(net: PumaNet, pos0, quat0, steps: int, dt: float):
    """Batched rollouts from rest: positions (B, steps+1, n), quaternions or None."""
    pos0 = _t(pos0)
    vel0 = torch.zeros(len(pos0), net.spec.tangent_dim) if net.spec.order == 2 else None
    pos, quat, _ = dynamics.stack(dynamics.rollout(net, (pos0, _t(quat0), vel0), dt, steps))
    return pos.numpy(), (quat.numpy() if quat is not None else None)


def imitation_metrics(net: PumaNet, demos: Demonstrations) -> dict:
    """Mean over demonstrations of RMSE, DTW per point and Fréchet (position and angle)."""
    trimmed = [demos.trimmed(i) for i in range(len(demos))]
    steps = max(len(p) for p, _ in trimmed) - 1
    pos0 = np.stack([p[0] for p, _ in trimmed])
    quat0 = np.stack([q[0] for _, q in trimmed]) if demos.orientation else None
    pos, quat = rollout_paths(net, pos0, quat0, steps, demos.dt)
    paths = [pos[i, : len(p_ref)].astype(float) for i, (p_ref, _) in enumerate(trimmed)]
    costs = [np.linalg.norm(p[:, None] - p_ref[None], axis=-1)
             for p, (p_ref, _) in zip(paths, trimmed)]
    lengths = np.array([len(p_ref) for p_ref, _ in trimmed])
    cols = {"rmse": [float(np.sqrt(((p - p_ref) ** 2).sum(-1).mean()))
                     for p, (p_ref, _) in zip(paths, trimmed)],
            "dtw": _dp_batch(costs, False) / lengths, "frechet": _dp_batch(costs, True)}
    if demos.orientation:
        acost = [orientation_errors_between(quat[i, : len(q_ref)].astype(float), q_ref)
                 for i, (_, q_ref) in enumerate(trimmed)]
        cols["rmse_angle"] = [float(np.sqrt((np.diag(c) ** 2).mean())) for c in acost]
        cols["dtw_angle"] = _dp_batch(acost, False) / lengths
        cols["frechet_angle"] = _dp_batch(acost, True)
    out = {k: float(np.mean(v)) for k, v in cols.items()}
    out["dtw_max"] = float(np.max(cols["dtw"]))
    out["dtw_per_demo"] = [float(v) for v in cols["dtw"]]
    out["n_demos"] = len(trimmed)
    return out




def convergence(net: PumaNet, ws: Workspace, dt: float, cfg: EvalConfig) -> dict:
    """Final distance to the goal of rollouts from ``cfg.random_starts`` random rest states."""
    rng = np.random.default_rng(cfg.seed)
    pos0, quat0 = ws.sample(rng, cfg.random_starts, net.spec.orientation)
    return convergence_from(net, pos0, quat0, dt, cfg)


@torch.inference_mode()
def convergence_from(net: PumaNet, pos0, quat0, dt: float, cfg: EvalConfig) -> dict:
    steps = int(round(cfg.horizon / dt))
    errs, angs = [], []
    for s in range(0, len(pos0), cfg.chunk):
        p = _t(pos0[s: s + cfg.chunk])
        q = _t(quat0[s: s + cfg.chunk]) if quat0 is not None else None
        v = torch.zeros(len(p), net.spec.tangent_dim) if net.spec.order == 2 else None
        p, q, _ = dynamics.final_state(net, (p, q, v), dt, steps)
        errs.append(p.norm(dim=-1).numpy())
        if q is not None:
            angs.append(manifold.quat_angle(q).numpy())
    err = np.concatenate(errs)
    ang = np.concatenate(angs) if angs else np.zeros_like(err)
    ok = (err < cfg.pos_tol) & (ang < cfg.ang_tol) & np.isfinite(err)
    return {"starts": int(len(err)), "converged_fraction": float(ok.mean()),
            "not_converged": int((~ok).sum()), "final_pos_error_max": float(np.nanmax(err)),
            "final_pos_error_mean": float(np.nanmean(err)),
            "final_angle_error_max": float(np.nanmax(ang)), "horizon_s": cfg.horizon,
            "pos_tol": cfg.pos_tol, "ang_tol": cfg.ang_tol}


def compatibility(net: PumaNet, ws: Workspace, cfg: EvalConfig) -> dict:
    """Fraction of rest states (away from the goal) where ``−∂ψᵀ f(x, 0) > 0``."""
    rng = np.random.default_rng(cfg.seed + 1)
    pos0, quat0 = ws.sample(rng, cfg.compat_samples, net.spec.orientation)
    far = beyond_goal(pos0, quat0, cfg.compat_min_dist)
    pos, quat = _t(pos0[far]), _t(quat0[far]) if quat0 is not None else None
    _, gp, gt = potential(net, pos, quat)
    with torch.inference_mode():
        vel = torch.zeros(len(pos), net.spec.tangent_dim) if net.spec.order == 2 else None
        f = net(pos, quat, vel)
    grad = torch.cat([gp, gt], dim=-1) if gt is not None else gp
    decrease = -(grad * f).sum(-1)
    return {"compatible_fraction": float((decrease > 0).float().mean()),
            "samples": int(far.sum()), "min_dist": cfg.compat_min_dist}


def imitation_dtw(net: PumaNet, demos: Demonstrations) -> float:
    """Mean position DTW per point over the demonstrations (``imitation_metrics(...)["dtw"]``,
    batched: the validation's quick check)."""
    trimmed = [demos.trimmed(i) for i in range(len(demos))]
    steps = max(len(p) for p, _ in trimmed) - 1
    pos0 = np.stack([p[0] for p, _ in trimmed])
    quat0 = np.stack([q[0] for _, q in trimmed]) if demos.orientation else None
    pos, _ = rollout_paths(net, pos0, quat0, steps, demos.dt)
    paths = [pos[i, : len(p)].astype(float) for i, (p, _) in enumerate(trimmed)]
    return float(np.mean(dtw_per_point_batch(paths, [p for p, _ in trimmed])))


def validator(demos: Demonstrations, ws: Workspace, cfg: EvalConfig, starts: int = 300,
              confirm: int = 0, horizon: float | None = None, stop_dtw: float = 0.0,
              stop_compat: float = 0.0, keep_dtw: float = 0.0, target: float = 0.0,
              patience: int = 0, min_delta: float = 0.03, plateau_stops: bool = True,
              smooth: int = 1):
    """Validation for checkpoint selection and early stopping, on its own random starts (seed
    ``cfg.seed + 1000``, not the evaluation's) and ψ samples (``cfg.seed + 1001``).

    Without a stop rule (``stop_dtw``, ``target`` and ``patience`` all 0) every validation is
    measured whole (:func:`_unruled`; horizon ``horizon`` or ``cfg.horizon``). With one, every
    validation measures the mean DTW (quick); the weights are a candidate to stop on when

    - the DTW is ≤ ``target`` or ≤ ``stop_dtw`` (good enough: ``target`` is set from the
      demonstrations' own spread), or
    - the DTW (median of the last ``smooth`` validations) has not improved on the best so far
      by a relative ``min_delta`` for ``patience`` validations and is within ``min_delta`` of it
      (``plateau_stops``; else ``info["plateau"]`` tells the caller, which anneals), or
    - it is the ``final`` validation;

    and only candidates, validations on a plateau (so that a passing one is kept while the
    learning rate decays) and any DTW ≤ ``keep_dtw`` are checked further: ψ-compatible fraction
    ≥ ``stop_compat``, ``starts`` random starts and, where all of those converge, ``confirm``
    more. ``previous``: the earlier validations' DTWs (the plateau is their function: a resumed
    run stops where an uninterrupted one does). ``info["passed"]``: every check passed (False
    where not checked: the caller decays only on a plateau that passed); ``info["stop"]``: a
    candidate passed. ``score = (passed, ψ passes, converged fraction, −DTW)`` (0: unmeasured)."""
    vcfg = replace(cfg, random_starts=starts + confirm, seed=cfg.seed + 1000,
                   horizon=float(horizon) if horizon else cfg.horizon)
    rng = np.random.default_rng(vcfg.seed)
    pos0, quat0 = ws.sample(rng, starts + confirm, demos.orientation)
    ccfg = replace(cfg, seed=cfg.seed + 1001)

    def conv(net, lo, hi):
        return convergence_from(net, pos0[lo:hi], None if quat0 is None else quat0[lo:hi],
                                demos.dt, vcfg)["converged_fraction"]

    def run(net: PumaNet, final: bool = False, previous: tuple = ()):
        if stop_dtw <= 0 and target <= 0 and patience <= 0:
            return _unruled(net, demos, conv(net, 0, starts),
                            lambda info: _psi(net, ws, ccfg, info), stop_compat)
        dtw = imitation_dtw(net, demos)
        plateau = _Plateau(patience, min_delta, smooth)
        stale = [plateau.update(d) for d in (*previous, dtw)][-1]
        good = any(0 < t and dtw <= t for t in (target, stop_dtw))
        candidate = good or final or (plateau_stops and stale
                                      and dtw <= plateau.best * (1 + min_delta))
        info = dict(dtw=dtw, stop=False, passed=False, stale=plateau.stale, plateau=stale)
        if not (candidate or stale) and not (keep_dtw > 0 and dtw <= keep_dtw):
            return (False, False, 0.0, -dtw), info
        psi_ok = stop_compat <= 0 or _psi(net, ws, ccfg, info) >= stop_compat
        frac = info["converged_fraction"] = conv(net, 0, starts)
        if frac == 1.0 and confirm > 0 and psi_ok:
            info["confirmed_fraction"] = conv(net, starts, starts + confirm)
            frac = (starts + confirm * info["confirmed_fraction"]) / (starts + confirm)
        passed = info["passed"] = psi_ok and frac == 1.0
        info["stop"] = candidate and passed
        return (passed, psi_ok, frac, -dtw), info

    return run


def _unruled(net: PumaNet, demos: Demonstrations, frac: float, psi, stop_compat: float):
    """A validation without a stop rule, converged fraction ``frac`` of its starts: ``(score,
    info)`` with ``score = (frac, −DTW)``, or with ``stop_compat`` > 0 ranking ψ (``psi(info)``,
    the ψ-compatible fraction) as the stop rule's score does: ``(ψ passes and all converge,
    ψ passes, frac, −DTW)``."""
    dtw = imitation_metrics(net, demos)["dtw"]
    info = {"converged_fraction": frac, "dtw": dtw}
    if stop_compat <= 0:
        return (frac, -dtw), info
    psi_ok = psi(info) >= stop_compat
    return (psi_ok and frac == 1.0, psi_ok, frac, -dtw), info


def _psi(net: PumaNet, ws: Workspace, cfg: EvalConfig, info: dict) -> float:
    """The ψ-compatible fraction (also stored in ``info``)."""
    info["compatible_fraction"] = compatibility(net, ws, cfg)["compatible_fraction"]
    return info["compatible_fraction"]


@dataclass
class _Plateau:
    """Validations since the mean DTW last improved on its best by a relative ``min_delta``.

    With ``smooth`` > 1 the count must also hold for the median of the last ``smooth``
    validations: one noisy dip sets a best that later validations cannot beat (the raw count
    grows) but moves the median little, and a noisy rise counts against the raw best only; a
    plateau is where both stopped improving (``stale`` is the smaller count)."""

    patience: int
    min_delta: float
    smooth: int = 1
    best: float = float("inf")
    stale: int = 0
    stale_raw: int = 0
    best_level: float = float("inf")
    stale_level: int = 0
    recent: list = field(default_factory=list)

    def update(self, dtw: float) -> bool:
        """Record one validation's DTW; True once ``patience`` (> 0) passed without improving."""
        self.recent = [*self.recent, dtw][-max(1, self.smooth):]
        level = float(np.median(self.recent))
        raw = 0 if dtw < self.best * (1.0 - self.min_delta) else self.stale_raw + 1
        smooth = 0 if level < self.best_level * (1.0 - self.min_delta) else self.stale_level + 1
        self.stale_raw, self.stale_level = raw, smooth
        self.best, self.best_level = min(self.best, dtw), min(self.best_level, level)
        self.stale = min(raw, smooth)
        return self.patience > 0 and self.stale >= self.patience


def evaluate(net: PumaNet, demos: Demonstrations, ws: Workspace, cfg: EvalConfig) -> dict:
    """All three evaluations in one JSON-able dict."""
    return {"imitation": imitation_metrics(net, demos),
            "convergence": convergence(net, ws, demos.dt, cfg),
            "compatibility": compatibility(net, ws, cfg)}
