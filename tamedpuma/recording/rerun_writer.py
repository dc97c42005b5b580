"""Rerun recorder: a ``.rrd`` replay of one episode (robot, obstacles, goal, EE path, plots).

Entity layout (all 3-D entities live in the named coordinate frame ``world``):

* ``/world/lbr_iiwa/**``: the URDF meshes (static); animated by one ``Transform3D`` per joint on
  ``/world/tf/<joint>`` (parent/child frames from :class:`rerun.urdf.UrdfTree`), and the robot
  base placed by ``world -> <root link>`` from the logged link pose.
* ``/world/obstacles``, ``/world/body_spheres``, ``/world/goal``: ``Ellipsoids3D``;
  ``/world/ee``: current end-effector point; ``/world/ee_path/<block>``: the end-effector path as
  ``LineStrips3D`` (one strip per block of steps, so the cost per step stays bounded).
* ``/joints/<joint>``: joint positions [rad]; ``/metrics/<name>``: every scalar (``Scalars``).

Timelines: ``step`` (sequence) and ``time`` (duration, simulated seconds). The file is streamed
while the episode runs (``RecordingStream.save`` before the first log), with a default blueprint:
a 3-D view of ``/world`` beside time-series views of the joints and the metrics.

Crash safety, as for MCAP: the file is ``<path>.active`` until :meth:`RerunRecorder.close`
renames it. A killed run's ``.active`` file has no RRD footer (``rerun rrd verify`` fails) but
:func:`tamedpuma.recording.read_rrd_joints` and the viewer read every batch sent before the kill.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from rerun.urdf import UrdfTree

from .mcap_writer import active_path, prepare_output
from .records import RunInfo, StepRecord

WORLD_FRAME = "world"
PATH_BLOCK = 100  # steps per end-effector path strip
GOAL_MARKER_RADIUS = 0.03  # [m], display only
_OBSTACLE_RGBA = (217, 51, 51, 160)
_BODY_RGBA = (51, 102, 230, 90)
_GOAL_RGBA = (26, 204, 51, 255)
_EE_RGBA = (255, 200, 0, 255)


def default_blueprint() -> rrb.Blueprint:
    """3-D view of ``/world`` (target frame ``world``) beside joint and metric plots."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="scene", origin="/world",
                              spatial_information=rrb.archetypes.SpatialInformation(
                                  target_frame=WORLD_FRAME, show_axes=True)),
            rrb.Vertical(
                rrb.TimeSeriesView(name="joints [rad]", origin="/joints"),
                rrb.TimeSeriesView(name="metrics", origin="/metrics"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RerunRecorder:
    """Write one episode to a Rerun ``.rrd`` file (layout in the module docstring).

    path: output file (created, with its parent directories; an existing ``path`` or
    ``<path>.active`` raises FileExistsError unless overwrite=True).
    batch: steps buffered before they are sent column-wise (``send_columns``): logging row by row
    costs ~2 ms per step, batching ~0.2 ms; a killed run loses at most the last ``batch`` steps.
    application_id: Rerun application id.
    """

    def __init__(self, path: str | os.PathLike, batch: int = 50,
                 application_id: str = "tamedpuma", overwrite: bool = False):
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        self.path = Path(path)
        self.active_path = active_path(path)
        self.batch = int(batch)
        self.overwrite = bool(overwrite)
        self.application_id = application_id
        self._rec: rr.RecordingStream | None = None
        self._info: RunInfo | None = None

    # -- Recorder protocol -------------------------------------------------------------------

    def open(self, info: RunInfo) -> None:
        """Start streaming to ``path``; log the URDF, frames, styles and run properties (static)."""
        if self._rec is not None:
            raise RuntimeError("RerunRecorder is already open")
        prepare_output(self.path, self.active_path, self.overwrite)
        self._info = info
        rec = rr.RecordingStream(self.application_id, recording_id=info.run_id)
        rec.save(self.active_path, default_blueprint=default_blueprint())
        self._rec = rec
        rec.send_recording_name(f"{info.method}/{info.scenario_name}/seed{info.seed}")
        rec.send_property("run", rr.AnyValues(**info.metadata()))
        rec.log("/config", rr.TextDocument(info.config_yaml, media_type=rr.MediaType.TEXT),
                static=True)

        # Frames: every world entity lives in the named frame "world" (the view's target frame);
        # styles are static so the per-step columns carry only numbers.
        rec.log("/world", rr.CoordinateFrame(WORLD_FRAME), rr.ViewCoordinates.RIGHT_HAND_Z_UP,
                static=True)
        k = len(info.body_sphere_radii)
        rec.log("/world/obstacles", rr.CoordinateFrame(WORLD_FRAME), rr.Ellipsoids3D.from_fields(
            colors=_OBSTACLE_RGBA, fill_mode="solid"), static=True)
        rec.log("/world/body_spheres", rr.CoordinateFrame(WORLD_FRAME),
                rr.Ellipsoids3D.from_fields(
                    half_sizes=np.repeat(info.body_sphere_radii, 3).reshape(k, 3),
                    colors=_BODY_RGBA, fill_mode="majorwireframe"), static=True)
        rec.log("/world/goal", rr.CoordinateFrame(WORLD_FRAME), rr.Ellipsoids3D.from_fields(
            half_sizes=[[GOAL_MARKER_RADIUS] * 3], colors=_GOAL_RGBA,
            fill_mode="majorwireframe"), static=True)
        rec.log("/world/ee", rr.CoordinateFrame(WORLD_FRAME), rr.Points3D.from_fields(
            radii=0.01, colors=_EE_RGBA), static=True)

        self._joints = []
        self._root = None
        self._root_index = None
        if Path(info.urdf_path).is_file():
            rec.log_file_from_path(info.urdf_path, entity_path_prefix="/world", static=True)
            tree = UrdfTree.from_file_path(info.urdf_path)
            self._joints = [tree.get_joint_by_name(n) for n in info.joint_names]
            if any(j is None for j in self._joints):
                missing = [n for n, j in zip(info.joint_names, self._joints) if j is None]
                raise ValueError(f"joints {missing} not in {info.urdf_path}")
            self._root = tree.root_link().name
            if self._root in info.link_names:
                self._root_index = info.link_names.index(self._root)
            else:  # no pose for the root link: base at the world origin
                rec.log("/world/tf/base", rr.Transform3D(
                    parent_frame=WORLD_FRAME, child_frame=self._root), static=True)
        else:
            warnings.warn(f"URDF {info.urdf_path} not found: the replay has no robot model",
                          stacklevel=2)
        self._buffer: list[StepRecord] = []
        self._path_tail: list[list[float]] = []  # EE points of the current path block
        self._count = 0

    def write(self, rec: StepRecord) -> None:
        """Buffer one step (arrays copied); send the buffer every ``batch`` steps."""
        if self._rec is None:
            raise RuntimeError("RerunRecorder.write before open")
        self._buffer.append(copy_record(rec))
        if len(self._buffer) >= self.batch:
            self._send()

    def close(self, complete: bool, summary: Mapping[str, object]) -> None:
        """Send buffered steps, log the outcome (static ``/summary``) and close the file."""
        stream = self._rec
        if stream is None:
            return
        try:
            self._send()
            fields = {k: (v if isinstance(v, (bool, int, float, str)) else str(v))
                      for k, v in summary.items()}
            stream.log("/summary", rr.AnyValues(**{**fields, "complete": bool(complete),
                                                   "recorded_steps": self._count}), static=True)
            stream.flush()
        finally:
            stream.disconnect()
            self._rec = None
            os.replace(self.active_path, self.path)

    # -- column-wise sending -----------------------------------------------------------------

    def _send(self) -> None:
        recs, self._buffer = self._buffer, []
        if not recs:
            return
        stream, info = self._rec, self._info
        n = len(recs)
        steps = np.array([r.step for r in recs], dtype=np.int64)
        times = np.array([r.t for r in recs], dtype=float)
        index = [rr.TimeColumn("step", sequence=steps), rr.TimeColumn("time", duration=times)]

        def send(entity: str, columns) -> None:
            stream.send_columns(entity, indexes=index, columns=columns)

        q = np.array([r.q for r in recs])
        if self._root_index is not None:
            i = self._root_index
            send("/world/tf/base", rr.Transform3D.columns(
                translation=np.array([r.link_positions[i] for r in recs]),
                quaternion=np.array([r.link_quaternions[i] for r in recs]),
                parent_frame=[WORLD_FRAME] * n, child_frame=[self._root] * n))
        for j, joint in enumerate(self._joints):
            send(f"/world/tf/{joint.name}", joint.compute_transform_columns(q[:, j], clamp=False))

        n_obs = [len(r.obstacle_radii) for r in recs]
        radii = np.concatenate([r.obstacle_radii for r in recs])
        send("/world/obstacles", rr.Ellipsoids3D.columns(
            centers=np.concatenate([r.obstacle_centers for r in recs]).reshape(-1, 3),
            half_sizes=np.repeat(radii, 3).reshape(-1, 3)).partition(n_obs))
        k = len(info.body_sphere_radii)
        if k:
            send("/world/body_spheres", rr.Ellipsoids3D.columns(
                centers=np.concatenate([r.body_sphere_centers for r in recs])).partition([k] * n))
        send("/world/goal", rr.Ellipsoids3D.columns(
            centers=np.array([r.goal_position for r in recs]),
            quaternions=np.array([r.goal_quaternion for r in recs])))
        ee = np.array([r.ee_position for r in recs])
        send("/world/ee", rr.Points3D.columns(positions=ee))
        self._send_path(stream, steps, times, ee)

        for j, name in enumerate(info.joint_names):
            send(f"/joints/{name}", rr.Scalars.columns(scalars=q[:, j]))
        for name in recs[0].scalars:
            values = np.array([float(r.scalars.get(name, np.nan)) for r in recs])
            send(f"/metrics/{name}", rr.Scalars.columns(scalars=values))
        stream.flush()  # on disk before the next batch: a killed run loses < batch steps

    def _send_path(self, stream, steps, times, ee) -> None:
        """EE path: strip b covers steps [b·B, (b+1)·B] (B = PATH_BLOCK), so strips join up and
        each step re-sends at most B points."""
        rows: dict[int, list] = {}
        for s, t, p in zip(steps.tolist(), times.tolist(), ee.tolist()):
            block = self._count // PATH_BLOCK
            if self._count % PATH_BLOCK == 0:
                self._path_tail = self._path_tail[-1:]
                stream.log(f"/world/ee_path/{block:05d}", rr.CoordinateFrame(WORLD_FRAME),
                           rr.LineStrips3D.from_fields(colors=_EE_RGBA, radii=0.003),
                           static=True)
            self._path_tail.append(p)
            rows.setdefault(block, []).append((s, t, list(self._path_tail)))
            self._count += 1
        for block, items in rows.items():
            strips = [np.array(pts) for _, _, pts in items]
            stream.send_columns(
                f"/world/ee_path/{block:05d}",
                indexes=[rr.TimeColumn("step", sequence=[s for s, _, _ in items]),
                         rr.TimeColumn("time", duration=[t for _, t, _ in items])],
                columns=rr.LineStrips3D.columns(strips=strips))


def copy_record(rec: StepRecord) -> StepRecord:
    """A copy of ``rec`` whose arrays the caller can no longer mutate."""
    return StepRecord(
        step=rec.step, t=rec.t, q=rec.q.copy(), qd=rec.qd.copy(), qdd_cmd=rec.qdd_cmd.copy(),
        link_positions=rec.link_positions.copy(), link_quaternions=rec.link_quaternions.copy(),
        ee_position=rec.ee_position.copy(), ee_quaternion=rec.ee_quaternion.copy(),
        body_sphere_centers=rec.body_sphere_centers.copy(),
        obstacle_centers=rec.obstacle_centers.copy(), obstacle_radii=rec.obstacle_radii.copy(),
        goal_position=rec.goal_position.copy(), goal_quaternion=rec.goal_quaternion.copy(),
        scalars=dict(rec.scalars))
