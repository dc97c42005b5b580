"""Rerun recorder: a ``.rrd`` replay of one episode (robot, obstacles, goal, EE path, plots).

Entity layout (all 3-D entities live in the named coordinate frame ``world``):

* ``/world/lbr_iiwa/**``: the URDF meshes (static); animated by one ``Transform3D`` per joint on
  ``/world/tf/<joint>`` (parent/child frames from :class:`rerun.urdf.UrdfTree`), and the robot
  base placed by ``world -> <root link>`` from the logged link pose.
* ``/world/obstacles``, ``/world/body_spheres``, ``/world/goal``: ``Ellipsoids3D``;
  ``/world/ee``: current end-effector point; ``/world/ee_path/<block>``: the end-effector path as
  ``LineStrips3D`` (one strip per block of steps, so the cost per step stays bounded).
* ``/joints/<joint>``: joint positions [rad]; ``/metrics/<name>``: every scalar (``Scalars``).

* ``/joint_speed/<joint>``: |q̇| divided by the joint's speed limit (raw [rad/s] when the limits
  are unknown), with ``/joint_speed/limit`` = 1.
* ``/world/reference_path``: PUMA's obstacle-free path, from a separate overlay file
  (:func:`write_reference_overlay`) that the viewer merges in; its label on
  ``/world/reference_path/label``, below the path's end.

Timelines: ``step`` (sequence) and ``time`` (duration, simulated seconds). The file is streamed
while the episode runs (``RecordingStream.save`` before the first log). Its blueprint
(:func:`replay_blueprint`) is sent with the first step and again on close: the 3-D scene with the
arm's visual meshes (collision meshes and body spheres hidden, one click away), an eye framing
everything the episode showed (:func:`frame_camera`), and one plot per quantity, its legend in
the corner its curves leave most free (:func:`legend_corner`, on close, from every
``FRAME_EVERY``-th step).

Crash safety, as for MCAP: the file is ``<path>.active`` until :meth:`RerunRecorder.close`
renames it. A killed run's ``.active`` file has no RRD footer (``rerun rrd verify`` fails) but
:func:`tamedpuma.recording.read_rrd_joints` and the viewer read every batch sent before the kill.
"""

from __future__ import annotations

import errno
import fnmatch
import os
import threading
import time
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb
from rerun.components import LineStrip3DBatch
from rerun.encodings import Vec3DBatch
from rerun.urdf import UrdfTree

from tamedpuma.records import RunInfo, StepRecord

from ..paths import LOW_SPACE, free_bytes
from .mcap_writer import active_path, prepare_output, write_error

WORLD_FRAME = "world"
PATH_BLOCK = 100  # steps per end-effector path strip
FRAME_EVERY = 5  # the camera frames the scene as seen every this many steps
GOAL_MARKER_RADIUS = 0.03  # [m], display only
_OBSTACLE_RGBA = (217, 51, 51, 160)
_BODY_RGBA = (51, 102, 230, 90)
_GOAL_RGBA = (26, 204, 51, 255)
_EE_RGBA = (255, 200, 0, 255)
_REFERENCE_RGBA = (80, 200, 255, 255)
_LIMIT_RGBA = (255, 60, 60, 255)


#: One time-series plot per quantity: (title, scalar-name patterns), in display order. A scalar
#: goes to the first plot whose pattern matches; the rest share "method internals". Counts and
#: on/off flags have plots of their own, so each plot keeps few enough series for a legend.
PLOT_GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("position error [m]", ("position_error_m", "goal_distance", "ik_position_error_m")),
    ("position error x, y, z [m]", ("position_error_?_m",)),
    ("clearance [m]", ("clearance_m", "min_clearance*", "ik_constraint_violation_m")),
    ("ψ (PUMA potential)", ("psi",)),
    ("ψ rate [1/s]", ("psi_rate",)),
    ("energies", ("energy_*", "dissipation", "potential")),
    ("compute time [ms]", ("compute_time_ms", "compute_cpu_time_ms", "ik_solve_ms")),
    ("orientation error [rad]", ("orientation_error_rad", "joint_error_rad")),
    ("orientation error x, y, z [rad]", ("orientation_error_?_rad",)),
    ("contacts and switches (1: on)", ("obstacle_contact", "ground_contact", "stall_pull",
                                       "configuration_pull", "ik_success", "ik_brake")),
    ("counts", ("n_*", "ik_iterations", "ik_failures")),
)
INTERNALS = "method internals"
JOINTS_PLOT = "joints [rad]"
MAX_LEGEND = 8  # plots with more series show no legend (hover shows the names): the
#: joint plots (7 joints, the speed limit) keep theirs
#: A plot's legend box as fractions of the plot (measured on the default 1600 × 900 window,
#: six rows of plots about 300 × 90 points: a legend row is 23 points high, the box 105 to 125
#: points wide for names of 9 to 18 characters): height ``LEGEND_PAD + LEGEND_ROW n`` for n
#: series, width ``LEGEND_PAD_X + LEGEND_CHAR c`` for the longest name of c characters (both
#: at most 1).
LEGEND_ROW, LEGEND_PAD = 0.25, 0.06
LEGEND_CHAR, LEGEND_PAD_X = 0.012, 0.2
LEGEND_GRID = (60, 20)  # cells (x, y) a plot is drawn into to weigh what a legend covers
#: The corners a legend may take, the preferred first (ties keep the earlier one).
LEGEND_CORNERS = (rrb.Corner2D.RightTop, rrb.Corner2D.RightBottom, rrb.Corner2D.LeftTop,
                  rrb.Corner2D.LeftBottom)
