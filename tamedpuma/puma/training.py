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

The ψ-compatibility hinge (``compat_uniform``) may take fresh uniform samples of the workspace
instead of the stability starts: the continued rollouts gather near the motion and the goal,
while the evaluation judges ψ uniformly over the box.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import ConfigError
from ..robot.rotations import quat_angle
from . import dynamics, losses, manifold
from .data import Demonstrations
from .network import PumaNet, StateSpec
from .settings import NetConfig, TrainConfig


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




@dataclass
class TrainResult:
    net: PumaNet
    seconds: float
    history: list[dict] = field(default_factory=list)
    selection: list[dict] = field(default_factory=list)  # validation scores, chosen one marked
    iterations_run: int = 0  # < the configured iterations after an early stop


def scales(demos: Demonstrations, ws: Workspace, order: int, out_quantile: float = 1.0):
    """Normalisation: position scale (max |e| of data and workspace), velocity and output scales.

    Per component group (position, orientation): the velocity scale is the maximum absolute
    value over the data; the decoder's output is ``s_a ⊙ φ`` with s_a the ``out_quantile``
    quantile, over the demonstrations, of each one's largest |acceleration| component (first
    order: |velocity|). 1 is the largest over all data, which one spike of one demonstration can
    set (pouring_v2: 3.7 m/s², the other 37 peak at 0.19-0.87); 0.5 is a typical demonstration's
    peak. The scale is also the step an optimiser's update makes in the output: a quantile over
    samples instead (the 99th percentile) lies below every demonstration's peak where each has a
    brief one (the synthetic reaches start at their largest acceleration), and learnt slower.
    """
    n = demos.n_pos
    allp = np.concatenate(demos.pos)
    box = np.maximum(np.abs(ws.low), np.abs(ws.high))
    pos_scale = np.maximum(np.maximum(np.abs(allp).max(0), box), 1e-6)
    acc = [np.diff(v, axis=0, append=v[-1:]) / demos.dt for v in demos.vel]

    def group(xs, q=1.0):
        dim = xs[0].shape[1]
        out = np.zeros(dim)
        for sl in (slice(0, n), slice(n, dim)) if dim > n else (slice(0, n),):
            out[sl] = max(np.quantile([np.abs(x[:, sl]).max() for x in xs], q), 1e-6)
        return out

    vel_scale = group(demos.vel)
    out_scale = group(acc if order == 2 else demos.vel, out_quantile)
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


def _random_starts(rng, ws: Workspace, spec: StateSpec, cfg: TrainConfig, vel_scale,
                   n: int | None = None):
    """Stability starts: samples of ``ws`` (the workspace, padded by ``sample_pad`` in ``train``);
    velocities zero for half, else within ±½ max speed.

    A fraction ``near_goal_fraction`` is shrunk towards the goal by a log-uniform factor in
    [1e-3, 1] (positions, rotation angles and velocities), so the goal's neighbourhood is trained.
    """
    b = cfg.stability_batch if n is None else n
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
    pos_scale, vel_scale, out_scale = scales(demos, ws, spec.order, net_cfg.out_quantile)
    if not spec.orientation:
        vel_scale, out_scale = vel_scale[: spec.n_pos], out_scale[: spec.n_pos]
    return PumaNet(spec, net_cfg, pos_scale, vel_scale, out_scale)


@dataclass
class _Sampler:
    """Demonstration windows: padded tensors and, per sample, (demonstration, index)."""

    P: torch.Tensor
    Q: torch.Tensor | None
    V: torch.Tensor
    demo: np.ndarray
    k: np.ndarray
    offsets: np.ndarray

    @staticmethod
    def of(demos: Demonstrations, window: int, orientation: bool) -> _Sampler:
        P, Q, V, lengths = _padded(demos, window, orientation)
        return _Sampler(P, Q, V, np.repeat(np.arange(len(lengths)), lengths),
                        np.concatenate([np.arange(L) for L in lengths]), np.arange(window + 1))

    def batch(self, rng, n: int, window: int | None = None):
        """n windows of ``window`` + 1 samples (default: the full W + 1): (positions,
        quaternions or None, velocities)."""
        pick = rng.integers(0, len(self.k), n)
        di = torch.as_tensor(self.demo[pick])[:, None]
        offsets = self.offsets if window is None else self.offsets[: window + 1]
        ki = torch.as_tensor(self.k[pick][:, None] + offsets)
        return self.P[di, ki], self.Q[di, ki] if self.Q is not None else None, self.V[di, ki]


