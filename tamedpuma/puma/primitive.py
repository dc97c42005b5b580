"""Trained primitives for the controllers: world frame, physical units, numpy in and out.

``load_primitive(path)`` returns a :class:`PosePrimitive` (second order on R³ × S³) or a
:class:`VectorPrimitive` (Rⁿ, first or second order; e.g. the first-order R³ position model of
Modulation-IK, or 2-D LASA models). Every call converts the world-frame state to the goal-relative
state the network was trained on (goal convention ``final_pose``: ``e = p − p_g``,
``ζ_rel = ζ ⊗ ζ_g⁻¹``; velocities are unchanged: ``ζ̇_rel = ½ ω ⊗ ζ_rel`` for a fixed goal) and runs
a float64 numpy copy of the network: for one state :class:`~tamedpuma.puma.single.SingleState`
(a fixed, small number of numpy calls on preallocated buffers), for batches, and as the reference
the one-state path is tested against, ``fastnet`` (itself checked against torch); no module is
built per call. ``primitive.single = None`` selects the reference for single states too (the
benchmark's before/after). Angular velocities are
world-frame ω [rad/s]: the network works with ω natively, so no quaternion-derivative conversion
happens at all on this path.
"""

from __future__ import annotations

import copy
import hashlib
from pathlib import Path

import numpy as np
import torch

from ..errors import CheckpointError
from ..robot.rotations import relative_quat, relative_rotation
from . import checkpoint
from .checkpoint import Meta
from .fastnet import FastNet
from .network import PumaNet
from .single import SingleState


def _floats(x) -> list[float]:
    return x.tolist() if isinstance(x, np.ndarray) else [float(v) for v in x]


def _pose_error(p, quat, goal_p, goal_quat) -> tuple[list[float], list[float]]:
    """``(p − p_g, entries of R(ζ ⊗ ζ_g⁻¹))`` of one pose, as Python floats."""
    (px, py, pz), (gx, gy, gz) = _floats(p), _floats(goal_p)
    return [px - gx, py - gy, pz - gz], relative_rotation(_floats(quat), _floats(goal_quat))


class _Base:
    def __init__(self, net: PumaNet, meta: Meta):
        self.net, self.meta = net, meta
        self.spec = net.spec
        self.dt = meta.dt  # model step [s] used in training; the ODE is in physical time
        net.eval()
        net.cache_goal()
        for p in net.parameters():
            p.requires_grad_(False)
        self.fast = FastNet(net)
        self.single: SingleState | None = SingleState(self.fast)  # None: the reference path

    def for_episode(self):
        """A wrapper of the same network for one episode: the network, its float64 copy and the
        one-state weights shared, the one-state buffers and rest-row memo its own
        (:meth:`SingleState.fresh`), so an episode's calls write only what the episode owns."""
        own = copy.copy(self)
        if self.single is not None:
            own.single = self.single.fresh()
        return own

    @property
    def goal(self) -> dict:
        """The task's nominal goal stored at training time ({'position', 'quaternion'})."""
        return self.meta.goal


class PosePrimitive(_Base):
    """Second-order primitive on R³ × S³ (end-effector position and orientation)."""

    def acceleration(self, p, quat_xyzw, v, omega, goal_p, goal_quat):
        """``(a (3,) [m/s²], α (3,) [rad/s²])`` world frame, at pose (p [m], ζ) and twist
        (v [m/s], ω [rad/s], world frame) for the goal (goal_p [m], goal_quat (x, y, z, w))."""
        one = self.single
        if one is not None:
            e, rot = _pose_error(p, quat_xyzw, goal_p, goal_quat)
            out = one.forward(e, rot, [*_floats(v), *_floats(omega)])
            return out[:3], out[3:]
        a = self.acceleration_batch(np.reshape(p, (1, 3)), np.reshape(quat_xyzw, (1, 4)),
                                    np.reshape(v, (1, 3)), np.reshape(omega, (1, 3)),
                                    goal_p, goal_quat)
        return a[0][0], a[1][0]

    def acceleration_batch(self, p, quat, v, omega, goal_p, goal_quat):
        """Batched :meth:`acceleration`: inputs (B, 3)/(B, 4); returns two (B, 3) arrays."""
        e = np.asarray(p, np.float64) - np.asarray(goal_p, np.float64)
        q = relative_quat(quat, goal_quat)
        vel = np.concatenate((np.asarray(v, np.float64), np.asarray(omega, np.float64)), axis=-1)
        out = self.fast.forward(e, q, vel)
        return out[:, :3], out[:, 3:]

    def potential(self, p, quat, goal_p, goal_quat):
        """``(ψ, ∂ψ/∂p (3,), ∂ψ/∂θ (3,))`` with ``ψ = ‖ρ(x_g, 0) − ρ(x, 0)‖²``.

        ∂ψ/∂θ is w.r.t. a small world-frame rotation δθ applied as ``ζ ← exp(δθ) ⊗ ζ``, so a
        joint-space gradient is ``∂ψ/∂q = ∂ψ/∂p · J_v + ∂ψ/∂θ · J_ω``.
        """
        if self.single is not None:
            return self.single.potential(*_pose_error(p, quat, goal_p, goal_quat))
        psi, gp, gt = self.potential_batch(np.reshape(p, (1, 3)), np.reshape(quat, (1, 4)),
                                           goal_p, goal_quat)
        return float(psi[0]), gp[0], gt[0]

    def psi(self, p, quat, goal_p, goal_quat) -> float:
        """ψ alone (no gradient) at pose (p [m], ζ) for the goal: what a log needs."""
        if self.single is not None:
            return self.single.psi(*_pose_error(p, quat, goal_p, goal_quat))
        return float(self.potential_batch(np.reshape(p, (1, 3)), np.reshape(quat, (1, 4)),
                                          goal_p, goal_quat)[0][0])

    def potential_batch(self, p, quat, goal_p, goal_quat):
        e = np.asarray(p, np.float64) - np.asarray(goal_p, np.float64)
        q = relative_quat(quat, goal_quat)
        return self.fast.potential(e, q)

    def latent(self, p, quat, v, omega, goal_p, goal_quat) -> np.ndarray:
        """The encoder's latent ``y = ρ(x, ẋ)`` of one state."""
        e = np.reshape(np.asarray(p, np.float64) - goal_p, (1, 3))
        q = relative_quat(np.reshape(quat, (1, 4)), goal_quat)
        vel = np.concatenate((np.ravel(v), np.ravel(omega)))[None]
        return self.fast.encode(e, q, vel)[0]