#: Vertical field of view of Rerun's 3-D eye [rad] (measured: a point 1 m off-axis at 3 m
#: projects 0.32 image heights from the centre, i.e. 55°).
RERUN_FOV_Y = np.deg2rad(55.0)
#: Direction from the scene centre to the default eye (front-right, above).
EYE_DIRECTION = (1.0, -1.5, 0.75)
#: Hidden by default; each is one click (the eye icon) away in the viewer: the body spheres and
#: the robot's collision meshes (logged by Rerun under the URDF's robot name)
HIDDEN_BY_DEFAULT = ("/world/body_spheres",)
COLLISION_MESHES = "/world/{robot}/collision_geometries"
REFERENCE_PATH = "/world/reference_path"
REFERENCE_LABEL_DROP = 0.15  # [m] below the reference path's end, where its label is drawn


def plot_groups(scalar_names: Iterable[str]) -> list[tuple[str, list[str]]]:
    """Split scalar names into the :data:`PLOT_GROUPS` plots (empty ones left out) plus
    "method internals" for names no group claims."""
    groups: dict[str, list[str]] = {title: [] for title, _ in PLOT_GROUPS}
    groups[INTERNALS] = []
    for name in scalar_names:
        title = next((t for t, pats in PLOT_GROUPS
                      if any(fnmatch.fnmatchcase(name, p) for p in pats)), INTERNALS)
        groups[title].append(name)
    return [(t, names) for t, names in groups.items() if names]