@dataclass
class _Selection:
    """Validation-based selection of the weights (``select_every``): keeps the best score.

    A validation the stop rule does not check (no converged share: not a candidate) can hold
    the lowest DTW of the run, and training may then leave it (a jump of the mean DTW between
    validations, as on the synthetic sets); its weights are kept aside (``unchecked``) and
    :meth:`reconsider` checks them at the end of the run where they are better than the chosen
    ones, so the kept weights are the best the checks can see, not only the best checked."""

    best: tuple | None = None
    best_state: dict | None = None
    records: list[dict] = field(default_factory=list)
    unchecked: tuple[int, float, dict] | None = None  # (iteration, DTW, weights) of that one

    def due(self, cfg: TrainConfig, it: int) -> bool:
        return cfg.select_every > 0 and (it == cfg.iterations - 1 or (
            it + 1 >= cfg.select_from * cfg.iterations and (it + 1) % cfg.select_every == 0))

    def validate(self, net: PumaNet, validator, it: int, final: bool = False) -> bool:
        """Validate the current weights, keep them if their score is the best so far; True when
        the validator says stop (the run ends). A stop does not keep the current weights over
        better ones: the last validation of a run whose learning rate decayed can score below
        an earlier one that passed (a first-order pouring model: 1.89 cm at its end against
        1.61 cm, both passing), and the validated DTW is the evaluation's own."""
        score, info = self._score(net, validator, final)
        lowest = "dtw" in info and all(info["dtw"] < r["dtw"] for r in self.records if "dtw" in r)
        if lowest:  # the run's lowest DTW so far: kept aside where the rule did not check it
            self.unchecked = None if "converged_fraction" in info else (
                it, info["dtw"], copy.deepcopy(net.state_dict()))
        self._record({"it": it, **info, "score": list(score)}, net, score)
        return bool(info.get("stop", False))

    def reconsider(self, net: PumaNet, validator) -> None:
        """Check the weights kept aside (:attr:`unchecked`) as a final candidate where their DTW
        is below the chosen weights'; keep them if they score better. ``net`` is overwritten."""
        if self.unchecked is None:
            return
        it, dtw, state = self.unchecked
        self.unchecked = None
        if not dtw < max(self.records, key=lambda r: r["score"]).get("dtw", np.inf):
            return
        net.load_state_dict(state)
        score, info = self._score(net, validator, True)
        self._record({"it": it, **info, "score": list(score), "rechecked": True}, net, score)

    def _score(self, net: PumaNet, validator, final: bool) -> tuple[tuple, dict]:
        net.eval()
        net.cache_goal()
        with torch.no_grad():
            out = validator(net, final, tuple(r["dtw"] for r in self.records if "dtw" in r))
        net.train()
        return out

    def _record(self, record: dict, net: PumaNet, score: tuple) -> None:
        self.records.append(record)
        if self.best is None or score > self.best:
            self.best, self.best_state = score, copy.deepcopy(net.state_dict())
        chosen = max(self.records, key=lambda r: r["score"])  # the first of equal scores
        for r in self.records:
            r["chosen"] = r is chosen


@dataclass
class _Run:
    """Everything one training iteration reads and updates (and a resumed run restores)."""

    net: PumaNet
    opt: torch.optim.Optimizer
    sched: object
    rng: np.random.Generator
    sampler: _Sampler
    start_ws: Workspace
    low: torch.Tensor
    high: torch.Tensor
    dt: float
    it: int = 0
    chain: tuple | None = None
    chain_rest: torch.Tensor | None = None
    ema: PumaNet | None = None  # exponential moving average of the weights (cfg.ema > 0)
    step: Callable | None = None  # the compiled rollout step (cfg.compile)
    ws: Workspace | None = None  # the evaluated workspace (not padded): ψ's uniform samples
    anneal_from: int | None = None  # iteration the final learning-rate decay started at
    anneal_lr: float = 0.0          # the learning rate it started from
    history: list[dict] = field(default_factory=list)
    selection: _Selection = field(default_factory=_Selection)

    def state(self) -> dict:
        """The resumable state (weights, optimiser, schedule, every RNG, persistent rollouts)."""
        return {"it": self.it, "net": self.net.state_dict(), "opt": self.opt.state_dict(),
                "sched": self.sched.state_dict(), "rng": self.rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(), "chain": self.chain,
                "chain_rest": self.chain_rest, "history": self.history,
                "ema": None if self.ema is None else self.ema.state_dict(),
                "anneal": (self.anneal_from, self.anneal_lr),
                "selection": {"best": self.selection.best, "best_state": self.selection.best_state,
                              "records": self.selection.records,
                              "unchecked": self.selection.unchecked}}

    def restore(self, state: dict) -> None:
        self.it = int(state["it"])
        self.net.load_state_dict(state["net"])
        self.opt.load_state_dict(state["opt"])
        self.sched.load_state_dict(state["sched"])
        self.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        self.chain, self.chain_rest = state["chain"], state["chain_rest"]
        if self.ema is not None:
            self.ema.load_state_dict(state["ema"])
        self.history = list(state["history"])
        self.anneal_from, self.anneal_lr = state.get("anneal", (None, 0.0))
        sel = state["selection"]
        self.selection = _Selection(None if sel["best"] is None else tuple(sel["best"]),
                                    sel["best_state"], list(sel["records"]),
                                    sel.get("unchecked"))


