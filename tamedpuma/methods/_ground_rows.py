"""The ground rows of the control-rate barrier step, fused: the numbers of
:func:`tamedpuma.robot.ground.hull_ground_rows` (bit for bit) with its per-link array
arithmetic in two kernels (:func:`~tamedpuma.methods._kernels.lowest_points`,
:func:`~tamedpuma.methods._kernels.ground_rows`); only the pinocchio reads stay per link.

Per moving link l (hull vertices v in the link frame, placement (R_l, p_l)): the lowest point
``x_l = min_v (R_l v + p_l)_z`` [m], its row ``(J_p)_z + (J_ω)_x r_y − (J_ω)_y r_x`` (r = R_l v)
[m/rad] and its curvature term, the z component of ``a_o + α × r + ω × (ω × r)`` [m/s²].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from tamedpuma.methods._kernels import STEP
from tamedpuma.robot.ground import GroundRows, LinkHulls

_WORLD = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass(frozen=True)
class HullTable:
    """The hulls of :class:`~tamedpuma.robot.ground.LinkHulls` as the kernels take them: every
    vertex (V, 3) [m], hull l's from ``starts[l]`` to ``starts[l + 1]``, and the radii (L,)."""

    hulls: LinkHulls
    vertices: np.ndarray
    starts: np.ndarray
    radii: np.ndarray

    @staticmethod
    def of(hulls: LinkHulls) -> HullTable:
        sizes = [len(v) for v in hulls.vertices]
        return HullTable(hulls, np.ascontiguousarray(np.concatenate(hulls.vertices), float),
                         np.concatenate(([0], np.cumsum(sizes))).astype(np.int64),
                         np.array(hulls.radii, dtype=float))


def hull_ground_rows(kinematics, table: HullTable, qd: np.ndarray,
                     below: float = np.inf) -> GroundRows:
    """:func:`tamedpuma.robot.ground.hull_ground_rows` of ``table.hulls`` (the same numbers):
    the lowest point of each hull lower than ``below`` [m] at the kinematics' last
    ``evaluate(q, q̇)``, its height, row and curvature term; qd: that q̇ [rad/s]."""
    model, data, oMf = kinematics.model, kinematics.data, kinematics.data.oMf
    ids = table.hulls.frame_ids
    L = len(ids)
    Rt, tz, radii = np.empty((L, 3, 3)), np.empty(L), table.radii
    for i, fid in enumerate(ids):
        placement = oMf[fid]
        tz[i] = height = placement.translation[2]
        if not height - radii[i] >= below:  # else no vertex is lower: R not read
            Rt[i] = placement.rotation.T
    found, heights, points = STEP["lowest_points"](table.vertices, table.starts, Rt, tz,
                                                   table.radii, below)
    links = found.nonzero()[0]
    k = len(links)
    if not k:
        return GroundRows(np.empty(0), np.empty((0, model.nv)), np.empty(0))
    J, acc = np.empty((k, 6, model.nv)), np.empty((k, 6))
    for n, i in enumerate(links):
        J[n] = pin.getFrameJacobian(model, data, ids[i], _WORLD)
        acc[n] = pin.getFrameClassicalAcceleration(model, data, ids[i], _WORLD).vector
    rows, jdqd = STEP["ground_rows"](J, acc, points[links], np.asarray(qd, dtype=float))
    return GroundRows(heights[links], rows, jdqd)
