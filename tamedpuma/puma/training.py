"""Training a PUMA primitive: batched demonstration windows + random workspace rollouts, Adam.

One iteration: ``B_il`` windows of W+1 demonstration samples (uniform over all samples, padded at
rest on the goal after each demonstration's end) and ``B_s`` random start states in the workspace
(positions uniform in the box, orientations within ``max_angle`` of the goal, velocities zero for
half of them and uniform within ± half the data's maximum speed for the rest); loss in ``losses``.
Cosine learning-rate decay, gradient clipping. Seeded (torch and numpy).

Persistent stability rollouts (``persist``): each iteration continues most stability rollouts from
where the previous iteration left them, so they cover long horizons (seconds) at the cost of a few
steps; slow unstable modes and spurious equilibria that a 10-step rollout never reveals get
penalised. Optional validation-based selection (``select_every``): the stability of the learned
field fluctuates during training, so the weights with the best validation score (fraction of
validation starts converged, then imitation DTW) are kept.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import ConfigError
from . import dynamics, losses, manifold
from .data import Demonstrations
from .network import NetConfig, PumaNet, StateSpec


@dataclass(frozen=True)
class Workspace:
    """Box of goal-relative positions ``[low, high]`` [unit] and orientations within max_angle."""

    low: tuple[float, ...]
    high: tuple[float, ...]
    max_angle: float = 0.0  # [rad]

    def __post_init__(self):
        lo, hi = np.asarray(self.low, float), np.asarray(self.high, float)
        if lo.shape != hi.shape or lo.ndim != 1 or np.any(hi <= lo):
            raise ConfigError(f"workspace needs low < high of equal length, got {self.low}, "
                              f"{self.high}")
        if not 0.0 <= self.max_angle <= np.pi:
            raise ConfigError(f"workspace max_angle must be in [0, π] rad, got {self.max_angle}")

    @staticmethod
    def around(demos: Demonstrations, margin: float = 0.1) -> Workspace:
        """The demonstrations' bounding box enlarged by ``margin`` of its size on each side."""
        allp = np.concatenate(demos.pos)
        lo, hi = allp.min(0), allp.max(0)
        pad = margin * (hi - lo).max()
        return Workspace(tuple(lo - pad), tuple(hi + pad), 0.0)

    def padded(self, fraction: float) -> Workspace:
        """The box enlarged by ``fraction`` of its size on each side (same max_angle)."""
        lo, hi = np.asarray(self.low), np.asarray(self.high)
        pad = fraction * (hi - lo)
        return Workspace(tuple(lo - pad), tuple(hi + pad), self.max_angle)

    def sample(self, rng: np.random.Generator, n: int, orientation: bool):
        """n positions (n, dim) and, with orientation, quaternions (n, 4)."""
        pos = rng.uniform(self.low, self.high, size=(n, len(self.low)))
        quat = manifold.np_random_rotations(rng, n, self.max_angle) if orientation else None
        return pos, quat


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (see ``conf/puma/default.yaml`` for meanings and units)."""

    iterations: int = 3000
    lr: float = 2e-3
    batch_windows: int = 48
    window: int = 25
    stability_batch: int = 64
    stability_horizon: int = 10
    stability_weight: float = 1.0
    margin: float = 1e-6
    decay_rate: float = 0.0
    near_goal_fraction: float = 0.0
    persist: float = 0.95
    select_every: int = 0
    select_from: float = 0.5
    squared_hinge: bool = False
    compat_weight: float = 0.1
    compat_eps: float = 0.01
    path_weight: float = 0.0
    sample_pad: float = 0.0
    boundary_weight: float = 0.0
    vel_weight: float = 0.1
    grad_clip: float = 1.0
    threads: int = 1
    log_every: int = 25


@dataclass
class TrainResult:
    net: PumaNet
    seconds: float
    history: list[dict] = field(default_factory=list)
    selection: list[dict] = field(default_factory=list)  # validation scores, chosen one marked


def scales(demos: Demonstrations, ws: Workspace, order: int):
    """Normalisation: position scale (max |e| of data and workspace), velocity and output scales.

    Per component group (position, orientation): the maximum absolute value over the data, so the
    decoder's output is ``s_a ⊙ φ`` with s_a = max |acceleration| (or |velocity| in first order).
    """
    n = demos.n_pos
    allp = np.concatenate(demos.pos)
    box = np.maximum(np.abs(ws.low), np.abs(ws.high))
    pos_scale = np.maximum(np.maximum(np.abs(allp).max(0), box), 1e-6)
    vel = np.concatenate(demos.vel)
    acc = np.concatenate([np.diff(v, axis=0, append=v[-1:]) / demos.dt for v in demos.vel])

    def group_max(x):
        out = np.empty(x.shape[1])
        out[:n] = max(np.abs(x[:, :n]).max(), 1e-6)
        out[n:] = max(np.abs(x[:, n:]).max(), 1e-6) if x.shape[1] > n else 0
        return out

    vel_scale = group_max(vel)
    out_scale = group_max(acc) if order == 2 else vel_scale
    return pos_scale, vel_scale, out_scale


def _padded(demos: Demonstrations, window: int, orientation: bool):
    """Tensors (D, L_max + W, ·) padded at rest on the goal, and the lengths L_i."""
    lengths = np.array([len(p) for p in demos.pos])
    total = lengths.max() + window
    d, n = len(demos), demos.n_pos
    pos = np.zeros((d, total, n))
    vel = np.zeros((d, total, demos.vel[0].shape[1] if orientation else n))
    quat = np.zeros((d, total, 4))
    quat[..., 3] = 1.0
    for i in range(d):
        L = lengths[i]
        pos[i, :L] = demos.pos[i]
        vel[i, :L] = demos.vel[i][:, : vel.shape[2]]
        if orientation:
            quat[i, :L] = demos.quat[i]
    f = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    return f(pos), (f(quat) if orientation else None), f(vel), lengths


def _random_starts(rng, ws: Workspace, spec: StateSpec, cfg: TrainConfig, vel_scale):
    """Stability starts: samples of ``ws`` (the workspace, padded by ``sample_pad`` in ``train``);
    velocities zero for half, else within ±½ max speed.

    A fraction ``near_goal_fraction`` is shrunk towards the goal by a log-uniform factor in
    [1e-3, 1] (positions, rotation angles and velocities), so the goal's neighbourhood is trained.
    """
    b = cfg.stability_batch
    pos, quat = ws.sample(rng, b, spec.orientation)
    vel = None
    if spec.order == 2:
        vel = rng.uniform(-0.5, 0.5, (b, len(vel_scale))) * vel_scale
        vel *= rng.random((b, 1)) < 0.5
    if cfg.near_goal_fraction > 0:
        shrink = np.where(rng.random((b, 1)) < cfg.near_goal_fraction,
                          10.0 ** rng.uniform(-3, 0, (b, 1)), 1.0)
        pos = pos * shrink
        if quat is not None:
            quat = manifold.np_quat_exp(manifold.np_quat_log(quat) * shrink)
        if vel is not None:
            vel = vel * shrink
    f = lambda a: None if a is None else torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    return f(pos), f(quat), f(vel)


def _keep(rng, chain, persist: float, low, high) -> torch.Tensor:
    """Which persistent rollouts continue: a fraction ``persist`` of those still finite and
    within the workspace box enlarged by its own size on each side; the others restart."""
    pos = chain[0]
    span = high - low
    inside = torch.all((pos > low - span) & (pos < high + span), dim=-1, keepdim=True)
    finite = torch.all(torch.isfinite(pos), dim=-1, keepdim=True)
    lucky = torch.as_tensor(rng.random((len(pos), 1)) < persist)
    return inside & finite & lucky


def build_net(demos: Demonstrations, ws: Workspace, spec: StateSpec, net_cfg: NetConfig) -> PumaNet:
    pos_scale, vel_scale, out_scale = scales(demos, ws, spec.order)
    if not spec.orientation:
        vel_scale, out_scale = vel_scale[: spec.n_pos], out_scale[: spec.n_pos]
    return PumaNet(spec, net_cfg, pos_scale, vel_scale, out_scale)


def train(demos: Demonstrations, ws: Workspace, spec: StateSpec, net_cfg: NetConfig,
          cfg: TrainConfig, seed: int = 0, progress: bool = True,
          validator: Callable[[PumaNet], tuple[tuple, dict]] | None = None) -> TrainResult:
    """Train a primitive on ``demos``; returns the network (eval mode) and the loss history.

    With ``validator`` and ``cfg.select_every`` > 0, the weights are validated every
    ``select_every`` iterations from ``select_from`` of the run on (and at the end); the weights
    with the best score (a tuple, larger is better) are returned. The validator must use its own
    random starts, not the evaluation's.
    """
    if spec.orientation and not demos.orientation:
        raise ConfigError("orientation requested but the demonstrations have none")
    if spec.n_pos != demos.n_pos or spec.n_pos != len(ws.low):
        raise ConfigError(f"dimension mismatch: spec {spec.n_pos}, data {demos.n_pos}, "
                          f"workspace {len(ws.low)}")
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    torch.set_num_threads(max(1, cfg.threads))
    net = build_net(demos, ws, spec, net_cfg)
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(1, cfg.iterations), cfg.lr * 0.02)
    P, Q, V, lengths = _padded(demos, cfg.window, spec.orientation)
    sample_demo = np.repeat(np.arange(len(lengths)), lengths)
    sample_k = np.concatenate([np.arange(L) for L in lengths])
    offsets = np.arange(cfg.window + 1)
    low = torch.as_tensor(ws.low, dtype=torch.float32)
    high = torch.as_tensor(ws.high, dtype=torch.float32)
    dt = demos.dt
    # stability starts also beyond the box (sample_pad): the field just outside the evaluated
    # workspace is trained too, else rollouts from its edges leave it into untrained space
    start_ws = ws.padded(cfg.sample_pad) if cfg.sample_pad > 0 else ws
    history: list[dict] = []
    chain = chain_rest = None
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.iterations, desc="PUMA", unit="it", dynamic_ncols=True)
    t0 = time.perf_counter()
    best: tuple | None = None
    best_state = None
    selection: list[dict] = []

    def validate(it):
        nonlocal best, best_state
        net.eval()
        net.cache_goal()
        with torch.no_grad():
            score, info = validator(net)
        net.train()
        selection.append({"it": it, **info, "score": list(score)})
        if best is None or score > best:
            best, best_state = score, copy.deepcopy(net.state_dict())
        for s in selection:
            s["chosen"] = False
        best_rec = max(selection, key=lambda s: s["score"])
        best_rec["chosen"] = True

    for it in range(cfg.iterations):
        pick = rng.integers(0, len(sample_k), cfg.batch_windows)
        di = torch.as_tensor(sample_demo[pick])[:, None]
        ki = torch.as_tensor(sample_k[pick][:, None] + offsets)
        target = (P[di, ki], Q[di, ki] if Q is not None else None, V[di, ki])
        l_il = losses.imitation_loss(net, target, dt, cfg.vel_weight)

        pos0, quat0, vel0 = _random_starts(rng, start_ws, spec, cfg, net.vel_scale.numpy())
        rest = (torch.all(vel0 == 0, dim=-1) if vel0 is not None
                else torch.ones(len(pos0), dtype=torch.bool))  # rollouts that started at rest
        if chain is not None:  # continue earlier rollouts (long horizons at no extra cost)
            keep = _keep(rng, chain, cfg.persist, low, high)
            pos0 = torch.where(keep, chain[0], pos0)
            quat0 = torch.where(keep, chain[1], quat0) if quat0 is not None else None
            vel0 = torch.where(keep, chain[2], vel0) if vel0 is not None else None
            rest = torch.where(keep[:, 0], chain_rest, rest)
        states = dynamics.rollout(net, (pos0, quat0, vel0), dt, cfg.stability_horizon)
        l_st, l_b = losses.stability_terms(
            net, states, dt, cfg.margin, cfg.squared_hinge,
            low if cfg.boundary_weight > 0 else None, high, cfg.decay_rate)
        if cfg.persist > 0:
            chain = tuple(None if s is None else s.detach() for s in states[-1])
            chain_rest = rest
        loss = l_il + cfg.stability_weight * l_st + cfg.boundary_weight * l_b
        l_p = torch.zeros(())
        if cfg.path_weight > 0:
            own = dynamics.stack(states)
            l_p = (losses.path_potential_loss(net, target[0], target[1], cfg.margin)
                   + losses.path_potential_loss(net, own[0], own[1], cfg.margin, rest))
            loss = loss + cfg.path_weight * l_p
        l_c = torch.zeros(())
        if cfg.compat_weight > 0:
            l_c = losses.compat_loss(net, pos0, quat0, cfg.compat_eps, cfg.margin)
            loss = loss + cfg.compat_weight * l_c
        opt.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.grad_clip)
        opt.step()
        sched.step()
        if it % cfg.log_every == 0 or it == cfg.iterations - 1:
            rec = {"it": it, "loss": loss.item(), "il": l_il.item(), "stable": l_st.item(),
                   "compat": l_c.item(), "path": l_p.item(), "boundary": l_b.item()}
            history.append(rec)
            if bar is not None:
                bar.set_postfix(il=f"{rec['il']:.2e}", st=f"{rec['stable']:.2e}",
                                cp=f"{rec['compat']:.2e}", refresh=False)
        if bar is not None:
            bar.update(1)
        if validator is not None and cfg.select_every > 0 and (
                it == cfg.iterations - 1 or (it + 1 >= cfg.select_from * cfg.iterations
                                             and (it + 1) % cfg.select_every == 0)):
            validate(it + 1)
    if bar is not None:
        bar.close()
    if best_state is not None:
        net.load_state_dict(best_state)
    net.eval()
    net.cache_goal()
    return TrainResult(net, time.perf_counter() - t0, history, selection)