def _at_rest(pos: torch.Tensor, vel: torch.Tensor | None) -> torch.Tensor:
    """Which starts are at rest (B,) bool: zero velocity (first order, no velocity: all)."""
    if vel is None:
        return torch.ones(len(pos), dtype=torch.bool)
    return torch.all(vel == 0, dim=-1)


def _stability_starts(run: _Run, spec: StateSpec, cfg: TrainConfig):
    """Stability starts, fresh or continued from the last iteration, then ``fresh_starts`` new
    ones (never continued: only the first ``stability_batch`` rows go on): (pos, quat, vel,
    rest)."""
    pos0, quat0, vel0 = _random_starts(run.rng, run.start_ws, spec, cfg, run.net.vel_scale.numpy())
    rest = _at_rest(pos0, vel0)
    if run.chain is not None:  # continue earlier rollouts (long horizons at no extra cost)
        keep = _keep(run.rng, run.chain, cfg.persist, run.low, run.high)
        pos0 = torch.where(keep, run.chain[0], pos0)
        quat0 = torch.where(keep, run.chain[1], quat0) if quat0 is not None else None
        vel0 = torch.where(keep, run.chain[2], vel0) if vel0 is not None else None
        rest = torch.where(keep[:, 0], run.chain_rest, rest)
    if cfg.fresh_starts > 0:  # fresh starts every iteration besides the continued ones
        more = _random_starts(run.rng, run.start_ws, spec, cfg, run.net.vel_scale.numpy(),
                              cfg.fresh_starts)
        rest = torch.cat((rest, _at_rest(more[0], more[2])))
        pos0, quat0, vel0 = (_cat(a, m) for a, m in zip((pos0, quat0, vel0), more))
    return pos0, quat0, vel0, rest


def compat_states(rng, ws: Workspace, spec: StateSpec, n: int, exclude: float):
    """Rest states for the ψ-compatibility hinge drawn as the evaluation draws its own: ``n``
    uniform samples of the workspace box ``ws`` (not padded; orientations within its
    ``max_angle``), less those within r = ``exclude`` × the box's largest side of the goal
    (|e| ≤ r [unit] and, with orientation, angle ≤ r [rad] too: the states the evaluation does
    not judge; within half a step (:func:`compat_step`) of the goal no direction lowers ψ).

    The stability starts, mostly continued rollouts (``persist``), crowd near the motion and the
    goal; these cover the box as uniformly as the evaluation's measure does. Returns
    (pos (m, n_pos), quat (m, 4) | None), m ≤ n, float32 tensors."""
    pos, quat = ws.sample(rng, n, spec.orientation)
    far = beyond_goal(pos, quat, exclude * float(np.max(np.subtract(ws.high, ws.low))))
    f = lambda a: None if a is None else torch.as_tensor(a[far], dtype=torch.float32)  # noqa: E731
    return f(pos), f(quat)


def beyond_goal(pos: np.ndarray, quat: np.ndarray | None, r: float) -> np.ndarray:
    """Which rest states (goal-relative positions (m, n_pos), quaternions (m, 4) or None) lie
    beyond r of the goal: ``‖e‖ > r`` [unit] or, with orientation, a rotation angle > r [rad]
    (the states ψ's compatibility is judged at, in the evaluation and in the hinge)."""
    far = np.linalg.norm(pos, axis=1) > r
    if quat is not None:
        far |= quat_angle(quat) > r
    return far


