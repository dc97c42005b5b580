"""Circulation: PUMA's push into an obstacle turned around it (``method.forcing.circulation``).

Why. Where the goal lies behind an obstacle as seen from the arm (the hand resting on a sphere with
the goal below it), PUMA's field points through the obstacle, the avoidance metric suppresses the
push along the barrier's normal (``forcing.mode: metric``) and what is left of PUMA's tangential
pull is balanced where the obstacle's side meets PUMA's potential: the arm rests at the barrier, a
local minimum of the forced fabric. Neither other gains nor switching off energization, the α bound,
the barrier step or the limit margin removes such a point: PUMA's field and the barrier's geometry
make it. Law and ablation row: docs/method.md, "How PUMA's forcing meets the fabric".

What. For every body sphere i within ``distance`` d_a of an obstacle j (clearance d, unit normal
n from the obstacle to the sphere) whose acceleration under PUMA's obstacle-free pull,
``p = J_i q̈_P + J̇_i q̇`` [m/s²], points into the obstacle (``p·n < 0``), an acceleration spec
on the sphere's motion along a tangent t̂ of the obstacle::

    t̂ᵀ(J_i q̈ + J̇_i q̇) = p·t̂ + g s (−p·n),     weight  w s,
    s = (1 − d/d_a) · min(1, (−p̂·n − c₀)/(1 − c₀))                               [1]

(the second factor: only a push within arccos c₀ of head-on counts as blocked; a pull that
merely grazes the obstacle, PUMA's own way round it, is left alone) is summed with PUMA's task
spec in the weighted pseudo-inverse of ``forcing.mode: metric``
(:func:`tamedpuma.methods._policy.pull_through_metric`): the push the barrier takes away along n
is given back along t̂ (gain g), as the modulation of a dynamical system around an obstacle keeps
the speed of the modulated field (Huber, Billard & Slotine 2019: normal eigenvalue → 0,
tangential eigenvalue 1 + g). The tangent is the obstacle's great circle through the sphere about
a fixed axis b (a circular field, Singh et al. 2022): b = n × t̂₀ is chosen when the first pair
becomes active, with t̂₀ the tangential part of PUMA's pull at rest ``J_i q̈_P(q, 0)`` (towards
the goal, without PUMA's damping of the current velocity, which would point the axis backwards
for an arm already sliding along the obstacle) (else of the sphere's velocity, else of the
first joint's motion of the sphere that has one, else of the world's axes), and kept while any
pair stays within d_a. So the arm keeps going round one way instead of turning back at the line
behind the obstacle, where p's tangential part changes sign; and every sphere and obstacle (two
overlapping spheres, a forearm and a hand on one obstacle) turn the same way.
t̂ = b × n / ‖b × n‖.

What holds. The spec only shapes the forcing near obstacles: far from them (d ≥ d_a for every pair,
in particular at a goal clear of the obstacles) f_θ^C is unchanged, so its zero set and the
statements of FPM (PUMA's zero set kept) and CPM (dH/dt = −β q̇ᵀMq̇, which does not depend on the
forcing) hold unchanged. Safety does not depend on the forcing: the barriers' metric and geometry
and the control-rate barrier step are unchanged. What is given up near obstacles: the forcing is no
longer PUMA's field (it is not anyway where the barrier metric bends it), and going round may climb
PUMA's potential ψ, which CPM's regulator opposes (CPM escapes only as far as its energy allows).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tamedpuma.methods._kernels import STEP

_X, _Y, _UP = np.eye(3)
#: [m] far above the rounding difference of two computations of one clearance (~1e-16 m), far
#: below anything physical: a clearance known to exceed d_a by this is beyond d_a in either
_ROUNDING_M = 1e-9


@dataclass(frozen=True)
class TangentSpecs:
    """Rows R (K, n) ``t̂ᵀJ_i``, targets a (K,) ``p·t̂ + g s (−p·n) − t̂·J̇_i q̇`` [m/s²] and
    weights (K,) ``w s(d)`` [1] of the active pairs; K may be 0."""

    rows: np.ndarray
    targets: np.ndarray
    weights: np.ndarray


@dataclass
class Circulation:
    """The circulation of ``method.forcing`` with its memory of the arm's axis (``axes["arm"]``,
    kept while any pair is within d_a).

    distance d_a [m] (> 0); gain g [1]; weight w [1] (PUMA's task metric); cos_onset c₀ [1]:
    a pair acts only where p points into the obstacle within arccos(c₀) of its normal, fully
    when head on: s is multiplied by ``min(1, (−p̂·n − c₀)/(1 − c₀))`` (0: any inward push)."""

    distance: float
    gain: float
    weight: float
    cos_onset: float = 0.0
    axes: dict = field(default_factory=dict)

    def specs(self, state, qd: np.ndarray, qdd_free: np.ndarray, centers: np.ndarray,
              radii: np.ndarray, pull_at_rest=None,
              min_clearance: float | None = None) -> TangentSpecs | None:
        """The tangent specs at a kinematic state (sphere centres, Jacobians, J̇q̇), joint
        velocity q̇, PUMA's obstacle-free joint acceleration q̈_P and the obstacles (centres
        (m, 3) [m], radii (m,) [m]); None when no pair is active. pull_at_rest: a callable
        giving PUMA's obstacle-free joint acceleration at q̇ = 0 (its pull towards the goal
        without its damping), called only when the axis is chosen (else q̈_P is used).
        min_clearance [m]: the smallest pair clearance when the caller knows it (the avoidance
        fabric's, :attr:`~tamedpuma.fabrics.fabric.AvoidanceFabric.min_clearance`, the same
        quantity up to rounding): beyond d_a + 1 nm no pair can be active, and the pair
        distances are not computed again (the common case, far from every obstacle)."""
        if len(radii) == 0 or (min_clearance is not None
                               and min_clearance > self.distance + _ROUNDING_M):
            self.axes.clear()
            return None
        pairs, clear, normals, pushes, push, head_on = STEP["pair_pushes"](
            state.sphere_centers, state.sphere_radii, state.sphere_jacobians, state.sphere_jdqd,
            centers, radii, qdd_free, self.distance, self.cos_onset)
        if len(pairs) == 0:
            self.axes.clear()
            return None
        rows, targets, weights = [], [], []
        for a in (~((push <= 0.0) | (head_on <= 0.0))).nonzero()[0]:
            n, p, i = normals[a], pushes[a], pairs[a, 0]
            Ji, jd = state.sphere_jacobians[i], state.sphere_jdqd[i]
            if "arm" not in self.axes and pull_at_rest is not None:
                rest = pull_at_rest()
                t = self._tangent(n, Ji @ rest, Ji @ qd, Ji)
            else:
                t = self._tangent(n, p, Ji @ qd, Ji)
            s = (1.0 - max(float(clear[a]), 0.0) / self.distance) * min(float(head_on[a]), 1.0)
            rows.append(t @ Ji)
            targets.append(float(p @ t) + self.gain * s * float(push[a]) - float(t @ jd))
            weights.append(self.weight * s)
        if not rows:
            return None
        return TangentSpecs(np.array(rows), np.array(targets), np.array(weights))

    def _tangent(self, n: np.ndarray, p: np.ndarray, v: np.ndarray,
                 Ji: np.ndarray) -> np.ndarray:
        """t̂ = b × n / ‖b × n‖ about the arm's axis b (one for every pair, chosen by the first
        pair to become active: see the module); a pair whose normal lies within 11.5° of b
        takes its own tangent (not stored)."""
        b = self.axes.get("arm")
        if b is not None:
            t = _cross(b, n)
            norm = _norm(t)
            if norm > 0.2:  # the axis still spans a tangent plane with n
                return t / norm
        for candidate in (p, v, *Ji.T, _UP, _X, _Y):
            t = candidate - (candidate @ n) * n
            norm = _norm(t)
            if norm > 1e-3 * max(_norm(candidate), 1e-9) and norm > 1e-9:
                t = t / norm
                if b is None:
                    self.axes["arm"] = _cross(n, t)
                return t
        raise AssertionError("unreachable: the world's axes cannot all be parallel to n")


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` of two 3-vectors: np.cross's numbers (``a₁b₂ − a₂b₁``, ...) without its
    ~10 µs of axis handling."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _norm(x: np.ndarray) -> float:
    """‖x‖: np.linalg.norm's numbers (``√(x·x)``) without its wrapper."""
    return math.sqrt(x.dot(x))
