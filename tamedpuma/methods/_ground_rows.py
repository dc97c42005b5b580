"""The ground rows of the control-rate barrier step, fused: the numbers of
:func:`tamedpuma.robot.ground.hull_ground_rows` (bit for bit). Where the kinematics is the
compiled chain's and the step kernels are compiled, one call
(:func:`~tamedpuma.methods._kernels.hull_ground`: the hull frames' placements, Jacobians and
J̇q̇, the lowest points and their rows); otherwise the per-link array arithmetic in two kernels
(:func:`~tamedpuma.methods._kernels.lowest_points`,
:func:`~tamedpuma.methods._kernels.ground_rows`) between the placement reads and the link
origins' Jacobians (:meth:`~tamedpuma.robot.kinematics.Kinematics.frame_motion`).

Per moving link l (hull vertices v in the link frame, placement (R_l, p_l)): the lowest point
``x_l = min_v (R_l v + p_l)_z`` [m], its row ``(J_p)_z + (J_ω)_x r_y − (J_ω)_y r_x`` (r = R_l v)
[m/rad] and its curvature term, the z component of ``a_o + α × r + ω × (ω × r)`` [m/s²].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tamedpuma.methods._kernels import STEP
from tamedpuma.robot.ground import GroundRows, LinkHulls, per_hull


@dataclass(frozen=True)
class HullTable:
    """The hulls of :class:`~tamedpuma.robot.ground.LinkHulls` as the kernels take them: every
    vertex (V, 3) [m], hull l's from ``starts[l]`` to ``starts[l + 1]``, the radii (L,) [m] and
    the vertical speed bounds (L,) [m/s] and Lipschitz constants (L,) [m/rad]."""

    hulls: LinkHulls
    vertices: np.ndarray
    starts: np.ndarray
    radii: np.ndarray
    speeds: np.ndarray
    lipschitz: np.ndarray

    @staticmethod
    def of(hulls: LinkHulls) -> HullTable:
        sizes = [len(v) for v in hulls.vertices]
        return HullTable(hulls, np.ascontiguousarray(np.concatenate(hulls.vertices), float),
                         np.concatenate(([0], np.cumsum(sizes))).astype(np.int64),
                         np.array(hulls.radii, dtype=float),
                         np.array(hulls.speed_bounds, dtype=float),
                         np.array(hulls.lipschitz, dtype=float))


def hull_ground_rows(kinematics, table: HullTable, qd: np.ndarray,
                     below: float | np.ndarray = np.inf) -> GroundRows:
    """:func:`tamedpuma.robot.ground.hull_ground_rows` of ``table.hulls`` (the same numbers):
    the lowest point of each hull lower than ``below`` [m] (one height, or one per hull) at the
    kinematics' last ``evaluate(q, q̇)``, its height, row and curvature term, and where none
    is that low how far the joints may move before one is (``GroundRows.reach``,
    :func:`~tamedpuma.methods._kernels.ground_reach`); qd: that q̇ [rad/s]."""
    model, ids = kinematics.model, table.hulls.frame_ids
    qd = np.asarray(qd, dtype=float)
    below = per_hull(below, table.hulls)
    chain = kinematics.chain_state(ids) if STEP["hull_ground"].fast is not None else None
    if chain is not None:  # one compiled call: the placements and the rows (the same numbers)
        return GroundRows(*STEP["hull_ground"](*chain, table.vertices, table.starts, table.radii,
                                               below, table.lipschitz, qd))
    R, origins = kinematics.frame_placements(ids)
    Rt, tz = np.ascontiguousarray(R.transpose(0, 2, 1)), np.ascontiguousarray(origins[:, 2])
    found, heights, points = STEP["lowest_points"](table.vertices, table.starts, Rt, tz,
                                                   table.radii, below)
    links = found.nonzero()[0]
    k = len(links)
    if not k:
        return GroundRows(np.empty(0), np.empty((0, model.nv)), np.empty(0),
                          float(STEP["ground_reach"](found, heights, below, table.lipschitz)))
    J, acc = kinematics.frame_motion([ids[i] for i in links])
    rows, jdqd = STEP["ground_rows"](J, acc, points[links], qd)
    return GroundRows(heights[links], rows, jdqd)
