"""Configuration pull: when the stall pull arms, a joint-space attractor to a goal configuration
takes the forcing over (``method.forcing.configuration_pull``: true, FPM's and CPM's default, or
false).

Why. A task-space attractor cannot leave a rest point made by the joint limits: where PUMA's
field, pulled to the joints, has turned a joint into its limit (a goal behind the base, the base
turned the short way round), the way out leads the hand away from the goal first, which neither
PUMA nor the stall pull (:mod:`tamedpuma.methods._stall`) asks for. The joint-limit box is convex,
so an attractor in joint space has no rest point made by the limits. Law and ablation row:
docs/method.md, "Ways out of a local minimum"; its constants: "The fixed constants".

What. Once the stall pull arms with the hand farther than ``release`` [m] from the goal, a route to
a goal configuration q_g is chosen (:func:`goal_route`): the goal pose's IK solution nearest to q
that is inside the limits by ``margin`` [rad], ``clearance`` [m] clear of the obstacles where they
are now, above the ground as the barrier step keeps it (:class:`Ground`), and reached along a clear
straight segment or, where none is clear, through one waypoint (the shortest of ``waypoints`` draws;
the pull turns to q_g within :data:`VIA_RADIUS` of it); no route, no change. PUMA's task rows are
replaced by the joint-space spec

    q̈_q = g (q_g − q) / max(‖q_g − q‖, ℓ) − k q̇,    k = 2√(g/ℓ)                 [rad/s²]

(g = ``gain`` [rad/s²], ℓ = ``length`` [rad]: critically damped near q_g, beyond ℓ a constant
pull cruising at g/k = √(gℓ)/2 = 1 rad/s, so the radians a reconfiguration needs take seconds),
pulled through the same avoidance metric with the task weight w on each joint row. It engages at
most once per arming (a search the hand overtakes, coming within ``near_release`` before the
search ends, serves none: the hand may leave the ball again, stalled, with the stall pull still
armed), chooses q_g again when the goal moves :data:`REPLAN_DISTANCE_M`, and lets go
within ``near_release`` of the goal, where the arm is nearly at rest and PUMA (the stall pull still
armed) finishes; handed over while still cruising, the hand overshoots. It also lets go once
‖q − q_g‖ has not fallen by ``progress`` [rad] for ``window`` [s] (a barrier holds it). These are
its only ends: PUMA's ψ, the stall pull's measure of being over the ridge, does not end it (a
reconfiguration may first lower ψ by a few per cent as the wrist turns, long before the arm is
out of the stall's basin), so the stall pull's arming stands while the pull acts.

Near the goal, too, a stall at a joint limit is left only by a reconfiguration (the elbow turned
over, the hand first moving away): with ``near_release`` > 0 the pull engages within ``release`` as
well, with a joint at a limit (or the goal pose blocked, below) and the hand farther than
``near_release``, but only at the step the stall pull arms in (a joint reaching its band later,
the hand still coming in, is no stall).
Farther than ``release`` no limit is asked for: CPM's regulator brakes every climb of ψ, so where
the way round climbs ψ away from obstacles and limits CPM crawls at about √ε with no joint at a
limit, and FPM converges in more scenarios of the randomized suite with every arming served than
with only those at a limit (docs/method.md).

A goal low over the table may put a link below the plane the barrier step keeps; q_g is then
solved with the target raised by the deficit (at most ``release``), and PUMA's approach does the
rest. The ground check is the controller's own (its link hulls): body spheres kept 1 cm above
z = 0 would reject the hand's sphere (7 cm round the task point) at every goal lower than 8 cm.

A blocked goal pose. Where every solution of the goal pose puts a body sphere inside an obstacle
(``clearance`` short of it: the prepared solutions,
and, before the pull engages for it, the pose solved from the arm's own configuration, which a
sample of the self-motion may miss), no controller that keeps the body clear can rest at the
pose; PUMA's rows, which ask for the pose, hold the hand short of the goal, centimetres away.
Once the stall pull, armed there (within ``release``), has itself stopped bringing the hand
nearer (:meth:`~tamedpuma.methods._stall.StallMonitor.stuck`; no joint at a limit needed), the
pull targets the goal position alone, solved from the arm's own configuration (the least
reconfiguration; else the nearest clear one of the prepared solutions of the position), and
holds there instead of handing the arm back to PUMA, which would carry it into the obstacle
again; every ``window`` it checks the pose again and, once an obstacle has moved off it, turns
to a solution of the pose and hands back as above. The rest point is then the goal position with
the orientation the obstacles leave, not PUMA's zero set: the paper's success (the position) is
kept, the goal orientation given up where no clear configuration holds it. Farther than
``release`` the arming's search is for the pose (What, above); where it engages not (no clear
route: the pose blocked) or its engagement lets go out there, and the stall pull armed there is
then stuck too, the pull searches once more as near the goal, once per arming: a blocked pose
also holds the hand 20-30 cm out where an obstacle sits beside the goal. Never at the arming
itself: there the prepared solutions (a sample of the self-motion) missed clear configurations
that the arm, left to PUMA and the stall pull, went on to reach with the goal orientation
(docs/method.md).

When it is computed. The goal pose's IK solutions depend on neither the obstacles nor q: the
controller's reset solves them from q₀ and ``restarts`` seeded starts
(:meth:`ConfigurationMonitor.prepare`). An engagement searches only the route among them, at most
``budget`` kinematic passes (:data:`SEARCH_BUDGET`) per control step, and engages when the search
ends (a moved goal likewise, the last q_g pulling meanwhile). The stall pull's arming stands
while the search runs too (``StallMonitor.hold``, :mod:`tamedpuma.methods._stall`): the search is
the engagement's answer spread over steps, which the stall pull's own approach meanwhile,
letting go once ψ falls by its ``release``, would otherwise drop. The price: the IK starts from
q₀, not the q at engagement, and a long search engages some steps late. The goal position's own
solutions are solved only inside the search that finds the pose blocked (from q, and the seeded
starts where that one is not clear).

What holds. The barriers, the energization bound and the barrier step are unchanged: the pull cannot
carry the arm through an obstacle or a limit. Away from these stalls the forcing is PUMA's, so FPM's
statement holds; q_g puts the hand at the goal pose, so the attractor's rest point lies in PUMA's
zero set; while it acts the path is not PUMA's. CPM's regulator watches the attractor's own
potential φ meanwhile (:meth:`ConfigurationMonitor.potential`; on ψ it would brake the climb the way
out needs): −∂φ/∂q is the pull, so ``dH_φ/dt ≤ −β‖q̇‖²`` with ``H_φ = ½‖q̇‖² + φ`` while engaged.
CPM's convergence argument holds on each interval on one potential and, after the last engagement,
on ψ's; it needs finitely many engagements (each needs a new arming of the stall pull).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tamedpuma.methods._policy import TaskAcceleration
from tamedpuma.robot.ground import LinkHulls, hull_heights, hull_heights_and_spheres
from tamedpuma.robot.ik import pose_dls_steps, run_to_end
from tamedpuma.robot.kinematics import Kinematics
from tamedpuma.robot.rotations import quat_to_matrix

#: [m] the goal may move this far before q_g is chosen again
REPLAN_DISTANCE_M = 0.02
#: [m] a goal configuration below the ground is solved again with its target raised by its
#: deficit plus this, at most RAISE_ATTEMPTS times
RAISE_SLACK_M = 0.002
RAISE_ATTEMPTS = 3
#: [m] how far below the ground plane (or below q's own margin) the segment to q_g may dip: the
#: barrier step's rounding, not a real dip
GROUND_SLACK_M = 0.001
#: the goal configurations (nearest first) a two-segment route is searched for
ROUTE_GOALS = 3
#: [rad] the pull turns from a waypoint to the next target once this near it
VIA_RADIUS = 0.3
#: [s] near the goal the pull engages only at the control step the stall pull arms in (its
#: t_armed is that step's t; this absorbs nothing but rounding)
ARMING_TOLERANCE_S = 1e-9
#: kinematic passes (one forward pass of the arm each, 0.05-0.3 ms) the goal-configuration
#: search may spend in one control step
SEARCH_BUDGET = 16
#: goal poses whose IK solutions a process keeps (:meth:`ConfigurationMonitor.prepare`)
PREPARED_KEPT = 64
_PREPARED: dict = {}


@dataclass(frozen=True)
class ConfigurationPull:
    """The configuration pull: gain g [rad/s²], length ℓ [rad], limit_band [rad] (a joint this
    near a limit is at it), release [m] (farther than it every arming engages the pull),
    margin [rad] (q_g's distance from the limits), near_release [m]
    (every engagement lets go within it; an arming within ``release`` engages too, farther
    than it; 0: the pull never engages within ``release`` and lets go at it),
    clearance [m] (q_g's body spheres from the obstacles), restarts (random IK starts besides
    q), waypoints (per goal configuration, for a two-segment route where no
    straight one is clear; 0: straight only), window [s] and progress [rad] (let go when
    ‖q − q_g‖ has not fallen by ``progress`` for ``window``), budget (the kinematic passes
    its search may spend per control step; 0: no bound, the whole search in one step)."""

    gain: float = 4.0
    length: float = 1.0
    limit_band: float = 0.1
    release: float = 0.15
    near_release: float = 0.03
    margin: float = 0.1
    clearance: float = 0.01
    restarts: int = 24
    waypoints: int = 32
    window: float = 2.0
    progress: float = 0.05
    budget: int = SEARCH_BUDGET


@dataclass(frozen=True)
class Ground:
    """The ground as the controller's barrier step keeps it: the heights of ``hulls`` (each
    moving link's lowest hull point, :mod:`tamedpuma.robot.ground`; None: the body spheres'
    bottoms c_z − r) at least ``height`` [m] above z = 0."""

    height: float
    hulls: LinkHulls | None = None

    def margins(self, kin: Kinematics, q: np.ndarray) -> np.ndarray:
        """The heights minus ``height`` [m] at q: all ≥ 0 where the ground rows hold."""
        if self.hulls is not None:
            return hull_heights(kin, self.hulls, q) - self.height
        return kin.sphere_centers(q)[:, 2] - np.asarray(kin.sphere_radii) - self.height

    def margins_and_spheres(self, kin: Kinematics, q: np.ndarray):
        """:meth:`margins` and the body-sphere centres (k, 3) [m] at q, one placement pass."""
        if self.hulls is not None:
            heights, spheres = hull_heights_and_spheres(kin, self.hulls, q)
            return heights - self.height, spheres
        spheres = kin.sphere_centers(q)
        return spheres[:, 2] - np.asarray(kin.sphere_radii) - self.height, spheres


def _pose_above_ground(kin: Kinematics, position: np.ndarray, rotation: np.ndarray,
                       start: np.ndarray, lo: np.ndarray, hi: np.ndarray, ground: Ground,
                       max_raise: float, rotation_weight: float = 1.0):
    """An IK solution of the pose (position [m], rotation) from ``start`` inside [lo, hi] whose
    ground margins are ≥ 0; where the solution dips below the plane by δ, the target is raised
    by δ + :data:`RAISE_SLACK_M` and solved again from it (at most :data:`RAISE_ATTEMPTS`
    times, by at most ``max_raise`` [m] in all); None when that fails. ``rotation_weight``: the
    orientation rows' weight in the IK (0: the position alone). A generator yielding before
    each kinematic pass (:func:`~tamedpuma.robot.ik.pose_dls_steps`), returning the solution."""
    target = np.array(position, dtype=float)
    for _ in range(RAISE_ATTEMPTS + 1):
        q, err, _ = yield from pose_dls_steps(kin, target, rotation, start, lo, hi,
                                              damping=0.05, tolerance=1e-4,
                                              max_iterations=200, patience=20,
                                              rotation_weight=rotation_weight)
        if np.linalg.norm(err) > 1e-3:
            return None
        yield
        deficit = -float(np.min(ground.margins(kin, q)))
        if deficit <= 0.0:
            return q
        target[2] += deficit + RAISE_SLACK_M
        if target[2] - position[2] > max_raise:
            return None
        start = q
    return None


@dataclass(frozen=True)
class PoseSolutions:
    """The IK solutions of one goal pose (position [m], quaternion (x, y, z, w)) inside the
    limits by the pull's margin and above the ground, in the order of their starts, before any
    obstacle is looked at: ``pose`` (the full pose) and ``position`` (the position alone, the
    orientation free: where the pose is blocked)."""

    position_m: np.ndarray
    quaternion: np.ndarray
    pose: tuple[np.ndarray, ...]
    position: tuple[np.ndarray, ...]

    def serves(self, position: np.ndarray, quaternion: np.ndarray) -> bool:
        """Whether these are the solutions for that goal: within :data:`REPLAN_DISTANCE_M`, the
        same orientation."""
        return (float(np.linalg.norm(np.asarray(position) - self.position_m))
                <= REPLAN_DISTANCE_M and np.array_equal(np.asarray(quaternion, dtype=float),
                                                        self.quaternion))


def _limits(kin: Kinematics, pull: ConfigurationPull) -> tuple[np.ndarray, np.ndarray]:
    spec = kin.spec
    return (np.asarray(spec.q_min, dtype=float) + pull.margin,
            np.asarray(spec.q_max, dtype=float) - pull.margin)


def pose_solutions(kin: Kinematics, position: np.ndarray, quaternion: np.ndarray,
                   q: np.ndarray, pull: ConfigurationPull, seed: int = 0,
                   ground: Ground | None = None, weights: tuple[float, ...] = (1.0, 0.0)):
    """The :class:`PoseSolutions` of the goal pose from q and from ``pull.restarts`` seeded
    random starts (the raised pose where it reaches below the ground, see
    :func:`goal_candidates`); weights: the orientation rows' weights solved for (1: the pose,
    0: the position alone). A generator yielding before each kinematic pass (run it with
    :func:`~tamedpuma.robot.ik.run_to_end`, or a step budget at a time)."""
    ground = ground or Ground(pull.clearance)
    lo, hi = _limits(kin, pull)
    goal_rot = quat_to_matrix(np.asarray(quaternion, dtype=float))
    position = np.asarray(position, dtype=float)
    rng = np.random.default_rng(seed)
    starts = [np.clip(np.asarray(q, dtype=float), lo, hi)]
    starts += [rng.uniform(lo, hi) for _ in range(pull.restarts)]
    found: dict[float, list[np.ndarray]] = {}
    for rotation_weight in weights:
        found[rotation_weight] = []
        for start in starts:
            qg = yield from _pose_above_ground(kin, position, goal_rot, start, lo, hi, ground,
                                               pull.release, rotation_weight)
            if qg is not None:
                found[rotation_weight].append(qg)
    return PoseSolutions(position.copy(), np.asarray(quaternion, dtype=float).copy(),
                         tuple(found.get(1.0, ())), tuple(found.get(0.0, ())))


def _clear_of_obstacles(kin: Kinematics, solutions: PoseSolutions, q: np.ndarray,
                        centers: np.ndarray, radii: np.ndarray, pull: ConfigurationPull,
                        position: bool = True):
    """The solutions ``pull.clearance`` clear of the obstacles, nearest to q first: the full
    pose's, or where none is clear (and ``position``), the position's. A generator yielding
    before each kinematic pass."""
    found = []
    for group in (solutions.pose, solutions.position) if position else (solutions.pose,):
        for qg in group:
            yield
            if _obstacle_gap(kin, qg, centers, radii) >= pull.clearance:
                found.append(qg)
        if found:
            break
    return sorted(found, key=lambda qg: float(np.linalg.norm(qg - q)))


def goal_candidates(kin: Kinematics, position: np.ndarray, quaternion: np.ndarray,
                    q: np.ndarray, obstacle_centers: np.ndarray, obstacle_radii: np.ndarray,
                    pull: ConfigurationPull, seed: int = 0,
                    ground: Ground | None = None) -> list[np.ndarray]:
    """The goal configurations [rad], nearest to q first (Euclidean in the joints), among IK
    solutions of the goal pose (position [m], quaternion (x, y, z, w)) started from q and from
    ``pull.restarts`` seeded random configurations: inside the limits by ``pull.margin``, the
    pose within 1 mm / 0.01 rad, every body sphere ``pull.clearance`` clear of every obstacle
    and above the ``ground`` (the controller's ground rows; None: the body spheres
    ``pull.clearance`` above z = 0). Where the goal pose itself reaches below the ground (a
    goal low over the table: the controller cannot put the hand there either), the pose raised
    until it is above, by at most ``pull.release``.
    Where no solution of the pose is clear: the solutions of the goal position alone (see the
    module). Deterministic for a seed."""
    solutions = run_to_end(pose_solutions(kin, position, quaternion, q, pull, seed, ground))
    centers = np.asarray(obstacle_centers, dtype=float).reshape(-1, 3)
    radii = np.asarray(obstacle_radii, dtype=float).reshape(-1)
    return run_to_end(_clear_of_obstacles(kin, solutions, np.asarray(q, dtype=float), centers,
                                          radii, pull))


def goal_configuration(kin: Kinematics, position: np.ndarray, quaternion: np.ndarray,
                       q: np.ndarray, obstacle_centers: np.ndarray, obstacle_radii: np.ndarray,
                       pull: ConfigurationPull, seed: int = 0,
                       ground: Ground | None = None) -> np.ndarray | None:
    """The nearest of :func:`goal_candidates` whose straight segment from q is clear of the
    obstacles and the ground (:func:`_segment_clear`); None when there is none."""
    route = goal_route(kin, position, quaternion, q, obstacle_centers, obstacle_radii,
                       replace(pull, waypoints=0), seed, ground)
    return None if route is None else route[-1]


def goal_route(kin: Kinematics, position: np.ndarray, quaternion: np.ndarray, q: np.ndarray,
               obstacle_centers: np.ndarray, obstacle_radii: np.ndarray,
               pull: ConfigurationPull, seed: int = 0,
               ground: Ground | None = None) -> tuple[np.ndarray, ...] | None:
    """The targets the pull visits in turn: (q_g,), the nearest goal configuration with a clear
    straight segment from q; where there is none, (w, q_g): the shortest two-segment route
    q → w → q_g with both segments clear, over ``pull.waypoints`` seeded waypoints per goal
    configuration (the nearest :data:`ROUTE_GOALS` of them) drawn about the segment's middle,
    ``w = q + s (q_g − q) + ‖q_g − q‖ u/√n``, s ~ U(0.25, 0.75), u ~ N(0, I), inside the
    limits by ``pull.margin`` and ``pull.clearance`` clear. None when neither exists.
    Deterministic for a seed."""
    solutions = run_to_end(pose_solutions(kin, position, quaternion, q, pull, seed, ground))
    return run_to_end(route_steps(kin, solutions, q, obstacle_centers, obstacle_radii, pull,
                                  seed, ground))


def route_steps(kin: Kinematics, solutions: PoseSolutions, q: np.ndarray,
                obstacle_centers: np.ndarray, obstacle_radii: np.ndarray,
                pull: ConfigurationPull, seed: int = 0, ground: Ground | None = None,
                position: bool = True):
    """:func:`goal_route` from the goal pose's ``solutions`` (:func:`pose_solutions`), with
    the obstacles where they are now (``position``: the goal position's solutions where no
    solution of the pose is clear): a generator yielding before each kinematic pass,
    returning the route (or None)."""
    ground = ground or Ground(pull.clearance)
    centers = np.asarray(obstacle_centers, dtype=float).reshape(-1, 3)
    radii = np.asarray(obstacle_radii, dtype=float).reshape(-1)
    q = np.asarray(q, dtype=float)
    goals = yield from _clear_of_obstacles(kin, solutions, q, centers, radii, pull, position)
    yield
    floor = min(0.0, float(np.min(ground.margins(kin, q)))) - GROUND_SLACK_M
    for qg in goals:
        if (yield from _segment_clear(kin, q, qg, centers, radii, ground, floor)):
            return (qg,)
    if pull.waypoints <= 0:
        return None
    lo, hi = _limits(kin, pull)
    rng = np.random.default_rng(seed + 1)
    best, best_length = None, np.inf
    for qg in goals[:ROUTE_GOALS]:
        span = float(np.linalg.norm(qg - q))
        for _ in range(pull.waypoints):
            w = np.clip(q + rng.uniform(0.25, 0.75) * (qg - q)
                        + span * rng.standard_normal(len(q)) / np.sqrt(len(q)), lo, hi)
            length = float(np.linalg.norm(w - q) + np.linalg.norm(qg - w))
            if length >= best_length:
                continue
            yield
            margins, spheres = ground.margins_and_spheres(kin, w)
            if (np.min(margins) >= 0.0 and _gap(kin, spheres, centers, radii) >= pull.clearance
                    and (yield from _segment_clear(kin, q, w, centers, radii, ground, floor))
                    and (yield from _segment_clear(kin, w, qg, centers, radii, ground,
                                                   floor))):
                best, best_length = (w, qg), length
    return best


def _obstacle_gap(kin: Kinematics, q: np.ndarray, centers: np.ndarray,
                  radii: np.ndarray) -> float:
    """The least clearance [m] between a body sphere at q and an obstacle (centres (m, 3),
    radii (m,) [m]; inf: none)."""
    if not len(radii):
        return np.inf
    return _gap(kin, kin.sphere_centers(q), centers, radii)


def _gap(kin: Kinematics, spheres: np.ndarray, centers: np.ndarray,
         radii: np.ndarray) -> float:
    """:func:`_obstacle_gap` from the body-sphere centres (k, 3) [m]."""
    if not len(radii):
        return np.inf
    return float(np.min(np.linalg.norm(spheres[:, None, :] - centers[None], axis=2)
                        - kin.sphere_radii[:, None] - radii[None]))


def _segment_clear(kin: Kinematics, q: np.ndarray, qg: np.ndarray, centers: np.ndarray,
                   radii: np.ndarray, ground: Ground, floor: float, step: float = 0.05):
    """Whether the straight joint-space segment q → q_g keeps every body sphere out of every
    (current) obstacle and the ground margins above ``floor`` [m] (0, or q's own where the
    barrier step lets it sit a little below): sampled every ``step`` [rad] of the largest
    joint's travel. A generator yielding before each sample, returning the answer."""
    n = int(np.ceil(np.abs(qg - q).max() / step)) + 1
    for s in np.linspace(0.0, 1.0, n + 1)[1:]:
        yield
        margins, spheres = ground.margins_and_spheres(kin, q + s * (qg - q))
        if np.min(margins) < floor or _gap(kin, spheres, centers, radii) < 0.0:
            return False
    return True


