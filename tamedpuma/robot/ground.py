"""How far the robot is above the ground plane z = 0: the rows the control-rate barrier step keeps
positive (``method.control_rate.barrier_step``; tamedpuma/methods/_tamed.py ControlRate).

Two geometries, each a set of heights x_i [m] with their rows a_i = ∂x_i/∂q [m/rad] and
curvature terms ȧ_i q̇ [m/s²]:

- ``spheres``: the body spheres, ``x_i = c_{i,z} − r_i`` (the authors' five, radius 7-9 cm
  round the link origins, plus the guard spheres);
- ``mesh``: each moving link's collision mesh, ``x_l = min_v (R_l v + p_l)_z`` over the vertices
  v of its convex hull (link frame): the height of the link's lowest point, the support point
  of the hull in the direction −z. Its row is the z row of that point's Jacobian,
  ``a_l = J_{v,l} + ω-part × r``: ``(J_p)_z + (J_ω)_x r_y − (J_ω)_y r_x`` with r = R_l v the
  vertex relative to the link origin, and its curvature term the z component of
  ``a_o + α × r + ω × (ω × r)`` (the origin's classical acceleration, the link's angular
  acceleration α and velocity ω at q̈ = 0).

Why the mesh. The whole-body criterion judges the links' meshes against the ground (PyBullet
contacts), and the spheres are far bulkier there: the hand's sphere (7 cm round the flange
origin, the task point) keeps the task point 8 cm above the ground with the barrier's 1 cm
margin, while the flange's own mesh (a 5.2 cm cylinder reaching 4.5 cm past the origin) lets it
come down to 5.5 cm when it points down. Random tomato goals shifted down by up to 8 cm
(z ≥ 3.5 cm) are then out of the hand's reach by up to 4.5 cm, inside the 5 cm goal tolerance
by millimetres only, and FPM and CPM stall against the ground rows there. The support point is
exact for the hull (no inflation) and continuous in q; its row jumps where the lowest vertex
changes, which the barrier step, a projection of one period's velocity, does not mind.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from tamedpuma.errors import ConfigError
from tamedpuma.robot.body_model import urdf_collision_geometry

_min = np.minimum.reduce  # np.min without its Python wrapper


@dataclass(frozen=True)
class GroundRows:
    """Heights x (k,) [m], rows a (k, n) [m/rad] and curvature terms ȧq̇ (k,) [m/s²]; reach
    [rad]: where no rows were found, how far any joint may move from this configuration with
    every hull still higher than its row height (the rows stay empty: 0 where not known)."""

    heights: np.ndarray
    rows: np.ndarray
    jdqd: np.ndarray
    reach: float = 0.0


@dataclass(frozen=True)
class LinkHulls:
    """The moving links' collision hulls: pinocchio frame ids and each hull's vertices (V, 3)
    in its link frame [m]."""

    links: tuple[str, ...]
    frame_ids: tuple[int, ...]
    vertices: tuple[np.ndarray, ...]
    #: [m/s] per hull: no point of it moves up or down faster within the joint speed limits
    #: (:func:`vertical_bounds` at q̇_max)
    speed_bounds: tuple[float, ...]
    #: [m/rad] per hull: no point of it moves up or down by more than this times the largest
    #: joint displacement (:func:`vertical_bounds` at 1 rad/s per joint)
    lipschitz: tuple[float, ...]
    radii: tuple[float, ...] = ()  # [m] each hull's farthest vertex from its link origin

    def __post_init__(self):
        if not self.radii:  # computed from the vertices when not given
            object.__setattr__(self, "radii", tuple(
                float(np.max(np.linalg.norm(v, axis=1))) for v in self.vertices))


def vertical_bounds(kinematics, frame_ids, vertices, rates) -> tuple[float, ...]:
    """Per hull, an upper bound on the vertical speed [m/s] of any of its points while each
    joint i turns no faster than ``rates[i]`` [rad/s]: ``Σ_i rates_i ρ_i`` over the joints i
    that move its link, ρ_i the largest distance of a hull point from joint i (the joint
    origins' distances down the chain to the link's own joint plus the hull's farthest point
    from that joint: the triangle inequality, whatever the configuration). A revolute joint on
    the fixed base turning about the world's vertical moves no point up or down (ż of ω × r is
    0 for ω along z) and is left out.

    At ``rates = q̇_max`` it decides which hulls need a row: the barrier step acts on a row only
    when one period Δt would take more than κ of its height, so a link higher than
    ``bound Δt / κ`` needs none. At rates 1 it is a Lipschitz constant [m/rad]: between two
    configurations a hull's lowest point moves up or down by at most that times the largest
    joint displacement."""
    model = kinematics.model
    rates = np.asarray(rates, dtype=float)
    lengths = [float(np.linalg.norm(p.translation)) for p in model.jointPlacements]
    bounds = []
    for fid, v in zip(frame_ids, vertices):
        frame = model.frames[fid]
        placement = frame.placement  # the link frame in its joint's frame
        rho = float(np.max(np.linalg.norm(v @ placement.rotation.T + placement.translation,
                                          axis=1)))
        bound, joint = 0.0, frame.parentJoint
        while joint > 0:  # from the link's joint towards the base: ρ grows by each placement
            if not _turns_about_vertical(model, joint):
                idx = model.joints[joint].idx_v
                bound += float(rates[idx]) * rho
            rho += lengths[joint]
            joint = model.parents[joint]
        bounds.append(bound)
    return tuple(bounds)


def _turns_about_vertical(model, joint: int) -> bool:
    """Whether ``joint`` is a revolute joint about its own z axis, on the fixed base (its
    parent the universe), with that axis along the world's vertical."""
    axis_z = model.jointPlacements[joint].rotation[:, 2]
    return (model.parents[joint] == 0 and model.joints[joint].shortname() == "JointModelRZ"
            and abs(abs(float(axis_z[2])) - 1.0) < 1e-12)