def compat_step(cfg: TrainConfig, ws: Workspace) -> float:
    """The ψ-compatibility hinge's step ε [unit | rad]: ``compat_eps_rel`` × the box's largest
    side where that is set (the same share of any workspace, whatever the data's unit: the
    hinge's gradient grows with ε, so this also keeps its weight against the other losses),
    else the length ``compat_eps``."""
    if cfg.compat_eps_rel > 0:
        return cfg.compat_eps_rel * float(np.max(np.subtract(ws.high, ws.low)))
    return cfg.compat_eps


def _compat_term(run: _Run, spec: StateSpec, cfg: TrainConfig, pos0, quat0) -> torch.Tensor:
    """ℓ_compat on the stability starts ``pos0``, ``quat0``, or with ``compat_uniform`` > 0 on
    that many uniform rest states of the workspace instead (:func:`compat_states`)."""
    if cfg.compat_uniform > 0:
        pos0, quat0 = compat_states(run.rng, run.ws, spec, cfg.compat_uniform,
                                    cfg.compat_exclude)
        if len(pos0) == 0:  # every sample within the excluded ball
            return torch.zeros(())
    return losses.compat_loss(run.net, pos0, quat0, compat_step(cfg, run.ws), cfg.margin)


def _cat(a, b, dim=0):
    return None if a is None else torch.cat((a, b), dim=dim)


def _rollouts(net: PumaNet, target, starts, dt: float, window: int, horizon: int, step=None):
    """The imitation windows (from the first sample of each ``target`` window, ``window`` steps)
    and the stability rollouts (from ``starts``, ``horizon`` steps), stacked (B, T+1, ·) each,
    and the stability rollouts' latents (B, T+1, ·) (the steps' own, the last one encoded).

    Both run as one batch for their common steps (rows are independent: the same states as two
    separate rollouts, at about half the per-operation cost), the longer one then alone.
    ``step``: the compiled step (:func:`dynamics.latent_step`, ``compile``) or None."""
    pos_t, quat_t, vel_t = target
    order2 = net.spec.order == 2
    il0 = (pos_t[:, 0], quat_t[:, 0] if quat_t is not None else None,
           vel_t[:, 0] if order2 else None)
    b = len(pos_t)
    common = min(window, horizon)
    states, ys = dynamics.rollout_latents(net, tuple(_cat(a, c) for a, c in zip(il0, starts)),
                                          dt, common, step)
    both = dynamics.stack(states)
    il = tuple(None if x is None else x[:b] for x in both)
    st = tuple(None if x is None else x[b:] for x in both)
    st_y = [y[b:] for y in ys]

    def extend(part, steps, latents=None):
        last = tuple(None if x is None else x[:, -1] for x in part)
        more, more_y = dynamics.rollout_latents(net, last, dt, steps, step)
        if latents is not None:
            latents.extend(more_y)
        return tuple(_cat(x, m, 1) for x, m in zip(part, dynamics.stack(more[1:])))

    if window > common:
        il = extend(il, window - common)
    if horizon > common:
        st = extend(st, horizon - common, st_y)
    st_y.append(net.encode(*(None if x is None else x[:, -1] for x in st)))
    return il, st, torch.stack(st_y, dim=1)


def stability_weight(cfg: TrainConfig, it: int) -> float:
    """λ of the stability loss at iteration ``it``: ``stability_weight``, or with
    ``stability_weight_end`` > 0 that until ``stability_ramp_from`` of the run, then linear to
    ``stability_weight_end`` at its end (a stronger push for convergence once the imitation has
    formed: from the start, λ 2-3 set a pouring seed's training off course at iteration ~1100)."""
    w0, w1 = cfg.stability_weight, cfg.stability_weight_end
    if w1 <= 0:
        return w0
    start = cfg.stability_ramp_from * cfg.iterations
    frac = min(1.0, max(0.0, (it - start) / max(1.0, cfg.iterations - start)))
    return w0 + (w1 - w0) * frac


def window_at(cfg: TrainConfig, it: int) -> int:
    """The imitation window [steps] at iteration ``it``: ``window``, or with ``window_start`` > 0
    that many steps at first, growing linearly to ``window`` over the first ``window_ramp`` of
    the run (an iteration's cost is set by its rollout steps: short windows fit the local motion
    cheaply, the full window then corrects the drift of longer closed-loop rollouts)."""
    w0, w1 = cfg.window_start, cfg.window
    if w0 <= 0 or w0 >= w1:
        return w1
    frac = min(1.0, it / max(1.0, cfg.window_ramp * cfg.iterations))
    return int(round(w0 + (w1 - w0) * frac))