def legend_corner(t: np.ndarray, values: np.ndarray, names: Iterable[str]) -> rrb.Corner2D:
    """The corner of a time-series plot where its legend covers the least of the curves.

    t (T,) [s] and values (T, n) (one column per series, non-finite entries not drawn) are
    scaled as the viewer fits them, ``x = (t − t₀)/(t₁ − t₀)``, ``y = (v − min)/(max − min)``
    (0.5 for a constant), and drawn into a grid of :data:`LEGEND_GRID` cells (series on top of
    each other fill a cell once); the legend of n series named ``names`` is a box of height
    ``min(1, LEGEND_PAD + LEGEND_ROW n)`` and width ``min(1, LEGEND_PAD_X + LEGEND_CHAR c)``
    (c: the longest name's length) in the corner, and covers the drawn cells whose centres it
    holds. Ties keep the earlier of :data:`LEGEND_CORNERS`, so a plot without samples keeps
    the right top one."""
    names = list(names)
    t = np.asarray(t, dtype=float)
    v = np.asarray(values, dtype=float).reshape(len(t), -1)
    ok = np.isfinite(v) & np.isfinite(t)[:, None]
    if not ok.any():
        return LEGEND_CORNERS[0]
    t_drawn = t[ok.any(axis=1)]
    span = float(np.ptp(t_drawn))
    x = (t - t_drawn.min()) / span if span > 0 else np.full(len(t), 0.5)
    x = np.broadcast_to(x[:, None], v.shape)[ok]
    lo, hi = float(v[ok].min()), float(v[ok].max())
    y = (v[ok] - lo) / (hi - lo) if hi > lo else np.full(len(x), 0.5)
    gx, gy = LEGEND_GRID
    ix = np.minimum((x * gx).astype(int), gx - 1)
    iy = np.minimum((y * gy).astype(int), gy - 1)
    cells = np.unique(ix * gy + iy)
    cx, cy = (cells // gy + 0.5) / gx, (cells % gy + 0.5) / gy  # the drawn cells' centres
    height = min(1.0, LEGEND_PAD + LEGEND_ROW * len(names))
    width = min(1.0, LEGEND_PAD_X + LEGEND_CHAR * max(map(len, names), default=0))
    right, top = cx >= 1.0 - width, cy >= 1.0 - height
    left, bottom = cx <= width, cy <= height
    covered = {rrb.Corner2D.RightTop: right & top, rrb.Corner2D.RightBottom: right & bottom,
               rrb.Corner2D.LeftTop: left & top, rrb.Corner2D.LeftBottom: left & bottom}
    return min(LEGEND_CORNERS, key=lambda c: int(covered[c].sum()))


@dataclass(frozen=True)
class Camera:
    """An orbit eye: ``position`` and ``look_target`` [m] in the world frame, +z up."""

    position: np.ndarray
    look_target: np.ndarray
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, backward) unit vectors of the image."""
        b = self.position - self.look_target
        b = b / np.linalg.norm(b)
        r = np.cross(self.up, b)
        r = r / np.linalg.norm(r)
        return r, np.cross(b, r), b

    def project(self, points: np.ndarray, width: int, height: int,
                fov_y: float = RERUN_FOV_Y) -> np.ndarray:
        """Pinhole projection of (N, 3) world points [m] to (N, 2) pixel coordinates (x right,
        y down) of a ``width`` × ``height`` view: ``x = W/2 + f (p·r)/z``,
        ``y = H/2 − f (p·u)/z``, ``f = (H/2)/tan(fov_y/2)``, z the depth along −b."""
        r, u, b = self.axes()
        d = np.asarray(points, dtype=float).reshape(-1, 3) - self.position
        depth = -(d @ b)
        f = 0.5 * height / np.tan(fov_y / 2)
        return np.stack([0.5 * width + f * (d @ r) / depth,
                         0.5 * height - f * (d @ u) / depth], axis=1)


def frame_camera(points: np.ndarray, direction=EYE_DIRECTION, fov_y: float = RERUN_FOV_Y,
                 aspect: float = 1.2, margin: float = 1.08, pad: float = 0.1) -> Camera:
    """The closest eye looking along ``-direction`` that sees every point with ``pad`` [m]
    around it (the arm's volume around its link origins), the points centred in the image.

    With camera axes (right r, up u, backward b), an eye at ``c + a·r + e·u + d·b`` (c: the
    bounding-box centre) and a point at offset p, the padded point is in the frustum when
    ``|p·r − a| + pad ≤ T_r (d − p·b − pad)`` and ``|p·u − e| + pad ≤ T_u (d − p·b − pad)``
    with ``T_u = tan(fov_y/2)/margin``, ``T_r = aspect·T_u``. For a given d the feasible a is
    ``[max(p·r + pad − T_r δ), min(p·r − pad + T_r δ)]`` (δ = d − p·b − pad), non-empty from
    some d on: d is found by bisection and a, e are the middles of their intervals.
    points: (N, 3) [m]; fov_y: vertical field of view [rad]; aspect: view width / height.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        pts = np.zeros((1, 3))
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    r, u, b = Camera(np.asarray(direction, dtype=float), np.zeros(3)).axes()
    p = pts - centre
    pr, pu, pb = p @ r, p @ u, p @ b
    t_u = np.tan(fov_y / 2) / margin
    t_r = aspect * t_u
    # x ± pad ∓ t δ = (x ± t p·b) ± pad ∓ t (d − pad): the extremes over the points do not
    # depend on d, so each bisection step below is scalar arithmetic
    right = (float(np.max(pr + t_r * pb)), float(np.min(pr - t_r * pb)), t_r)
    up = (float(np.max(pu + t_u * pb)), float(np.min(pu - t_u * pb)), t_u)

    def interval(d: float, axis: tuple[float, float, float]) -> tuple[float, float]:
        hi, lo, t = axis
        return hi + pad - t * (d - pad), lo - pad + t * (d - pad)

    def feasible(d: float) -> bool:
        lo_r, hi_r = interval(d, right)
        lo_u, hi_u = interval(d, up)
        return lo_r <= hi_r and lo_u <= hi_u

    near, far = 0.0, 1.0
    while not feasible(far):
        near, far = far, 2.0 * far
    for _ in range(50):
        mid = 0.5 * (near + far)
        near, far = (near, mid) if feasible(mid) else (mid, far)
    d = max(far, 0.5)
    a = 0.5 * sum(interval(d, right))
    e = 0.5 * sum(interval(d, up))
    target = centre + a * r + e * u
    return Camera(position=target + d * b, look_target=target)


_AXES6 = np.vstack([np.eye(3), -np.eye(3)])  # ±x, ±y, ±z


def scene_points(rec: StepRecord) -> np.ndarray:
    """Points a camera must see at one step: links, end effector, goal, obstacle extremes."""
    r = rec.obstacle_radii[:, None, None] * _AXES6[None]
    obstacles = (rec.obstacle_centers[:, None, :] + r).reshape(-1, 3)
    return np.vstack([rec.link_positions, rec.ee_position, rec.goal_position, obstacles])


def replay_blueprint(scalar_names: Iterable[str] = (), joint_names: Iterable[str] = (),
                     camera: Camera | None = None, speed_limits: bool = True,
                     corners: Mapping[str, rrb.Corner2D] | None = None,
                     robot: str | None = None) -> rrb.Blueprint:
    """The replay layout: the 3-D scene (visual meshes; collision meshes and body spheres hidden
    but listed, so one click shows them; eye from ``camera``) beside one plot per quantity
    (joints, joint speed against the limits, then :func:`plot_groups` of ``scalar_names``).
    corners: each plot's legend corner by plot title (:func:`legend_corner`; the right top
    for a plot not named); robot: the URDF's robot name (its collision meshes are hidden; None:
    no robot model logged)."""
    eye = None
    if camera is not None:
        eye = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital,
                                position=camera.position.tolist(),
                                look_target=camera.look_target.tolist(), eye_up=list(camera.up))
    scene = rrb.Spatial3DView(
        name="scene", origin="/world",
        spatial_information=rrb.SpatialInformation(target_frame=WORLD_FRAME, show_axes=False),
        overrides={path: rrb.EntityBehavior(visible=False) for path in (
            *HIDDEN_BY_DEFAULT, *([COLLISION_MESHES.format(robot=robot)] if robot else []))},
        eye_controls=eye)
    joint_names = list(joint_names)
    corners = corners or {}

    def legend(title: str, n: int) -> rrb.PlotLegend:  # a legend of many series hides a plot
        return rrb.PlotLegend(corner=corners.get(title, LEGEND_CORNERS[0]),
                              visible=n <= MAX_LEGEND)

    plots = [rrb.TimeSeriesView(name=JOINTS_PLOT, origin="/joints",
                                plot_legend=legend(JOINTS_PLOT, len(joint_names)))]
    if joint_names:
        title = speed_plot(speed_limits)
        plots.append(rrb.TimeSeriesView(name=title, origin="/joint_speed",
                                        plot_legend=legend(title, len(joint_names))))
    for title, names in plot_groups(scalar_names):
        plots.append(rrb.TimeSeriesView(name=title, origin="/metrics",
                                         contents=[f"/metrics/{n}" for n in names],
                                         plot_legend=legend(title, len(names))))
    return rrb.Blueprint(
        rrb.Horizontal(scene, rrb.Grid(*plots, grid_columns=2), column_shares=[3, 2]),
        # the plots' x-axis in simulated seconds (the "step" timeline labels it #0, #1, ...)
        rrb.TimePanel(state="collapsed", timeline="time"),
        rrb.SelectionPanel(state="collapsed"), rrb.BlueprintPanel(state="collapsed"))


