"""Integration of a PUMA primitive: semi-implicit Euler on Rⁿ × S³.

Second order, step Δt [s]:
    ``(ë, ω̇) = f(e, ζ, ė, ω)``;  ``ė ← ė + ë Δt``, ``ω ← ω + ω̇ Δt``;
    ``e ← e + ė Δt``, ``ζ ← exp(ω Δt) ⊗ ζ``  (the exponential map of S³, see ``manifold``).
First order: ``(ė, ω) = f(e, ζ)``; ``e ← e + ė Δt``, ``ζ ← exp(ω Δt) ⊗ ζ``.

A state is a tuple ``(pos, quat, vel)``; ``quat`` is None without orientation and ``vel`` is None
for a first-order primitive. Tensors carry a leading batch dimension.
"""

from __future__ import annotations

import torch

from . import manifold
from .network import PumaNet

State = tuple  # (pos, quat | None, vel | None)


def step(net: PumaNet, state: State, dt: float) -> State:
    """One semi-implicit Euler step of Δt [s]."""
    return advance(net.spec, state, net(*state), dt)


def advance(spec, state: State, out, dt: float) -> State:
    """The step of Δt [s] from ``state`` with the network's output ``out`` (ẍ or ẋ) there."""
    pos, quat, vel = state
    n = spec.n_pos
    if spec.order == 2:
        vel = vel + out * dt
        tangent = vel
    else:
        tangent = out
    pos = pos + tangent[..., :n] * dt
    if quat is not None:
        quat = manifold.step_orientation(quat, tangent[..., n:], dt)
    return pos, quat, vel


def rollout(net: PumaNet, state: State, dt: float, steps: int, every: int = 1) -> list[State]:
    """States at steps 0, every, 2·every, ... ≤ steps (the start included)."""
    out = [state]
    for k in range(1, steps + 1):
        state = step(net, state, dt)
        if k % every == 0:
            out.append(state)
    return out


def latent_step(net: PumaNet, pos, quat, vel, goal_out, dt: float):
    """One step and the latent it computed: ``(pos', quat', vel', y)``, with the goal offset
    ``goal_out`` (:meth:`PumaNet.goal_offset`) passed in, so that the step is a function of its
    arguments alone (``torch.compile`` compiles it once per batch shape)."""
    y = net.encode(pos, quat, vel)
    return (*advance(net.spec, (pos, quat, vel), net.output(y, goal_out), dt), y)


def rollout_latents(net: PumaNet, state: State, dt: float, steps: int, step=None):
    """States at steps 0..steps and the latents ``y_k = ρ(x_k, ẋ_k)`` at steps 0..steps−1 (the
    ones the steps computed; training reuses them in the stability loss). ``step``: a compiled
    :func:`latent_step` to take the steps with (None: :func:`latent_step` itself)."""
    step = step or latent_step
    states, latents = [state], []
    goal_out = net.goal_offset()
    for _ in range(steps):
        *moved, y = step(net, *state, goal_out, dt)
        state = tuple(moved)
        latents.append(y)
        states.append(state)
    return states, latents


def stack(states: list[State]) -> State:
    """List of states → one state with a time axis at dim 1: (batch, T, ...)."""
    pos = torch.stack([s[0] for s in states], dim=1)
    quat = torch.stack([s[1] for s in states], dim=1) if states[0][1] is not None else None
    vel = torch.stack([s[2] for s in states], dim=1) if states[0][2] is not None else None
    return pos, quat, vel


def final_state(net: PumaNet, state: State, dt: float, steps: int) -> State:
    """Integrate ``steps`` steps without keeping the path (for convergence tests)."""
    for _ in range(steps):
        state = step(net, state, dt)
    return state
