"""Stall pull: a goal attractor added to PUMA's position rows once the hand stops making
progress (``method.forcing.stall_pull``; FPM and CPM only, never PUMA alone).

Why. In the logs of the random scenarios most FPM/CPM failures are local minima of the forced
fabric, not unsafe motion: the arm comes to rest (or circles slowly) short of the goal where PUMA's
forcing, pulled through the avoidance metric, is balanced by a barrier. Two classes were read in
the logs: joints held at their limit barriers where PUMA's field, a
task-space field pulled to the joints, asks for motion past them (random tomato ``anywhere`` 7014:
joints 3 and 5 on their lower limits from 16 s on); and near-goal stalls where a nearby
obstacle's metric eats PUMA's weak pull (random pouring 7028, 5.4 cm short). A forced fabric only
promises convergence to *a* local minimum of its forcing's potential plus the barriers (Ratliff
et al. 2023, Prop. II.17-18); PUMA's field is not a gradient in joint space, so these rest points
are real and no change of gains removes them (the circulation module's note).

What. Two measures of progress are watched: the hand's distance to the goal d = ‖p_g − p‖ [m]
and PUMA's potential ψ (the latent distance to the goal, 0 there; sampled every
:data:`PSI_SAMPLE_S`). While either improves on its best so far within ``window`` [s] (d by
``progress`` [m], ψ by the fraction ``psi_progress``) nothing changes. Distance alone is not
PUMA's measure: a demonstrated motion may first move away from the goal (the real-data tomato
model's default case goes 0.72 → 0.98 m in its first 4 s under impedance control, with ψ
falling throughout), and a pull armed there cut across PUMA's path and left the hand 0.27 m short.
Once neither has improved for ``window`` seconds, and d > ``radius`` [m], the pull arms: PUMA's
position acceleration becomes

    ẍ_p ← ẍ_p + a(t) · (k (p_g − p) − 2√k v),   k = g / max(d, ℓ)                  [m/s²]

with g = ``stall_pull`` [m/s²], a(t) ramping 0 → 1 over ``ramp`` [s] from the moment it armed,
ℓ = 0.1 m and v the hand's velocity relative to the goal's [m/s]: the negative gradient of
ψ_s = g·φ(d), φ(d) = d²/(2ℓ) for d ≤ ℓ and d − ℓ/2 beyond (convex, its only minimum the goal; a
goal attractor of the kind the Fabrics method forces with), with the damping that makes the
spring critically damped at its local stiffness k, pulled through the same metric as PUMA's own
rows. The damping only dissipates and vanishes at rest, so the rest set is the undamped one's.
Why: undamped, near the goal the attractor is a spring of k = g/ℓ = 15 s⁻² (a period of 1.6 s),
and where the goal lies a few millimetres beyond what the ground barrier lets the hand reach, the
hand circled it ±1 cm at that period for 20 s and never came to rest (random tomato ``anywhere``
2029, FPM); paired on random seeds 2015-2064 (FPM both tasks, CPM tomato; 300 scenarios)
converged 284 → 289 runs, 1 lost, 6 gained.

A creep is no progress either (``progress_fraction``, 0: off): the hand's distance counts as
progress only when it falls by ``max(progress, progress_fraction · d_best)``, a fraction of
what is left. In the logs of random tomato ``anywhere`` 2014 the arm slid along an obstacle
1.7-2.7 cm away with joints 1 and 4 on their limits, 0.33 → 0.27 m from the goal in 11 s (3-6
mm/s: 6-12 mm per window, above the 5 mm of ``progress``, a goal a minute or more away), and
the pull armed only at 23 s of the 40. With a fraction f the pull arms once the remaining
distance would take longer than about ``window``/f to close at the current rate (40 s for f =
0.05), while PUMA's own approach, which closes a fixed fraction of the distance per second,
counts as progress all the way in. Off for FPM: the circulation's way round an obstacle is a
creep too (Table-1 tomato 02, FPM: 0.57 → 0.53 m in 9 s, then round and in at 20 s), and a
pull armed there pulled the hand back into the obstacle's shadow and into two joint limits
CPM has ``progress_fraction`` 0.05: its regulator brakes
every climb of ψ, and where ψ climbs along the hand's way CPM crawls at about √ε, the hand
closing 2-6 mm/s (random pouring ``near_table1`` 81020: 0.42 → 0.34 m in 24 s), which 5 mm per
window counted as progress; armed, the configuration pull (CPM: ``always``) takes over far from
the goal (783 → 795 of 800 on four random seed sets, none lost).

When it lets go is PUMA's own measure: the pull disarms once PUMA's potential ψ (the latent
distance to the goal, 0 there) has fallen below (1 − ``release``) times its value when the pull
armed. Where the stall is a local minimum of ψ on the barriers (the hand held against an
obstacle, PUMA's field pointing through it), ψ first rises as the pull takes the hand round, and
the pull holds until the hand is over the ridge, in the part of ψ's sublevel set that no longer
drains into the stall point; letting go at the first few millimetres of progress instead handed
the hand back to PUMA's field, which returned it to the stall (the point-robot test). Disarmed,
the watch starts afresh from the hand's current distance.

Near the goal (``hold_radius`` [m], 0: off) the hand's distance is the only measure. ψ is the
latent distance of the whole pose, and within a few centimetres of the goal it is dominated by
the orientation: in the logs of random tomato scenarios it fell 0.28 → 0.17 in 15 s as the
orientation converged while joint 2's limit and the ground barrier held the hand 6.5-8.8 cm
short (``near_table1`` 2047, CPM), and it swung 0.18 ↔ 0.54 as the wrist turned while the hand
crept 8 → 7 cm in 20 s (``anywhere`` 2065, FPM): each fall counted as progress or let the pull
go again. Within ``hold_radius`` therefore only d ≤ best − ``progress`` is progress, and a pull
armed there is let go only once the hand is inside ``radius``, not on ψ: there the convex
attractor's only minimum is the goal a few centimetres away, and there is no demonstrated path
left for it to cut across. A pull armed there is never let go: at the goal it
vanishes (g·(p_g − p)/ℓ → 0), so the goal stays a rest point of the forced system and PUMA's
zero set is kept, while a PUMA field that still orients the hand can no longer carry it back out
unopposed (let go at the radius, it did: the default tomato FPM run, 3 → 10 cm).

What holds. Safety never depended on the forcing: the barriers' metric and geometry, the
energization bound and the control-rate barrier step are unchanged, so the pull cannot carry the
arm through a barrier the fabric holds (what it can do is press harder where the barriers'
coverage is incomplete: a link mesh outside the body spheres). Away from stalls (every run that
keeps approaching the goal) the forcing is PUMA's to the bit, and so are FPM's statement (PUMA's
zero set, once reached, kept) and CPM's. While armed the forcing is PUMA's plus a convex
attractor with the same goal, so the rest set of the forced system (where the sum vanishes in
the metric) no longer contains the stall point unless the barriers also hold the attractor there
(then the arm stays, safely). CPM's energy statement (dH/dt = −β q̇ᵀMq̇ above the speed √ε, H =
½‖q̇‖² + k_ψψ) does not depend on the forcing, whose power along q̇ energization takes away: the
pull steers CPM rather than powering it, and CPM climbs ψ only as far as below √ε (where its law
is PUMA's start from rest) and its energy tank let it, as without the pull. What is given up
while armed: the hand's path is not PUMA's (the imitation is suspended exactly where it had
stopped delivering the goal).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tamedpuma.methods._policy import TaskAcceleration

#: ℓ [m]: below this distance the attractor's strength falls linearly to 0 at the goal
PULL_LENGTH_M = 0.1
#: [s] PUMA's potential is evaluated at most this often (a network pass with its gradient)
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
        self.distance = np.inf  # the hand's distance to the goal at the last call [m]

    @property
    def armed(self) -> bool:
        return self.t_armed is not None

    def _potential(self, t: float, potential: Callable[[], float]) -> float:
        if not t - self.t_psi < PSI_SAMPLE_S - 1e-9:  # (rounding of t)
            self.psi, self.t_psi = float(potential()), t
        return self.psi

    def _needed(self) -> float:
        """How much nearer [m] than its best so far the hand must come to count as progress:
        ``max(progress, f · best)``, f = ``progress_fraction`` (the first distance always
        counts)."""
        if not np.isfinite(self.best):
            return 0.0
        return max(self.pull.progress, self.pull.progress_fraction * self.best)

    def _released(self, psi: float) -> bool:
        """Whether an armed pull lets go at potential ψ: armed near the goal, never; armed
        elsewhere, once ψ is ``release`` below its value at arming."""
        return not self.armed_near and psi < (1.0 - self.pull.release) * self.psi_armed

    def acceleration(self, t: float, position: np.ndarray, goal: np.ndarray,
                     potential: Callable[[], float],
                     velocity: Callable[[], np.ndarray] | None = None) -> np.ndarray | None:
        """The attractor's task acceleration [m/s²] at time t [s] (hand ``position`` and
        ``goal`` [m]; ``potential()``: PUMA's ψ there, called at most every
        :data:`PSI_SAMPLE_S`), or None while disarmed. Updates the monitor's state."""
        e = np.asarray(goal, dtype=float) - np.asarray(position, dtype=float)
        d = self.distance = float(np.linalg.norm(e))
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
        if self.t_armed is None:
            return None
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