def speed_plot(speed_limits: bool) -> str:
    """The joint-speed plot's title: against the limits, or raw without them."""
    return "joint speed / limit" if speed_limits else "joint speed [rad/s]"


def default_blueprint() -> rrb.Blueprint:
    """:func:`replay_blueprint` before any step is known (joint plot and scene only)."""
    return replay_blueprint()


def _log_styles(rec, info: RunInfo) -> None:
    """The static entities: every world entity lives in the named frame "world" (the view's
    target frame); styles are static so the per-step columns carry only numbers."""
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

    if len(info.velocity_limits):
        rec.log("/joint_speed/limit", rr.SeriesLines(colors=_LIMIT_RGBA, names="limit",
                                                     widths=2.0), static=True)


#: A flush waits at most this long [s] in slices of FLUSH_SLICE [s]: rerun's file sink that
#: failed (a full disk) never acknowledges a flush, and one unbounded native wait would hold the
#: process past SIGTERM and Ctrl-C (signal handlers run between the slices).
FLUSH_TIMEOUT, FLUSH_SLICE = 30.0, 0.25
#: Streams whose file sink failed, kept referenced: closing or collecting them waits on the
#: sink forever (see :func:`_release`).
_STUCK: list = []


def bounded_flush(stream, path: Path, timeout: float = FLUSH_TIMEOUT) -> None:
    """Flush ``stream`` (writing ``path``) to disk, waiting at most ``timeout`` [s]. A flush
    that does not finish while the disk of ``path`` has less than ``LOW_SPACE`` bytes free is
    the file sink's failure (a full disk): ``OSError(ENOSPC)`` at once; otherwise RuntimeError
    after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            stream.flush(timeout_sec=FLUSH_SLICE)
            return
        except RuntimeError:  # "Flush timed out"
            free = free_bytes(path)
            if free is not None and free < LOW_SPACE:
                raise OSError(errno.ENOSPC, "No space left on device", str(path)) from None
            if time.monotonic() > deadline:
                raise


def _release(stream, failed: bool) -> None:
    """Close ``stream``'s file. A stream whose file sink failed never finishes closing (nor
    does rerun's own shutdown at exit): it is closed in a daemon thread given
    ``FLUSH_SLICE`` × 8 s, then left open, referenced, and rerun's exit-time shutdown is
    dropped, so the process ends."""
    if not failed:
        stream.disconnect()
        return
    closer = threading.Thread(target=stream.disconnect, daemon=True, name="rerun-close")
    closer.start()
    closer.join(8 * FLUSH_SLICE)
    if closer.is_alive():
        _STUCK.append(stream)
        rr.unregister_shutdown()


class RerunRecorder:
    """Write one episode to a Rerun ``.rrd`` file (layout in the module docstring).

    path: output file (created, with its parent directories; an existing ``path`` or
    ``<path>.active`` raises FileExistsError unless overwrite=True).
    batch, max_wait: buffered steps are sent column-wise (``send_columns``, about 40 entities)
    and flushed to disk when ``batch`` steps are buffered or ``max_wait`` wall seconds have
    passed since the last send, whichever comes first: a killed run loses at most that much.
    Each send costs a fixed ~10 ms (one Arrow chunk per entity), so rare sends are what keeps
    the recorder cheap: logging row by row costs ~2 ms per step.
    application_id: Rerun application id.
    """

    def __init__(self, path: str | os.PathLike, batch: int = 500, max_wait: float = 1.0,
                 application_id: str = "tamedpuma", overwrite: bool = False):
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        if not max_wait > 0:
            raise ValueError(f"max_wait must be > 0 s, got {max_wait}")
        self.path = Path(path)
        self.active_path = active_path(path)
        self.batch = int(batch)
        self.max_wait = float(max_wait)
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
        # The layout needs the scalar names and the scene's extent: sent with the first step
        # (camera framing the start) and again on close (framing the whole episode).
        rec.save(self.active_path)
        self._rec = rec
        rec.send_recording_name(f"{info.method}/{info.scenario_name}/seed{info.seed}")
        rec.send_property("run", rr.AnyValues(**info.metadata()))
        rec.log("/config", rr.TextDocument(info.config_yaml, media_type=rr.MediaType.TEXT),
                static=True)

        _log_styles(rec, info)
        self._log_robot(rec, info)
        self._points: list[np.ndarray] = []  # what the camera must frame [m]
        self._last: StepRecord | None = None  # the last step (its scene frames the camera)
        self._pending: list[StepRecord] = []  # steps not yet in the column buffers
        self._scalar_names: list[str] = []
        self._columns: _Columns | None = None  # the steps not sent yet, one row each
        self._ee_path = _Columns()  # every end-effector point so far (the path strips' source)
        self._samples: list[tuple] = []  # (t, q, speed, scalars) every FRAME_EVERY steps
        self._count = 0  # steps sent
        self._failed = False  # a write failed: the file keeps its .active name
        self._last_send = time.monotonic()

    def _log_robot(self, rec, info: RunInfo) -> None:
        """The robot model from the URDF (static) and the joints whose angles animate it; a
        missing URDF gives a replay without the robot (with a warning)."""
        self._joints = []
        self._root = None
        self._root_index = None
        self._robot = None
        if Path(info.urdf_path).is_file():
            rec.log_file_from_path(info.urdf_path, entity_path_prefix="/world", static=True)
            tree = _urdf_tree(info.urdf_path)
            self._joints = [tree.get_joint_by_name(n) for n in info.joint_names]
            if any(j is None for j in self._joints):
                missing = [n for n, j in zip(info.joint_names, self._joints) if j is None]
                raise ValueError(f"joints {missing} not in {info.urdf_path}")
            self._root, self._robot = tree.root_link().name, tree.name
            if self._root in info.link_names:
                self._root_index = info.link_names.index(self._root)
            else:  # no pose for the root link: base at the world origin
                rec.log("/world/tf/base", rr.Transform3D(
                    parent_frame=WORLD_FRAME, child_frame=self._root), static=True)
        else:
            warnings.warn(f"URDF {info.urdf_path} not found: the replay has no robot model",
                          stacklevel=3)

    def write(self, rec: StepRecord) -> None:
        """Buffer one step; send the buffer when it holds ``batch`` steps or ``max_wait``
        seconds have passed since the last send. The step is kept as it is and copied into
        the column buffers just before the send, all buffered steps back to back (the same
        columns, at less cost than one step between two control steps)."""
        if self._rec is None:
            raise RuntimeError("RerunRecorder.write before open")
        if self._columns is None:  # the first step: its scalar names fix the plots of the layout
            self._scalar_names = list(rec.scalars)
            self._send_blueprint()
            self._columns = _Columns()
            self._last_send = time.monotonic()
        self._pending.append(rec)
        self._last = rec
        if (self._columns.n + len(self._pending) >= self.batch
                or time.monotonic() - self._last_send >= self.max_wait):
            try:
                self._send()
            except (OSError, RuntimeError) as exc:  # the file sink failed (a full disk)
                self._failed = True
                raise write_error(self.active_path, exc, self._count) from exc

    def _take_pending(self) -> None:
        """Copy the buffered steps into the column buffers, in order: one stacked array per
        column (the same rows, at a fraction of the cost of copying step by step)."""
        pending, cols, root = self._pending, self._columns, self._root_index
        if not pending:
            return
        first = self._count + cols.n  # the step index (in this recording) of pending[0]
        for k in range(-first % FRAME_EVERY, len(pending), FRAME_EVERY):
            self._points.append(scene_points(pending[k]))
        names = self._scalar_names
        ee = np.array([r.ee_position for r in pending])
        rows = {"step": [r.step for r in pending], "t": [r.t for r in pending],
                "q": [r.q for r in pending], "qd": [r.qd for r in pending], "ee": ee,
                "goal_position": [r.goal_position for r in pending],
                "goal_quaternion": [r.goal_quaternion for r in pending],
                "body_spheres": [r.body_sphere_centers for r in pending],
                "scalars": [[r.scalars.get(name, np.nan) for name in names] for r in pending]}
        if root is not None:
            rows["root_position"] = [r.link_positions[root] for r in pending]
            rows["root_quaternion"] = [r.link_quaternions[root] for r in pending]
        cols.extend(**{name: np.array(v, dtype=float) for name, v in rows.items()})
        cols.obstacles.extend((r.obstacle_centers.copy(), r.obstacle_radii.copy())
                              for r in pending)
        self._ee_path.extend(ee=ee)
        pending.clear()

    def close(self, complete: bool, summary: Mapping[str, object]) -> None:
        """Send buffered steps, log the outcome (static ``/summary``) and close the file.

        The file is renamed to ``path`` only if it ends with the RRD footer: a write that
        failed (the file sink reports a full disk on stderr, not always to the caller) leaves
        ``<path>.active``, readable up to the failure, and raises a one-line error."""
        stream = self._rec
        if stream is None:
            return
        finished = False
        try:
            if self._failed:
                return
            self._send(flush=False)  # flushed below, with the layout and the summary
            if self._last is not None:
                self._points.append(scene_points(self._last))
            self._send_blueprint()
            fields = {k: (v if isinstance(v, (bool, int, float, str)) else str(v))
                      for k, v in summary.items()}
            stream.log("/summary", rr.AnyValues(**{**fields, "complete": bool(complete),
                                                   "recorded_steps": self._count}), static=True)
            bounded_flush(stream, self.active_path)
            finished = True
        except (OSError, RuntimeError) as exc:
            self._failed = True
            raise write_error(self.active_path, exc, self._count) from exc
        finally:
            _release(stream, self._failed)
            self._rec = None
            if finished and not has_footer(self.active_path):
                self._failed = True
                raise write_error(self.active_path, OSError("the file has no RRD footer"),
                                  self._count)
            if not self._failed:
                os.replace(self.active_path, self.path)

    def blueprint(self) -> rrb.Blueprint:
        """The layout for what was written so far (camera framing every point seen)."""
        info = self._info
        camera = frame_camera(np.vstack(self._points)) if self._points else None
        return replay_blueprint(self._scalar_names, info.joint_names, camera,
                                speed_limits=len(info.velocity_limits) > 0,
                                corners=self._legend_corners(),
                                robot=getattr(self, "_robot", None))

    def _legend_corners(self) -> dict[str, rrb.Corner2D]:
        """Each plot's legend corner (:func:`legend_corner`) from the samples kept so far (every
        ``FRAME_EVERY``-th step; none before the first send: every legend right top)."""
        if not self._samples:
            return {}
        t, q, speed, values = (np.concatenate(part) for part in zip(*self._samples))
        info = self._info
        names = list(info.joint_names)
        corners = {JOINTS_PLOT: legend_corner(t, q, names)}
        limits = len(info.velocity_limits) > 0
        if limits:  # the limit line (1) is a series of the plot too
            speed = np.column_stack([speed, np.ones(len(t))])
        corners[speed_plot(limits)] = legend_corner(t, speed, names + ["limit"] * limits)
        index = {name: j for j, name in enumerate(self._scalar_names)}
        for title, group in plot_groups(self._scalar_names):
            corners[title] = legend_corner(t, values[:, [index[n] for n in group]], group)
        return corners

    def _send_blueprint(self) -> None:
        self._rec.send_blueprint(self.blueprint(), make_active=True, make_default=True)

    # -- column-wise sending -----------------------------------------------------------------

    def _send(self, flush: bool = True) -> None:
        cols = self._columns
        if cols is None:
            return
        self._take_pending()
        if not cols.n:
            return
        self._columns = _Columns()
        self._last_send = time.monotonic()
        stream, info = self._rec, self._info
        n = cols.n
        c = cols.arrays()
        steps, times = c["step"].astype(np.int64), c["t"]
        keep = np.arange(-self._count % FRAME_EVERY, n, FRAME_EVERY)  # the legends' samples
        index = [rr.TimeColumn("step", sequence=steps), rr.TimeColumn("time", duration=times)]

        def send(entity: str, columns) -> None:
            stream.send_columns(entity, indexes=index, columns=columns)

        q = c["q"]
        if self._root_index is not None:
            send("/world/tf/base", rr.Transform3D.columns(
                translation=c["root_position"], quaternion=c["root_quaternion"],
                parent_frame=[WORLD_FRAME] * n, child_frame=[self._root] * n))
        for j, joint in enumerate(self._joints):
            send(f"/world/tf/{joint.name}", joint.compute_transform_columns(q[:, j], clamp=False))

        n_obs = [len(r) for _, r in cols.obstacles]
        radii = np.concatenate([r for _, r in cols.obstacles])
        send("/world/obstacles", rr.Ellipsoids3D.columns(
            centers=np.concatenate([o for o, _ in cols.obstacles]).reshape(-1, 3),
            half_sizes=np.repeat(radii, 3).reshape(-1, 3)).partition(n_obs))
        k = len(info.body_sphere_radii)
        if k:
            send("/world/body_spheres", rr.Ellipsoids3D.columns(
                centers=c["body_spheres"].reshape(-1, 3)).partition([k] * n))
        send("/world/goal", rr.Ellipsoids3D.columns(
            centers=c["goal_position"], quaternions=c["goal_quaternion"]))
        send("/world/ee", rr.Points3D.columns(positions=c["ee"]))
        self._send_path(stream, steps, times)

        for j, name in enumerate(info.joint_names):
            send(f"/joints/{name}", rr.Scalars.columns(scalars=q[:, j]))
        speed = np.abs(c["qd"])
        if len(info.velocity_limits):
            speed = speed / info.velocity_limits
            send("/joint_speed/limit", rr.Scalars.columns(scalars=np.ones(n)))
        for j, name in enumerate(info.joint_names):
            send(f"/joint_speed/{name}", rr.Scalars.columns(scalars=speed[:, j]))
        values = c["scalars"].astype(float)
        for j, name in enumerate(self._scalar_names):
            send(f"/metrics/{name}", rr.Scalars.columns(scalars=values[:, j]))
        self._samples.append((times[keep], q[keep], speed[keep], values[keep]))
        if flush:  # on disk before the next batch: a killed run loses only the buffer
            bounded_flush(stream, self.active_path)

    def _send_path(self, stream, steps, times) -> None:
        """EE path: strip b covers steps [b·B, (b+1)·B] (B = PATH_BLOCK), so strips join up and
        each step re-sends at most B + 1 points: the row of step g in block b holds the path
        points [max(b·B − 1, 0), g]."""
        path = self._ee_path.arrays()["ee"]
        first = self._count
        g = np.arange(first, first + len(steps))
        blocks = g // PATH_BLOCK
        for block in np.unique(blocks).tolist():
            if block * PATH_BLOCK >= first:  # the block starts in this batch: its style
                stream.log(f"/world/ee_path/{block:05d}", rr.CoordinateFrame(WORLD_FRAME),
                           rr.LineStrips3D.from_fields(colors=_EE_RGBA, radii=0.003),
                           static=True)
            rows = np.flatnonzero(blocks == block)
            start = max(block * PATH_BLOCK - 1, 0)
            ends = g[rows] + 1  # each row: path[start:end]
            lengths = ends - start
            offsets = np.zeros(len(rows) + 1, dtype=np.int32)
            np.cumsum(lengths, out=offsets[1:])
            # point j of the flattened strips is path[start + j − offsets[row of j]]
            flat = np.arange(offsets[-1]) - np.repeat(offsets[:-1], lengths) + start
            strips = pa.ListArray.from_arrays(
                pa.array(offsets, type=pa.int32()),
                Vec3DBatch(path[flat]).as_arrow_array(), type=LineStrip3DBatch._ARROW_DATATYPE)
            stream.send_columns(
                f"/world/ee_path/{block:05d}",
                indexes=[rr.TimeColumn("step", sequence=steps[rows].tolist()),
                         # as lists, as before: rerun rounds a list's seconds to the nearest
                         # ns but truncates an array's (the other entities' "time")
                         rr.TimeColumn("time", duration=times[rows].tolist())],
                columns=rr.LineStrips3D.columns(strips=strips))
        self._count += len(steps)


_TREES: dict[tuple[str, int, int], UrdfTree] = {}


#: the last bytes of a finished RRD file (the footer's magic, then its version)
RRD_FOOTER_MAGIC = b"RRF2FOOT"


def has_footer(path: str | os.PathLike) -> bool:
    """True if the RRD file ``path`` ends with its footer (written when the stream closes)."""
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - 64))
            return RRD_FOOTER_MAGIC in fh.read()
    except OSError:
        return False


def _urdf_tree(path: str) -> UrdfTree:
    """The parsed URDF at ``path``, parsed once per file version (path, mtime, size): the tree
    is only read (joints, root link, transforms), and parsing costs a few ms per episode."""
    st = os.stat(path)
    key = (os.fspath(path), st.st_mtime_ns, st.st_size)
    tree = _TREES.get(key)
    if tree is None:
        if len(_TREES) > 8:
            _TREES.clear()
        tree = _TREES[key] = UrdfTree.from_file_path(path)
    return tree


class _Columns:
    """Growable column buffers, one row per step: ``extend(name=rows, ...)`` copies m rows into
    rows ``n … n+m−1`` of each column (allocated at the first rows from their shape, grown to at
    least twice its size when full); ``arrays()`` returns the filled rows. ``obstacles``: per-row
    (centres, radii) (their count may change between steps)."""

    def __init__(self):
        self.n = 0
        self._cols: dict[str, np.ndarray] = {}
        self.obstacles: list[tuple[np.ndarray, np.ndarray]] = []

    def extend(self, **columns: np.ndarray) -> None:
        """Append m rows at once: each value an (m, ...) float array, m the same for all."""
        cols, i = self._cols, self.n
        m = 0
        for name, value in columns.items():
            m = len(value)
            col = cols.get(name)
            if col is None:
                col = cols[name] = np.empty((max(16, m), *value.shape[1:]))
            elif i + m > len(col):
                grown = np.empty((max(2 * len(col), i + m), *col.shape[1:]))
                grown[:i] = col[:i]
                col = cols[name] = grown
            col[i:i + m] = value
        self.n = i + m

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: col[:self.n] for name, col in self._cols.items()}


def reference_label_anchor(points: np.ndarray,
                           drop: float = REFERENCE_LABEL_DROP) -> np.ndarray:
    """Where the reference path's label is drawn [m]: ``drop`` [m] below the path's end (the
    goal), the label's text under it. The tasks' arm comes to the goal from above and behind,
    so below it no link passes at any instant; drawn on the strip itself the label sat at the
    strip's middle, over the arm as it passed, and at the path's start it covers the hand
    while the run begins. points: (T, 3) [m]."""
    end = np.asarray(points, dtype=float).reshape(-1, 3)[-1]
    return end - np.array([0.0, 0.0, drop])


def write_reference_overlay(path: str | os.PathLike, recording_id: str, points: np.ndarray,
                            label: str = "PUMA without obstacles",
                            application_id: str = "tamedpuma") -> Path:
    """A small ``.rrd`` that adds a reference end-effector path (static ``LineStrips3D`` on
    :data:`REFERENCE_PATH`) to the recording ``recording_id``: the viewer merges files that share
    application and recording ids, so the run's own file is never modified. The strip keeps its
    label for hover and selection but does not draw it; the drawn label is a point of its own
    (``REFERENCE_PATH/label``) at :func:`reference_label_anchor`. points: (T, 3) [m]."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    points = np.asarray(points, dtype=float)
    rec = rr.RecordingStream(application_id, recording_id=recording_id)
    rec.save(path)
    rec.log(REFERENCE_PATH, rr.CoordinateFrame(WORLD_FRAME), rr.LineStrips3D(
        [points], colors=_REFERENCE_RGBA, radii=0.004, labels=label, show_labels=False),
        static=True)
    rec.log(f"{REFERENCE_PATH}/label", rr.CoordinateFrame(WORLD_FRAME), rr.Points3D(
        [reference_label_anchor(points)], colors=_REFERENCE_RGBA, radii=0.004, labels=label,
        show_labels=True), static=True)
    try:
        bounded_flush(rec, path)
    except (OSError, RuntimeError) as exc:
        _release(rec, failed=True)
        raise write_error(path, exc, 0) from exc
    rec.disconnect()
    return path
