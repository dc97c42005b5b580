"""Whether a scenario's goal pose can be held clear of its obstacles: a scenario's share in a
failure, apart from the model's and the controller's.

The random generator keeps every obstacle ``goal_clearance`` (10 cm) from the goal *point*
(:mod:`tamedpuma.worlds.random_scenarios`). That does not keep the arm clear at the goal *pose*:
with the pouring orientation the wrist and forearm reach 15-25 cm behind the hand, and an
obstacle there leaves no configuration that puts the hand at the goal pose with every body
sphere clear. A controller that keeps the body spheres clear cannot rest at that pose; it can
still converge under the paper's criterion (the position within the tolerance), giving up the
orientation the obstacle forbids, or rest short of the ball.

The measure (:func:`goal_pose_gap`, with :mod:`tamedpuma.worlds.goal_pose`, the test
``scenario=from_demos`` places its obstacles by): over ``count`` inverse-kinematics solutions of
the goal pose, one started from the run's start q₀ and the others from seeded random starts
(inside the joint limits, every body sphere above the ground), the
largest of each solution's least clearance

    gap(q) = min over body spheres i and obstacles j of  ‖c_i(q) − o_j‖ − r_i − ρ_j       [m]

A negative gap: no configuration found holds the goal pose clear. The solutions sample the arm's
self-motion at the pose (one dimension for the 7-joint iiwa); they can miss a narrow clear set,
so ``blocked`` means "none found". The obstacles and the goal are taken where they are at the
start (a moving goal or obstacle is judged at t = 0).
"""

from __future__ import annotations

#: seeded pose IK solutions tried per goal (100: about 1 s per goal pose on one core)
SOLUTIONS = 100


def goal_pose_gap(kinematics, position, quaternion, centers, radii,
                  count: int = SOLUTIONS, seed: int = 0, q0=None) -> float | None:
    """The largest least clearance [m] between the body spheres and the obstacles (centres
    (m, 3) [m], radii (m,) [m]) over ``count`` seeded IK solutions of the goal pose (position
    [m], quaternion (x, y, z, w)), the first from the start ``q0`` [rad] where given (see the
    module); inf without obstacles, None when no start converges to the pose."""
    from tamedpuma.worlds.goal_pose import goal_pose_spheres, pose_gap

    spheres = goal_pose_spheres(kinematics, position, quaternion, seed, count, q0)
    return pose_gap(spheres, kinematics.spec.sphere_radii, centers, radii)


def scenario_key(summary: dict) -> tuple:
    """(task, scenario name, number of obstacles) of a run summary: a scenario and its
    obstacle-free twin (``without_obstacles``) share the name."""
    return summary["task"], summary["scenario"], int(summary.get("n_obstacles", 0))


#: the three verdicts on a scenario's goal pose: a solution clear of the obstacles (gap ≥ 0),
#: every solution inside one (gap < 0), no solution found (None: the IK did not converge to the
#: pose with every body sphere above the ground, e.g. a goal low over the ground)
VERDICTS = ("clear", "blocked", "unsolved")


def verdict(gap: float | None) -> str:
    """One of :data:`VERDICTS` for a goal-pose gap [m]."""
    return "unsolved" if gap is None else ("clear" if gap >= 0.0 else "blocked")


def reach_table(rows: list[dict], gaps: dict) -> list[dict]:
    """Per method label: runs and runs converged (paper criterion) on the scenarios of each
    :data:`VERDICTS`. rows: run summaries (``method_label`` or ``method``, ``task``,
    ``scenario``, ``n_obstacles``, ``converged_paper``); gaps: :func:`scenario_key` -> gap [m]
    or None (a run whose scenario is missing counts as unsolved)."""
    table: dict[str, dict] = {}
    for s in rows:
        label = s.get("method_label") or s["method"]
        t = table.setdefault(label, {"method": label, **{f"{v}_{c}": 0 for v in VERDICTS
                                                         for c in ("runs", "converged")}})
        side = verdict(gaps.get(scenario_key(s)))
        t[f"{side}_runs"] += 1
        t[f"{side}_converged"] += bool(s.get("converged_paper"))
    return [table[k] for k in sorted(table)]