#: link hulls a process keeps (every controller of a sweep worker's runs builds them), by the
#: URDF file (path, size, modification time) and the model's frames
_HULLS: dict = {}


def link_hulls(kinematics) -> LinkHulls:
    """The convex-hull vertices of every URDF link with collision geometry that moves with a
    joint (the fixed base never comes nearer the ground; a gripper's fingers, locked in the
    model, move with the last joint and are included). Built once per process and model (the
    vertices read-only)."""
    path = kinematics.spec.urdf_path
    try:
        stat = os.stat(path)
        key = (os.path.realpath(path), stat.st_size, stat.st_mtime_ns,
               tuple((f.name, f.parentJoint) for f in kinematics.model.frames),
               tuple(kinematics.spec.qd_max))
    except OSError:
        key = None
    if key is not None and key in _HULLS:
        return _HULLS[key]
    hulls = _build_link_hulls(kinematics)
    for v in hulls.vertices:
        v.setflags(write=False)
    if key is not None:
        _HULLS[key] = hulls
    return hulls


def _build_link_hulls(kinematics) -> LinkHulls:
    from scipy.spatial import ConvexHull

    geometry = urdf_collision_geometry(kinematics.spec.urdf_path)
    model = kinematics.model
    links, ids, verts = [], [], []
    for name in geometry:
        if not model.existFrame(name):
            continue
        fid = model.getFrameId(name)
        if model.frames[fid].parentJoint == 0:  # attached to the universe: the base
            continue
        v = geometry[name].vertices
        try:
            v = v[ConvexHull(v).vertices]
        except Exception:  # a flat or degenerate point set: keep every point
            pass
        links.append(name)
        ids.append(fid)
        verts.append(np.ascontiguousarray(v, dtype=float))
    if not links:
        raise ConfigError("method.control_rate.barrier_step (its ground rows): no moving link has "
                          f"collision geometry in {kinematics.spec.urdf_path}")
    qd_max = np.asarray(kinematics.spec.qd_max, dtype=float)
    return LinkHulls(tuple(links), tuple(ids), tuple(verts),
                     vertical_bounds(kinematics, ids, verts, qd_max),
                     vertical_bounds(kinematics, ids, verts, np.ones_like(qd_max)))


def sphere_ground_rows(state) -> GroundRows:
    """The body spheres' heights ``c_z − r`` from a KinematicState."""
    return GroundRows(state.sphere_centers[:, 2] - state.sphere_radii,
                      state.sphere_jacobians[:, 2, :], state.sphere_jdqd[:, 2])


def per_hull(below, hulls: LinkHulls) -> np.ndarray:
    """``below`` [m], one number or one per hull, as a writable C float array with one per hull
    (L,) (the kernels' argument type): ``below`` itself where it is one already, else a copy."""
    L = len(hulls.frame_ids)
    if (type(below) is np.ndarray and below.shape == (L,) and below.dtype == np.float64
            and below.flags.c_contiguous and below.flags.writeable):
        return below
    return np.array(np.broadcast_to(np.asarray(below, dtype=float), (L,)))


