"""Stall pull: a goal attractor added to PUMA's position rows once the hand stops making
progress (``method.forcing.stall_pull``; FPM and CPM only, never PUMA alone).

Why. Most runs of FPM and CPM that miss the goal end at a local minimum of the forced fabric, not
in unsafe motion: the arm rests (or circles slowly) short of the goal where PUMA's forcing, pulled
through the avoidance metric, is balanced by a barrier: joints held at their limit barriers where
PUMA's task-space field asks for motion past them, or the hand near the goal where an obstacle's
metric outweighs PUMA's weak pull. A forced fabric only promises convergence to *a* local minimum
of its forcing's potential plus the barriers (Ratliff et al. 2023, Prop. II.17-18); PUMA's field
is not a gradient in joint space, so these rest points are real and no change of gains removes
them. Law and ablation row: docs/method.md, "Ways out of
a local minimum"; its constants: "The fixed constants".

What. Two measures of progress are watched: the hand's distance to the goal d = ‖p_g − p‖ [m]
and PUMA's potential ψ (the latent distance to the goal, 0 there; sampled every
:data:`PSI_SAMPLE_S`). While either improves on its best so far within ``window`` [s] (d by
``progress`` [m], ψ by the fraction ``psi_progress``) nothing changes. Distance alone is not
PUMA's measure: a demonstrated motion may first move away from the goal while ψ falls, and a pull
armed there would cut across PUMA's path. Once neither has improved for ``window`` seconds, and
d > ``radius`` [m], the pull arms: PUMA's position acceleration becomes

    ẍ_p ← ẍ_p + a(t) · (k (p_g − p) − 2√k v),   k = g / max(d, ℓ)                  [m/s²]

with g = ``stall_pull`` [m/s²], a(t) ramping 0 → 1 over ``ramp`` [s] from the moment it armed,
ℓ = 0.1 m and v the hand's velocity relative to the goal's [m/s]: the negative gradient of
ψ_s = g·φ(d), φ(d) = d²/(2ℓ) for d ≤ ℓ and d − ℓ/2 beyond (convex, its only minimum the goal; a
goal attractor of the kind the Fabrics method forces with), with the damping that makes the
spring critically damped at its local stiffness k, pulled through the same metric as PUMA's own
rows. The damping only dissipates and vanishes at rest, so the rest set is the undamped one's; it
is there because near the goal the undamped attractor is a spring of k = g/ℓ = 15 s⁻² (a period
of 1.6 s), and where the goal lies just beyond what the ground barrier lets the hand reach, the
hand circles it at that period and never comes to rest.

A creep is no progress either (f = ``progress_fraction``, 0: off): the distance counts as
progress only when it falls by ``max(progress, f · d_best)``, so the pull arms once the remaining
distance would take longer than about ``window``/f to close at the current rate (40 s for
f = 0.05), while PUMA's own approach, which closes a fixed fraction of the distance per
second, counts as progress all the way in. CPM has it (0.05): where ψ climbs along the hand's
way its regulator lets the hand crawl at about √ε, a few millimetres a second, which a fixed
``progress`` per window counts as progress. FPM has it off.

It lets go on PUMA's own measure: once ψ has fallen below (1 − ``release``) times its value at
arming, and not while the configuration pull serves this arming
(:mod:`tamedpuma.methods._configuration_pull`: while it searches the route of the engagement the
arming asked for, over a few control steps, and while it acts, which ends on its own measures);
from then on it measures the fall from ψ where the configuration pull ended. Where the stall is a
local minimum of ψ on the barriers (the hand held against an obstacle, PUMA's field pointing
through it), ψ first rises as the pull takes the hand round, and the pull holds until the hand is
over the ridge, in the part of ψ's sublevel set that no longer drains into the stall point; let go
at the first millimetres of progress, PUMA's field returns the hand to the stall. Disarmed, the
watch starts afresh from the hand's current distance.

Near the goal (``hold_radius`` [m], 0: off) the distance is the only measure: ψ is the latent
distance of the whole pose, and there it is dominated by the orientation, falling as the wrist
turns while a barrier holds the hand centimetres short, so each fall would count as progress or
let the pull go. Within ``hold_radius`` only d ≤ best − ``progress`` is progress, and a pull armed
there never lets go: at the goal it vanishes (g·(p_g − p)/ℓ → 0), so the goal stays a rest point
and PUMA's zero set is kept, while a PUMA field still turning the hand cannot carry it back out
unopposed. The convex attractor's only minimum is the goal a few centimetres away, and no
demonstrated path is left there for it to cut across.

What holds. Safety does not depend on the forcing: the barriers' metric and geometry, the
energization bound and the control-rate barrier step are unchanged, so the pull cannot carry the
arm through a barrier the fabric holds (it can press harder where the barriers' coverage is
incomplete: a link mesh outside the body spheres). Away from stalls the forcing is PUMA's to the
bit, and so are FPM's statement (PUMA's zero set, once reached, kept) and CPM's. While armed the
forcing is PUMA's plus a convex attractor with the same goal, so the rest set of the forced system
no longer contains the stall point unless the barriers also hold the attractor there (then the arm
stays, safely). CPM's energy statement (dH/dt = −β q̇ᵀMq̇ above the speed √ε, H = ½‖q̇‖² + k_ψψ)
does not depend on the forcing, whose power along q̇ energization takes away: the pull steers CPM
rather than powering it. What is given up while armed: the hand's path is not PUMA's (the
imitation is suspended where it has stopped delivering the goal).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tamedpuma.methods._policy import TaskAcceleration

#: ℓ [m]: below this distance the attractor's strength falls linearly to 0 at the goal
PULL_LENGTH_M = 0.1
#: [s] PUMA's potential ψ is evaluated at most this often (ψ alone: one encoder pass at rest)
PSI_SAMPLE_S = 0.1


@dataclass(frozen=True)
class StallPull:
    """The stall pull: gain g [m/s²] (``method.forcing.stall_pull``; 0: off), and its fixed
    window [s], progress [m], progress_fraction [1] (CPM's creep criterion), psi_progress [1],
    radius [m], ramp [s], release [1] and hold_radius [m] (see the module)."""

    gain: float = 0.0
    window: float = 2.0
    progress: float = 0.005
    progress_fraction: float = 0.0
    psi_progress: float = 0.1
    radius: float = 0.045
    ramp: float = 1.0
    release: float = 0.05
    hold_radius: float = 0.15


class StallMonitor:
    """The per-episode state of one :class:`StallPull`: the best distance and potential so far
    and when each was last beaten, when the pull armed and ψ then."""

    def __init__(self, pull: StallPull):
        self.pull = pull
        self.best = self.best_psi = np.inf
        self.t_best = self.t_best_psi = self.t_psi = -np.inf
        self.psi = np.nan
        self.t_armed: float | None = None
        self.psi_armed = np.nan
        self.armed_near = False  # armed within hold_radius: see _released
        self.best_armed, self.t_best_armed = np.inf, -np.inf  # the least distance while armed
        self.held = False  # the configuration pull serves this arming: see hold
        self.distance = np.inf  # the hand's distance to the goal at the last call [m]

    @property
    def armed(self) -> bool:
        return self.t_armed is not None

    def stuck(self, t: float) -> bool:
        """Whether the armed pull has itself made no progress: the distance has not fallen by
        ``progress`` below its least value since the arming for ``window`` [s]."""
        return self.t_armed is not None and t - self.t_best_armed >= self.pull.window

    def hold(self, held: bool) -> None:
        """Whether the configuration pull serves this arming (searches its route or acts): the
        arming stands while it does, and once it ends the release is measured from ψ then."""
        if self.held and not held:
            self.psi_armed = self.psi
        self.held = held

    def _potential(self, t: float, potential: Callable[[], float]) -> float:
        if not t - self.t_psi < PSI_SAMPLE_S - 1e-9:  # (rounding of t)
            self.psi, self.t_psi = float(potential()), t
        return self.psi

    def _needed(self) -> float:
        """How much nearer [m] than its best so far the hand must come to count as progress:
        ``max(progress, f · best)``, f = ``progress_fraction`` (the first distance always
        counts)."""
        if not math.isfinite(self.best):
            return 0.0
        return max(self.pull.progress, self.pull.progress_fraction * self.best)

    def _released(self, psi: float) -> bool:
        """Whether an armed pull lets go at potential ψ: armed near the goal, never; while the
        configuration pull serves this arming (:meth:`hold`), not yet; otherwise once ψ is
        ``release`` below its value at arming (or at the configuration pull's end)."""
        return (not self.armed_near and not self.held
                and psi < (1.0 - self.pull.release) * self.psi_armed)

    def acceleration(self, t: float, position: np.ndarray, goal: np.ndarray,
                     potential: Callable[[], float],
                     velocity: Callable[[], np.ndarray] | None = None) -> np.ndarray | None:
        """The attractor's task acceleration [m/s²] at time t [s] (hand ``position`` and
        ``goal`` [m]; ``potential()``: PUMA's ψ there, called at most every
        :data:`PSI_SAMPLE_S`), or None while disarmed. Updates the monitor's state."""
        e = np.asarray(goal, dtype=float) - np.asarray(position, dtype=float)
        d = self.distance = math.sqrt(float(e.dot(e)))  # ‖e‖, as np.linalg.norm computes it
        p = self.pull
        psi = self._potential(t, potential)
        if self.t_armed is not None and self._released(psi):
            self.t_armed = None  # over the ridge: PUMA's again, watched afresh from here
            self.best, self.t_best, self.best_psi, self.t_best_psi = d, t, psi, t
        if self.t_armed is None:
            if d < self.best - self._needed():
                self.best, self.t_best = d, t
            if psi < (1.0 - p.psi_progress) * self.best_psi:
                self.best_psi, self.t_best_psi = psi, t
            near = d <= p.hold_radius  # near the goal only the distance counts as progress
            last = self.t_best if near else max(self.t_best, self.t_best_psi)
            if d > p.radius and t - last >= p.window:
                self.t_armed, self.psi_armed, self.armed_near = t, psi, near
                self.best_armed, self.t_best_armed = d, t
        if self.t_armed is None:
            return None
        if d < self.best_armed - p.progress:
            self.best_armed, self.t_best_armed = d, t
        a = 1.0 if p.ramp <= 0.0 else min(1.0, (t - self.t_armed) / p.ramp)
        k = p.gain / max(d, PULL_LENGTH_M)
        if velocity is None:
            return (a * k) * e
        return a * (k * e - 2.0 * np.sqrt(k) * np.asarray(velocity(), dtype=float))

    def applied(self, t: float, position: np.ndarray, goal: np.ndarray, task: TaskAcceleration,
                potential: Callable[[], float],
                velocity: Callable[[], np.ndarray] | None = None) -> TaskAcceleration:
        """``task`` with the attractor added to its position rows (the first three, or all of
        a planar task's)."""
        extra = self.acceleration(t, position, goal, potential, velocity)
        if extra is None:
            return task
        xdd = np.array(task.xdd, dtype=float)
        k = min(3, len(xdd))
        xdd[:k] += extra[:k]
        return TaskAcceleration(xdd, task.J, task.jdqd)