def _schedule(run: _Run, cfg: TrainConfig) -> None:
    """The learning rate for the next iteration: the cosine schedule over ``iterations``, or,
    once a plateau started the final decay (``anneal``), linear from where it was to 2% of
    ``lr`` over ``anneal`` iterations."""
    if run.anneal_from is None:
        run.sched.step()
        return
    frac = min(1.0, (run.it + 1 - run.anneal_from) / max(1, cfg.anneal))
    for group in run.opt.param_groups:
        group["lr"] = run.anneal_lr + (0.02 * cfg.lr - run.anneal_lr) * frac


def _annealed(run: _Run, cfg: TrainConfig) -> bool:
    """True once the final decay has run its ``anneal`` iterations."""
    return run.anneal_from is not None and run.it >= run.anneal_from + cfg.anneal


def _ends_here(selection: _Selection) -> bool:
    """Whether the last validation starts the final decay, which ends the run: a plateau of the
    DTW whose weights also passed every check of the validation (ψ, every start converged).

    The plateau is a function of the DTW alone (a rise after a training upset counts as well);
    the decay freezes the weights where they are, so a plateau of weights that do not converge
    would end the run on them. Such a plateau leaves the schedule and the stability weight's
    ramp running, and a later validation on the plateau that passes starts the decay (the kept
    weights are then ones that passed, whatever the decay's end shows)."""
    last = selection.records[-1]
    return bool(last.get("plateau")) and bool(last.get("passed"))


def _iteration(run: _Run, spec: StateSpec, cfg: TrainConfig) -> dict:
    """One optimisation step; returns the loss terms (floats)."""
    net = run.net
    window = window_at(cfg, run.it)
    target = run.sampler.batch(run.rng, cfg.batch_windows, window)
    pos0, quat0, vel0, rest = _stability_starts(run, spec, cfg)
    net.share_goal()
    try:
        il, states, latents = _rollouts(net, target, (pos0, quat0, vel0), run.dt, window,
                                        cfg.stability_horizon, run.step)
        l_il = losses.imitation_error(net, tuple(None if x is None else x[:, 1:] for x in il),
                                      target, cfg.vel_weight, cfg.pos_weight)
        l_st, l_b = losses.stability_terms(
            net, states, run.dt, cfg.margin, cfg.squared_hinge,
            run.low if cfg.boundary_weight > 0 else None, run.high, cfg.decay_rate, latents)
        if cfg.persist > 0:
            b = cfg.stability_batch
            run.chain = tuple(None if x is None else x[:b, -1].detach() for x in states)
            run.chain_rest = rest[:b]
        loss = l_il + stability_weight(cfg, run.it) * l_st + cfg.boundary_weight * l_b
        l_p = torch.zeros(())
        if cfg.path_weight > 0:
            k = cfg.path_windows or cfg.batch_windows  # the windows are in random order
            l_p = (losses.path_potential_loss(net, target[0][:k],
                                              None if target[1] is None else target[1][:k],
                                              cfg.margin)
                   + losses.path_potential_loss(net, states[0], states[1], cfg.margin, rest))
            loss = loss + cfg.path_weight * l_p
        l_c = torch.zeros(())
        if cfg.compat_weight > 0:
            l_c = _compat_term(run, spec, cfg, pos0, quat0)
            loss = loss + cfg.compat_weight * l_c
        run.opt.zero_grad(set_to_none=True)
        loss.backward()
    finally:
        net.release_goal()
    if cfg.grad_clip > 0:
        torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.grad_clip)
    run.opt.step()
    _schedule(run, cfg)
    if run.ema is not None:
        with torch.no_grad():
            torch._foreach_lerp_(list(run.ema.parameters()), list(net.parameters()),
                                 1.0 - cfg.ema)
    return {"loss": loss.item(), "il": l_il.item(), "stable": l_st.item(), "compat": l_c.item(),
            "path": l_p.item(), "boundary": l_b.item()}


def compiled_step() -> Callable:
    """:func:`dynamics.latent_step` through ``torch.compile`` (inductor: the step's element-wise
    work, LayerNorm and GELU fused into generated C++ loops next to the matrix products, and its
    backward likewise). Compiled at its first call for each batch shape (the imitation and
    stability rows together, the imitation rows alone), kept on disk by inductor's cache.
    Without a C++ compiler: :class:`ConfigError` before the first iteration."""
    import shutil

    if shutil.which("g++") is None and shutil.which("c++") is None:
        raise ConfigError("puma.train.compile=true needs a C++ compiler (g++) for torch.compile; "
                          "install one (e.g. apt-get install g++) or set "
                          "puma.train.compile=false")
    return torch.compile(dynamics.latent_step, dynamic=False, fullgraph=True,
                         options={"cpp_wrapper": True})