class VectorPrimitive(_Base):
    """Primitive on Rⁿ: first order (``velocity``) or second order (``acceleration``)."""

    def _rel(self, x, goal):
        x = np.asarray(x, np.float64)
        return x - (0.0 if goal is None else np.asarray(goal, np.float64))

    def velocity(self, x, goal=None) -> np.ndarray:
        """First order: ``ẋ = f(x − x_g)`` [unit/s]; x (n,) or (B, n)."""
        if self.spec.order != 1:
            raise CheckpointError("velocity() needs a first-order primitive; this one is second "
                                  "order (use acceleration)")
        e = self._rel(x, goal)
        if e.ndim == 1 and self.single is not None:
            return self.single.forward(e.tolist(), None, None)
        return self.fast.forward(np.atleast_2d(e)).reshape(e.shape)

    def acceleration(self, x, xd, goal=None) -> np.ndarray:
        """Second order: ``ẍ = f(x − x_g, ẋ)`` [unit/s²]; x, xd (n,) or (B, n)."""
        if self.spec.order != 2:
            raise CheckpointError("acceleration() needs a second-order primitive; this one is "
                                  "first order (use velocity)")
        e = self._rel(x, goal)
        if e.ndim == 1 and self.single is not None:
            return self.single.forward(e.tolist(), None, np.asarray(xd, np.float64).tolist())
        xd = np.atleast_2d(np.asarray(xd, np.float64))
        return self.fast.forward(np.atleast_2d(e), None, xd).reshape(e.shape)

    def psi(self, x, goal=None) -> float:
        """ψ alone (no gradient) at one x (n,): what a log needs."""
        e = self._rel(x, goal)
        if self.single is not None:
            return self.single.psi(e.tolist(), None)
        return float(self.fast.potential(e[None])[0][0])

    def potential(self, x, goal=None):
        """``(ψ, ∂ψ/∂x)`` with ``ψ = ‖ρ(x_g, 0) − ρ(x, 0)‖²``; x (n,) or (B, n)."""
        e = self._rel(x, goal)
        if e.ndim == 1 and self.single is not None:
            psi, g, _ = self.single.potential(e.tolist(), None)
            return psi, g
        psi, g, _ = self.fast.potential(np.atleast_2d(e))
        return (float(psi[0]), g[0]) if e.ndim == 1 else (psi, g)


Primitive = PosePrimitive | VectorPrimitive


def wrap(net: PumaNet, meta: Meta) -> PosePrimitive | VectorPrimitive:
    """The right primitive class for a network's state spec."""
    if net.spec.orientation:
        if net.spec.n_pos != 3 or net.spec.order != 2:
            raise CheckpointError(f"unsupported pose primitive {net.spec}")
        return PosePrimitive(net, meta)
    return VectorPrimitive(net, meta)


#: checkpoints a process keeps loaded (a sweep worker's runs share them), by path and sha256
LOADED_KEPT = 8
_LOADED: dict = {}


def load_primitive(path: str | Path, threads: int | None = 1) -> PosePrimitive | VectorPrimitive:
    """Load a checkpoint strictly (see ``checkpoint.load``) and wrap it for inference: a fresh
    wrapper (its own buffers and caches) around the network, which is loaded once per process
    and file content (the key is the resolved path and the file's sha256: a file rewritten in
    place is loaded again).

    ``threads``: torch intra-op threads for inference (1 is fastest for one state); None keeps it.
    """
    if threads is not None:
        torch.set_num_threads(threads)
    path = Path(path)
    try:
        key = (str(path.resolve()), hashlib.sha256(path.read_bytes()).hexdigest())
    except OSError:  # missing or unreadable: checkpoint.load says so in its words
        return wrap(*checkpoint.load(path))
    if key not in _LOADED:
        if len(_LOADED) >= LOADED_KEPT:
            _LOADED.pop(next(iter(_LOADED)))
        _LOADED[key] = checkpoint.load(path)
    net, meta = _LOADED[key]
    warn_failed_gates(path, meta.report)
    return wrap(net, meta)


_WARNED: set[str] = set()


def warn_failed_gates(path: str | Path, report: dict | None, log=None) -> list[str]:
    """Say once per model file (on stderr, or through ``log``) which gates its training failed
    (:mod:`.gates`, stored in its report); returns those lines."""
    import sys

    from .gates import failed_lines

    lines = failed_lines(report)
    key = str(Path(path).resolve())
    if lines and key not in _WARNED:
        _WARNED.add(key)
        say = log or (lambda m: print(m, file=sys.stderr))
        say(f"warning: the model {path} failed {len(lines)} gate(s) after its training:")
        for line in lines:
            say(f"  - {line}")
    return lines