def hull_ground_rows(kinematics, hulls: LinkHulls, qd: np.ndarray,
                     below: float | np.ndarray = np.inf) -> GroundRows:
    """The lowest point of each hull lower than ``below`` [m] (one height, or one per hull) at
    the kinematics' last ``evaluate(q, q̇)`` (its placements, and the link origins' Jacobians
    and J̇q̇ by :meth:`~tamedpuma.robot.kinematics.Kinematics.frame_motion`: no forward pass of
    its own);
    qd: that q̇ [rad/s]. Its height, the z row of its point Jacobian
    and its ȧq̇ (see the module).

    Per link only the placement read and the hull's support point (one product over its
    vertices); the rows and curvature terms of all the lowest points are then a few array
    operations over the links at once, each the same floating-point operation, in the same
    order, as the link-by-link formula (the 3-vector dot products as ``(a₀b₀ + a₁b₁) + a₂b₂``,
    which is what a length-3 ``np.dot`` computes): the same numbers, bit for bit."""
    model = kinematics.model
    found = _lowest_points(kinematics.frame_placements(hulls.frame_ids), hulls,
                           per_hull(below, hulls))
    k = len(found)
    heights, rows, jdqd = np.empty(k), np.empty((k, model.nv)), np.empty(k)
    if not k:
        return GroundRows(heights, rows, jdqd)
    r = np.empty((k, 3))
    for n, (_, height, point) in enumerate(found):
        heights[n] = height
        r[n] = point
    # [v; ω] of each link origin and its J̇q̇
    J, acc = kinematics.frame_motion([hulls.frame_ids[i] for i, _, _ in found])
    rx, ry, rz = r[:, 0], r[:, 1], r[:, 2]
    np.subtract(J[:, 2] + J[:, 3] * ry[:, None], J[:, 4] * rx[:, None], out=rows)
    w = J[:, 3:] @ np.asarray(qd, dtype=float)  # ω (k, 3)
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    w_r = (wx * rx + wy * ry) + wz * rz
    w_w = (wx * wx + wy * wy) + wz * wz
    # z of a_o + α × r + ω × (ω × r), with ω × (ω × r) = ω (ω·r) − r ‖ω‖²
    jdqd[:] = acc[:, 2] + acc[:, 3] * ry - acc[:, 4] * rx + wz * w_r - rz * w_w
    return GroundRows(heights, rows, jdqd)


def _lowest_points(placements, hulls: LinkHulls, below: np.ndarray) -> list:
    """(link index, height [m], lowest vertex relative to the link origin in world axes (3,))
    of each hull l whose lowest point is below ``below[l]``, at the hulls' ``placements``
    (world rotations (L, 3, 3), origins (L, 3))."""
    lowest = []
    rotations, origins = placements
    for i, (v, radius) in enumerate(zip(hulls.vertices, hulls.radii)):
        tz = origins[i, 2]
        if tz - radius >= below[i]:  # no vertex of this hull is lower
            continue
        R = rotations[i]
        z = v @ R[2]
        j = z.argmin()
        height = float(tz + z[j])
        if height < below[i]:
            lowest.append((i, height, R @ v[j]))
    return lowest


def hull_heights(kinematics, hulls: LinkHulls, q: np.ndarray) -> np.ndarray:
    """The lowest point [m] of each hull at q (a placement pass of its own on ``kinematics``,
    whose model the hulls' frame ids index): the heights :func:`hull_ground_rows` reads, at
    any configuration (a goal configuration's check, not the control step)."""
    return hull_heights_and_spheres(kinematics, hulls, q)[0]


def hull_heights_and_spheres(kinematics, hulls: LinkHulls, q: np.ndarray):
    """:func:`hull_heights` and the body-sphere centres (k, 3) [m] at q from the one placement
    pass (the same numbers as ``kinematics.sphere_centers(q)``)."""
    L = len(hulls.frame_ids)
    R, p = kinematics.placements(q, tuple(hulls.frame_ids) + tuple(kinematics.sphere_ids))
    heights = np.array([_lowest_height(R[i], p[i], v) for i, v in enumerate(hulls.vertices)])
    return heights, np.ascontiguousarray(p[L:])


def _lowest_height(R: np.ndarray, origin: np.ndarray, vertices: np.ndarray) -> float:
    """The lowest point [m] of a hull (vertices (V, 3) in its link frame) at its link's
    placement (world rotation R, origin [m]): the minimum as the bare ufunc reduction (the
    numbers of ``np.min``)."""
    return origin[2] + float(_min(vertices @ R[2]))


def hull_heights_from_poses(hulls: LinkHulls, link_names, positions: np.ndarray,
                            quaternions: np.ndarray) -> np.ndarray:
    """The lowest point [m] of each hull whose link is logged, from the link poses
    (``link_names`` with positions (L, 3) [m] and quaternions (L, 4) (x, y, z, w), e.g. a step
    record's): the same heights as :func:`hull_ground_rows`, without the kinematics' forward
    pass (a link not logged, such as a gripper's finger, is left out)."""
    from tamedpuma.robot.rotations import quat_to_matrix

    index = {name: j for j, name in enumerate(link_names)}
    out = []
    for link, v in zip(hulls.links, hulls.vertices):
        if link in index:
            j = index[link]
            out.append(positions[j][2] + float(np.min(v @ quat_to_matrix(quaternions[j])[2])))
    return np.array(out)