class ConfigurationMonitor:
    """The per-episode state of one :class:`ConfigurationPull`: the goal pose's IK solutions
    (solved before the first step, :meth:`prepare`), q_g, the goal it was chosen for, which
    arming of the stall pull it serves, and the search under way (at most ``pull.budget``
    kinematic passes per control step, see the module)."""

    def __init__(self, pull: ConfigurationPull, spec, ground: Ground | None = None):
        self.pull, self.ground = pull, ground  # ground: the controller's (None: spheres)
        self.kin = Kinematics(spec)  # its own pinocchio data: the controller's pass is kept
        self.q_min = np.asarray(spec.q_min, dtype=float)
        self.q_max = np.asarray(spec.q_max, dtype=float)
        self.q_goal: np.ndarray | None = None  # the current target: a waypoint, then q_g
        self.route: tuple[np.ndarray, ...] = ()  # the targets after it
        self.goal_for = np.full(3, np.nan)
        self.served: float | None = None  # t_armed of the stall pull last engaged for
        self.served_blocked: float | None = None  # ... and searched again for a blocked pose
        self.served_before: float | None = None  # ``served`` before the search under way
        self.engaged = False
        self.release_at = pull.release  # [m] this engagement lets go within it
        self.holding = False  # q_g holds the goal position alone (the pose is blocked)
        self.t_checked = -np.inf  # when the blocked pose was last checked while holding [s]
        self.best = np.inf  # the least ‖q − q_g‖ while engaged [rad], and when it was reached
        self.t_best = -np.inf
        self.solutions: PoseSolutions | None = None  # the goal pose's IK solutions
        self.search = None  # the search under way: a generator of route_steps' kind
        self.search_goal = np.full(3, np.nan)  # the goal it searches for
        self.passes = 0  # kinematic passes of the searches so far (all steps)

    def prepare(self, position: np.ndarray, quaternion: np.ndarray, q0: np.ndarray) -> None:
        """Solve the goal pose (position [m], quaternion (x, y, z, w)) from q0 and the seeded
        random starts, before the first control step (the scenario's goal is known then): an
        engagement then searches only the route among these solutions. The solutions do not
        depend on the obstacles: the runs of one scenario (every method, with and without its
        obstacles) in one process share them (:data:`_PREPARED`, the same numbers)."""
        ground = self.ground or Ground(self.pull.clearance)
        key = (repr(self.kin.spec), np.asarray(position, dtype=float).tobytes(),
               np.asarray(quaternion, dtype=float).tobytes(),
               np.asarray(q0, dtype=float).tobytes(), self.pull.margin, self.pull.release,
               self.pull.restarts, ground.height,
               None if ground.hulls is None else ground.hulls.links)
        if key not in _PREPARED:
            if len(_PREPARED) >= PREPARED_KEPT:
                _PREPARED.pop(next(iter(_PREPARED)))
            _PREPARED[key] = run_to_end(pose_solutions(self.kin, position, quaternion, q0,
                                                       self.pull, ground=self.ground,
                                                       weights=(1.0,)))
        self.solutions = _PREPARED[key]

    def at_limit(self, q: np.ndarray) -> bool:
        """A joint within ``limit_band`` [rad] of a limit."""
        band = self.pull.limit_band
        return bool(np.any(q - self.q_min < band) or np.any(self.q_max - q < band))

    def applied(self, q: np.ndarray, qd: np.ndarray, distance: float, stall, obs,
                task: TaskAcceleration) -> TaskAcceleration:
        """``task``, or the joint-space spec (J = I) while the pull is engaged (see the
        module). distance: the hand's distance to the goal [m]; stall: the
        :class:`~tamedpuma.methods._stall.StallMonitor` (its ``t_armed``; its arming is held while
        this pull searches or acts)."""
        p = self.pull
        if self.engaged and (distance <= self.release_at or self._stuck(q, obs.t)):
            self.engaged, self.search = False, None
        if not self.engaged and self.search is not None and distance <= self.release_at:
            # the engagement searched for is over before it began: the arming is not served
            # (a hand that leaves the ball again, stalled, gets its engagement)
            self.search, self.served = None, self.served_before
        if not self.engaged and self.search is None and self._engages(q, distance, stall, obs):
            again = stall.t_armed == self.served  # far out, this arming's second search
            self.served_before, self.served = self.served, stall.t_armed
            if again:
                self.served_blocked = stall.t_armed
            self.release_at = p.near_release if p.near_release > 0.0 else p.release
            self._start(q, obs, position_alone=again or distance <= p.release)
        if self.engaged and self.search is None and np.linalg.norm(
                np.asarray(obs.goal_position) - self.goal_for) > REPLAN_DISTANCE_M:
            self._start(q, obs, self.holding)  # the goal moved: the last q_g serves meanwhile
        if (self.engaged and self.holding and self.search is None
                and obs.t - self.t_checked >= p.window):
            self.t_checked = obs.t  # has the pose come clear (an obstacle moved)? then to it
            self.search_goal = np.array(obs.goal_position, dtype=float)
            self.search = self._recheck(np.array(q, dtype=float),
                                        np.array(obs.obstacle_centers, dtype=float),
                                        np.array(obs.obstacle_radii, dtype=float))
        if self.search is not None:
            self._advance(obs.t)
        stall.hold(self.search is not None or self.engaged)  # the arming stands meanwhile
        if not self.engaged:
            return task
        if self.route and np.linalg.norm(self.q_goal - q) < VIA_RADIUS:
            self.q_goal, self.route = self.route[0], self.route[1:]
            self.best, self.t_best = np.inf, obs.t
        e = self.q_goal - q
        n = len(q)
        acc = p.gain * e / max(float(np.linalg.norm(e)), p.length) \
            - 2.0 * np.sqrt(p.gain / p.length) * qd
        return TaskAcceleration(acc, np.eye(n), np.zeros(n))

    def _start(self, q: np.ndarray, obs, position_alone: bool) -> None:
        """Begin the search for a route from q to the goal of ``obs`` (its obstacles where they
        are now; ``position_alone``: to the goal position alone where the pose is blocked); the goal
        pose is solved again first where :meth:`prepare` solved another."""
        self.search_goal = np.array(obs.goal_position, dtype=float)
        self.search = self._search(np.array(q, dtype=float), self.search_goal,
                                   np.array(obs.goal_quaternion, dtype=float),
                                   np.array(obs.obstacle_centers, dtype=float),
                                   np.array(obs.obstacle_radii, dtype=float), position_alone)

    def _search(self, q, position, quaternion, centers, radii, position_alone):
        if self.solutions is None or not self.solutions.serves(position, quaternion):
            self.solutions = yield from pose_solutions(self.kin, position, quaternion, q,
                                                       self.pull, ground=self.ground,
                                                       weights=(1.0,))
        if not position_alone:
            return (yield from route_steps(self.kin, self.solutions, q, centers, radii,
                                           self.pull, ground=self.ground, position=False))
        lo, hi = _limits(self.kin, self.pull)
        ground = self.ground or Ground(self.pull.clearance)
        rotation = quat_to_matrix(quaternion)
        if not self.at_limit(q):
            # engaged for a stalled stall pull: only where the pose is blocked. A clear prepared
            # solution, or the pose solved from q itself (the prepared ones are a sample), and
            # PUMA keeps the arm
            if (yield from _clear_of_obstacles(self.kin, self.solutions, q, centers, radii,
                                               self.pull, position=False)):
                return None
            own = yield from _pose_above_ground(self.kin, position, rotation, np.clip(q, lo, hi),
                                                lo, hi, ground, self.pull.release)
            if own is not None and (_obstacle_gap(self.kin, own, centers, radii)
                                    >= self.pull.clearance):
                return None
        else:  # a joint at a limit: the pose's own solutions first, as farther out
            route = yield from route_steps(self.kin, self.solutions, q, centers, radii,
                                           self.pull, ground=self.ground, position=False)
            if route is not None:
                return route
        # the goal position alone, solved from q: the least reconfiguration; where that is not
        # clear, from the seeded starts (solved only now: a blocked pose is rare)
        near = yield from _pose_above_ground(self.kin, position, rotation, np.clip(q, lo, hi),
                                             lo, hi, ground, self.pull.release,
                                             rotation_weight=0.0)
        if near is not None and (_obstacle_gap(self.kin, near, centers, radii)
                                 >= self.pull.clearance):
            alone = (near,)
        else:
            alone = (yield from pose_solutions(self.kin, position, quaternion, q, self.pull,
                                               ground=self.ground, weights=(0.0,))).position
        self.solutions = replace(self.solutions, position=alone)
        # the position's solutions alone: the pose's have just been found blocked (or, at a
        # limit, without a clear route)
        return (yield from route_steps(self.kin, replace(self.solutions, pose=()), q, centers,
                                       radii, self.pull, ground=self.ground, position=True))

    def _recheck(self, q, centers, radii):
        """While holding the goal position: the route to a clear solution of the pose where
        one has come clear, else the current targets (a generator of :meth:`_search`'s kind)."""
        if not (yield from _clear_of_obstacles(self.kin, self.solutions, q, centers, radii,
                                               self.pull, position=False)):
            return (self.q_goal, *self.route)
        return (yield from route_steps(self.kin, self.solutions, q, centers, radii, self.pull,
                                       ground=self.ground, position=False))

    def _advance(self, t: float) -> bool:
        """Run the search for at most ``pull.budget`` kinematic passes (0: to its end); once
        it ends, take its route (engage, or re-target) or, with none, let go. Whether it
        ended."""
        budget = self.pull.budget
        for _ in range(budget if budget > 0 else 2**62):
            try:
                next(self.search)
                self.passes += 1
            except StopIteration as done:
                route = done.value
                break
        else:
            return False
        self.search = None
        self.goal_for = self.search_goal
        self.engaged = route is not None
        if route is not None:
            self.q_goal, self.route = route[0], route[1:]
            self.holding = not any(route[-1] is qg for qg in self.solutions.pose)
            self.t_checked = t
            if self.holding:
                self.release_at = -np.inf  # it holds: no distance lets it go
            else:
                p = self.pull
                self.release_at = p.near_release if p.near_release > 0.0 else p.release
        else:
            self.q_goal, self.route = None, ()
        self.best, self.t_best = np.inf, t
        return True

    def _engages(self, q: np.ndarray, distance: float, stall, obs) -> bool:
        """Whether the pull engages now: at an arming of the stall pull (its ``t_armed`` [s])
        not served yet; farther than ``release`` [m] at once; nearer, with the hand farther
        than ``near_release`` [m] (0: never), at the arming step with a joint at a limit, or
        once the armed stall pull has itself stopped making progress (``stall.stuck``): the
        search then engages only where the goal pose is blocked (see the module). Farther out,
        an arming already served gets that second search once, once it is stuck."""
        p, armed_at, t = self.pull, stall.t_armed, obs.t
        if armed_at is None:
            return False
        if armed_at == self.served:  # far out: once more where the stalled pull is stuck
            return (distance > p.release and self.served_blocked != armed_at
                    and stall.stuck(t))
        if distance > p.release:
            return p.release > 0.0
        if not distance > p.near_release > 0.0:
            return False
        if t - armed_at < ARMING_TOLERANCE_S and self.at_limit(q):
            return True
        return stall.stuck(t)

    def potential(self, q: np.ndarray) -> tuple[float, np.ndarray]:
        """The attractor's own potential while engaged (what CPM's regulator
        watches while the pull acts): φ(q) = g ρ_ℓ(‖q − q_g‖) [rad²/s²] with the Huber
        function ρ_ℓ(d) = d²/(2ℓ) for d ≤ ℓ, d − ℓ/2 beyond, so that

            ∂φ/∂q = g (q − q_g) / max(‖q − q_g‖, ℓ)                            [rad/s²]

        is minus the attractor's pull: q̈_q = −∂φ/∂q − k q̇, and H = ½‖q̇‖² + φ falls at
        k‖q̇‖² along it (k = 2√(g/ℓ))."""
        p = self.pull
        e = np.asarray(q, dtype=float) - self.q_goal
        d = float(np.linalg.norm(e))
        phi = d * d / (2.0 * p.length) if d <= p.length else d - 0.5 * p.length
        return p.gain * phi, p.gain * e / max(d, p.length)

    def _stuck(self, q: np.ndarray, t: float) -> bool:
        """No progress towards q_g: ‖q − q_g‖ has not fallen by ``progress`` [rad] below its
        least value for ``window`` [s] (the attractor held by a barrier: let go)."""
        d = float(np.linalg.norm(self.q_goal - q))
        if self.holding and d < self.pull.progress:
            self.best, self.t_best = d, t  # at q_g: it holds there
        if d < self.best - self.pull.progress:
            self.best, self.t_best = d, t
        return t - self.t_best >= self.pull.window