def _start(demos: Demonstrations, ws: Workspace, spec: StateSpec, net_cfg: NetConfig,
           cfg: TrainConfig, seed: int) -> _Run:
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
    # foreach: one call per update operation for all the weights instead of a loop over them
    # (on CPU the same per-tensor arithmetic in the same order: the weights to the bit)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, foreach=True)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(1, cfg.iterations), cfg.lr * 0.02)
    # stability starts also beyond the box (sample_pad): the field just outside the evaluated
    # workspace is trained too, else rollouts from its edges leave it into untrained space
    start_ws = ws.padded(cfg.sample_pad) if cfg.sample_pad > 0 else ws
    ema = None
    if cfg.ema > 0:
        ema = copy.deepcopy(net)
        ema.requires_grad_(False)
    return _Run(net, opt, sched, rng, _Sampler.of(demos, cfg.window, spec.orientation), start_ws,
                torch.as_tensor(ws.low, dtype=torch.float32),
                torch.as_tensor(ws.high, dtype=torch.float32), demos.dt, ema=ema,
                step=compiled_step() if cfg.compile else None, ws=ws)


def train(demos: Demonstrations, ws: Workspace, spec: StateSpec, net_cfg: NetConfig,
          cfg: TrainConfig, seed: int = 0, progress: bool = True,
          validator: Callable[[PumaNet, bool, tuple], tuple[tuple, dict]] | None = None,
          resume: dict | None = None, save: Callable[[dict], None] | None = None,
          save_every: int = 0) -> TrainResult:
    """Train a primitive on ``demos``; returns the network (eval mode) and the loss history.

    With ``validator`` and ``cfg.select_every`` > 0, the weights are validated every
    ``select_every`` iterations from ``select_from`` of the run on (and at the end); the weights
    with the best score (a tuple, larger is better) are returned. The validator must use its own
    random starts, not the evaluation's; it is called with the network, whether this is the final
    validation, and the earlier validations' DTWs. The run ends sooner where the validator says
    stop, or ``anneal`` iterations after a validation reported a plateau and passed (``info[
    "plateau"]`` and ``info["passed"]``: :func:`_ends_here`).
    ``save(state)`` is called every ``save_every`` iterations with the resumable state; passing
    that state back as ``resume`` continues the run exactly (same result as uninterrupted).
    """
    run = _start(demos, ws, spec, net_cfg, cfg, seed)
    if resume is not None:
        run.restore(resume)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.iterations, initial=run.it, desc="PUMA", unit="it",
                   dynamic_ncols=True)
    t0 = time.perf_counter()
    while run.it < cfg.iterations:
        it = run.it
        terms = _iteration(run, spec, cfg)
        if it % cfg.log_every == 0 or it == cfg.iterations - 1:
            run.history.append({"it": it, **terms})
            if bar is not None:
                bar.set_postfix(il=f"{terms['il']:.2e}", st=f"{terms['stable']:.2e}",
                                cp=f"{terms['compat']:.2e}", refresh=False)
        if bar is not None:
            bar.update(1)
        run.it = it + 1
        final = it == cfg.iterations - 1 or _annealed(run, cfg)
        if validator is not None and cfg.select_every > 0 and (final or run.selection.due(cfg, it)):
            if run.selection.validate(run.ema if run.ema is not None else run.net,
                                      validator, it + 1, final) or final:
                break  # early stop: the validation met every target (or the decay ended)
            if cfg.anneal > 0 and run.anneal_from is None and _ends_here(run.selection):
                run.anneal_from, run.anneal_lr = run.it, run.opt.param_groups[0]["lr"]
        if save is not None and save_every > 0 and run.it % save_every == 0 \
                and run.it < cfg.iterations:
            save(run.state())
    if bar is not None:
        bar.close()
    if validator is not None:
        run.selection.reconsider(run.ema if run.ema is not None else run.net, validator)
    if run.selection.best_state is not None:
        run.net.load_state_dict(run.selection.best_state)
    elif run.ema is not None:
        run.net.load_state_dict(run.ema.state_dict())
    run.net.eval()
    run.net.cache_goal()
    return TrainResult(run.net, time.perf_counter() - t0, run.history, run.selection.records,
                       run.it)
