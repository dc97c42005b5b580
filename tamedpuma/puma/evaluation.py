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

import numpy as np
import torch

from ..robot.rotations import orientation_errors_between, quat_angle
from . import dynamics, manifold
from .data import Demonstrations
from .network import PumaNet, potential
from .settings import EvalConfig
from .training import Workspace


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
    rows = []
    for i, (p_ref, q_ref) in enumerate(trimmed):
        p = pos[i, : len(p_ref)].astype(float)
        r = {"rmse": float(np.sqrt(((p - p_ref) ** 2).sum(-1).mean())),
             "dtw": dtw_per_point(p, p_ref), "frechet": frechet(p, p_ref)}
        if q_ref is not None:
            q = quat[i, : len(q_ref)].astype(float)
            cost = orientation_errors_between(q, q_ref)
            r["rmse_angle"] = float(np.sqrt((np.diag(cost) ** 2).mean()))
            r["dtw_angle"] = _dp(cost, False) / len(q_ref)
            r["frechet_angle"] = _dp(cost, True)
        rows.append(r)
    out = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
    out["dtw_max"] = float(max(r["dtw"] for r in rows))
    out["n_demos"] = len(rows)
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
    far = np.linalg.norm(pos0, axis=1) > cfg.compat_min_dist
    if quat0 is not None:
        far |= quat_angle(quat0) > cfg.compat_min_dist
    pos, quat = _t(pos0[far]), _t(quat0[far]) if quat0 is not None else None
    _, gp, gt = potential(net, pos, quat)
    with torch.inference_mode():
        vel = torch.zeros(len(pos), net.spec.tangent_dim) if net.spec.order == 2 else None
        f = net(pos, quat, vel)
    grad = torch.cat([gp, gt], dim=-1) if gt is not None else gp
    decrease = -(grad * f).sum(-1)
    return {"compatible_fraction": float((decrease > 0).float().mean()),
            "samples": int(far.sum()), "min_dist": cfg.compat_min_dist}


def validator(demos: Demonstrations, ws: Workspace, cfg: EvalConfig, starts: int = 300):
    """Validation for checkpoint selection: ``score = (converged fraction, −DTW)`` on its own
    random starts (seed ``cfg.seed + 1000``, not the evaluation's), horizon ``cfg.horizon``."""
    vcfg = EvalConfig(**{**cfg.__dict__, "random_starts": starts, "seed": cfg.seed + 1000})

    def run(net: PumaNet):
        conv = convergence(net, ws, demos.dt, vcfg)
        dtw = imitation_metrics(net, demos)["dtw"]
        frac = conv["converged_fraction"]
        return (frac, -dtw), {"converged_fraction": frac, "dtw": dtw}

    return run


def evaluate(net: PumaNet, demos: Demonstrations, ws: Workspace, cfg: EvalConfig) -> dict:
    """All three evaluations in one JSON-able dict."""
    return {"imitation": imitation_metrics(net, demos),
            "convergence": convergence(net, ws, demos.dt, cfg),
            "compatibility": compatibility(net, ws, cfg)}
