"""MCAP recorder (Foxglove schemas), crash-safe: ``<path>.active`` while running, ``<path>`` after.

Layout of a file written by :class:`McapRecorder` (all times are simulated time, log_time [ns]):

===============  =======================  ===================================================
topic            schema                   content per step
===============  =======================  ===================================================
/joint_states    foxglove.JointStates     q [rad] → position, qd [rad/s] → velocity,
                                          qdd_cmd [rad/s²] → acceleration
/tf              foxglove.FrameTransforms world → each link (simulator truth)
/ee_pose         foxglove.PoseInFrame     end-effector pose in ``world``
/scene           foxglove.SceneUpdate     entities ``obstacles``, ``goal``, ``body_spheres``
/scalars         JSON schema              {"step", "t", <every scalar>}
===============  =======================  ===================================================

Metadata records: ``tamedpuma.run_info`` (the :class:`RunInfo` fields), ``tamedpuma.app.config``
(``yaml``), and on close ``tamedpuma.summary`` (``complete``: "true"/"false", ``summary_json``).
Attachments: ``config.yaml`` and the URDF (``model.urdf``).

Crash safety: the file is written as ``<path>.active`` and renamed on :meth:`McapRecorder.close`.
Every ``flush_every`` steps the current chunk is finished and flushed to disk, so a killed run
leaves a ``.active`` file that :func:`tamedpuma.recording.read_mcap` reads up to its last flush.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
import warnings
from collections.abc import Mapping
from pathlib import Path

import foxglove
from foxglove.channels import (
    FrameTransformsChannel,
    JointStatesChannel,
    PoseInFrameChannel,
    SceneUpdateChannel,
)
from foxglove.mcap import MCAPWriteOptions
from foxglove.messages import (
    Color,
    FrameTransform,
    FrameTransforms,
    JointState,
    JointStates,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from tamedpuma.errors import DiskFullError, LogError, LogExistsError, TamedPumaError
from tamedpuma.paths import free_bytes, no_space
from tamedpuma.records import RunInfo, StepRecord

from ..runlog import ACTIVE_SUFFIX, ATTACH_URDF, META_CONFIG, META_RUN_INFO, META_SUMMARY

WORLD_FRAME = "world"
#: the logger the SDK reports a failed write of a logged message to (it does not raise)
SDK_SINK_LOGGER = "foxglove.log_sink_set"
ATTACH_CONFIG = "config.yaml"
GOAL_MARKER_RADIUS = 0.03  # [m], display only

_OBSTACLE_COLOR = dict(r=0.85, g=0.2, b=0.2, a=0.6)
_GOAL_COLOR = dict(r=0.1, g=0.8, b=0.2, a=0.9)
_BODY_COLOR = dict(r=0.2, g=0.4, b=0.9, a=0.25)
_IDENTITY = dict(x=0.0, y=0.0, z=0.0, w=1.0)


def active_path(path: str | os.PathLike) -> Path:
    """The in-progress name of a log: ``<path>.active``."""
    return Path(f"{os.fspath(path)}{ACTIVE_SUFFIX}")


def prepare_output(path: Path, active: Path, overwrite: bool) -> None:
    """Make room for a new log at ``path`` (written as ``active`` until closed): refuse to
    replace an existing file unless ``overwrite``; create the parent folder."""
    for existing in (path, active):
        if existing.exists() and not overwrite:
            raise LogExistsError(f"{existing} exists (a run was already written there: choose "
                                 f"another run folder, e.g. hydra.run.dir, or pass "
                                 f"overwrite=True to replace it)")
    path.unlink(missing_ok=True)
    path.parent.mkdir(parents=True, exist_ok=True)


def _stamp(t: float) -> tuple[int, Timestamp]:
    """Simulated time t [s] as (log_time [ns], foxglove Timestamp)."""
    ns = int(round(t * 1e9))
    return ns, Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


class _Spheres:
    """Sphere primitives of one colour, identity orientation, size = diameter per axis [m].

    The constant parts (colour, orientation, one size per radius) are built once and shared by
    every step's messages (each message copies them when it is built): per sphere only the
    position is new."""

    def __init__(self, color: dict):
        self.color = Color(**color)
        self.identity = Quaternion(**_IDENTITY)
        self._sizes: dict[float, Vector3] = {}

    def size(self, r: float) -> Vector3:
        size = self._sizes.get(r)
        if size is None:
            d = 2.0 * r
            size = self._sizes[r] = Vector3(x=d, y=d, z=d)
        return size

    def __call__(self, centers, radii) -> list[SpherePrimitive]:
        color, identity, size = self.color, self.identity, self.size
        return [SpherePrimitive(pose=Pose(position=Vector3(x=x, y=y, z=z), orientation=identity),
                                size=size(r), color=color)
                for (x, y, z), r in zip(centers.tolist(), radii.tolist())]


class _LastSpheres(_Spheres):
    """:class:`_Spheres` that hands back the previous step's primitives when the centres and
    radii are those of the previous step (static obstacles: the same messages, not rebuilt;
    1000 obstacles are 3000 objects per step)."""

    def __init__(self, color: dict):
        super().__init__(color)
        self._key: tuple[bytes, bytes] | None = None
        self._last: list[SpherePrimitive] = []

    def __call__(self, centers, radii) -> list[SpherePrimitive]:
        key = (centers.tobytes(), radii.tobytes())
        if key != self._key:
            self._last, self._key = super().__call__(centers, radii), key
        return self._last


class McapRecorder:
    """Write one episode to an MCAP file that Foxglove opens (see the module docstring).

    path: final file name (``.mcap``). flush_every: finish and flush the current chunk every this
    many steps (bounds what a killed run loses). compression: "zstd", "lz4" or None.
    overwrite: replace an existing ``path`` or ``<path>.active``; otherwise :meth:`open` raises
    FileExistsError (an ``.active`` file is an interrupted run: recover or delete it first).

    Scalars that are not finite (NaN, ±inf) are written as JSON ``null`` (strict JSON, so
    Foxglove parses them) and read back as NaN.
    """

    def __init__(self, path: str | os.PathLike, flush_every: int = 100,
                 compression: str | None = "zstd", overwrite: bool = False):
        if flush_every < 1:
            raise ValueError(f"flush_every must be >= 1, got {flush_every}")
        self.path = Path(path)
        self.active_path = active_path(path)
        self.flush_every = int(flush_every)
        self._compression = {
            "zstd": foxglove.mcap.MCAPCompression.Zstd,
            "lz4": foxglove.mcap.MCAPCompression.Lz4,
            None: None,
        }[compression]
        self.overwrite = bool(overwrite)
        self._writer = None
        self._info: RunInfo | None = None
        self._count = 0

    # -- Recorder protocol -------------------------------------------------------------------

    def open(self, info: RunInfo) -> None:
        """Create ``<path>.active``, the channels, and write the run metadata and attachments."""
        if self._writer is not None:
            raise RuntimeError("McapRecorder is already open")
        prepare_output(self.path, self.active_path, self.overwrite)
        self._info = info
        self._ctx = foxglove.Context()  # private context: recorders never see each other's data
        options = MCAPWriteOptions(compression=self._compression, profile="",
                                   chunk_size=4 * 1024 * 1024)
        self._writer = foxglove.open_mcap(self.active_path, allow_overwrite=True,
                                          context=self._ctx, writer_options=options)
        self._joints = JointStatesChannel("/joint_states", context=self._ctx)
        self._tf = FrameTransformsChannel("/tf", context=self._ctx)
        self._ee = PoseInFrameChannel("/ee_pose", context=self._ctx)
        self._scene = SceneUpdateChannel("/scene", context=self._ctx)
        self._scalars = foxglove.Channel(
            "/scalars", context=self._ctx,
            schema={"type": "object", "title": "tamedpuma.Scalars",
                    "properties": {"step": {"type": "integer"}, "t": {"type": "number"}},
                    "additionalProperties": {"type": ["number", "null"]}})
        self._count = 0
        self._failed = False  # a write failed (a full disk): the file is kept as .active
        self._pending: list[StepRecord] = []  # steps taken since the last flush
        self._in_chunk = False  # True while _log_pending runs (an exception may cut it short)
        self._obstacle_spheres = _LastSpheres(_OBSTACLE_COLOR)
        self._body_spheres = _Spheres(_BODY_COLOR)
        self._goal_style = _Spheres(_GOAL_COLOR)
        self._body_radii = info.body_sphere_radii
        self._scalar_keys: dict[str, str] = {}  # scalar name -> its JSON key
        self._scalar_names: tuple[str, ...] | None = None  # the names _scalar_template holds
        self._scalar_template = ""

        meta = info.metadata()
        meta["created_unix_s"] = repr(time.time())
        self._writer.write_metadata(META_RUN_INFO, meta)
        self._writer.write_metadata(META_CONFIG, {"yaml": info.config_yaml or "# (empty)"})
        now = time.time_ns()
        self._writer.attach(log_time=0, create_time=now, name=ATTACH_CONFIG,
                            media_type="application/yaml", data=info.config_yaml.encode())
        urdf = Path(info.urdf_path)
        if urdf.is_file():
            self._writer.attach(log_time=0, create_time=now, name=ATTACH_URDF,
                                media_type="application/xml", data=urdf.read_bytes())
        else:
            warnings.warn(f"URDF {urdf} not found: not embedded in {self.path.name}",
                          stacklevel=2)
        self._writer.flush()

    def write(self, rec: StepRecord) -> None:
        """Take one step; every ``flush_every`` steps log the steps taken since the last flush
        on every channel, in order, and flush them (as one chunk) to disk.

        Logging a batch back to back instead of one step between two control steps writes the
        same messages (same log times, same order) at about half the cost (the writer's code
        stays in the CPU's caches), and loses nothing more when the run is killed: steps after
        the last flush were never on disk either way."""
        if self._writer is None or self._info is None:
            raise RuntimeError("McapRecorder.write before open")
        self._pending.append(rec)
        self._count += 1
        if self._count % self.flush_every == 0:
            held = _HeldWriteErrors()
            sink = logging.getLogger(SDK_SINK_LOGGER)
            sink.addFilter(held)
            try:
                self._log_pending()
                self._writer.flush()
                if held.first is not None:
                    raise RuntimeError(held.first)
            except (OSError, RuntimeError) as exc:
                self._failed = True
                raise write_error(self.active_path, exc, self._count) from exc
            finally:
                sink.removeFilter(held)

    def _log_pending(self) -> None:
        self._in_chunk = True
        for rec in self._pending:
            self._log(rec)
        self._pending.clear()
        self._in_chunk = False

    def _log(self, rec: StepRecord) -> None:
        """Log one step on every channel."""
        info = self._info
        ns, stamp = _stamp(rec.t)

        self._joints.log(JointStates(timestamp=stamp, joints=[
            JointState(name=n, position=p, velocity=v, acceleration=a)
            for n, p, v, a in zip(info.joint_names, rec.q.tolist(), rec.qd.tolist(),
                                  rec.qdd_cmd.tolist())]), log_time=ns)

        self._tf.log(FrameTransforms(transforms=[
            FrameTransform(timestamp=stamp, parent_frame_id=WORLD_FRAME, child_frame_id=name,
                           translation=Vector3(x=p[0], y=p[1], z=p[2]),
                           rotation=Quaternion(x=o[0], y=o[1], z=o[2], w=o[3]))
            for name, p, o in zip(info.link_names, rec.link_positions.tolist(),
                                  rec.link_quaternions.tolist())]), log_time=ns)

        p, o = rec.ee_position.tolist(), rec.ee_quaternion.tolist()
        self._ee.log(PoseInFrame(timestamp=stamp, frame_id=WORLD_FRAME, pose=Pose(
            position=Vector3(x=p[0], y=p[1], z=p[2]),
            orientation=Quaternion(x=o[0], y=o[1], z=o[2], w=o[3]))), log_time=ns)

        g, go = rec.goal_position.tolist(), rec.goal_quaternion.tolist()
        goal_style = self._goal_style
        goal = SpherePrimitive(
            pose=Pose(position=Vector3(x=g[0], y=g[1], z=g[2]),
                      orientation=Quaternion(x=go[0], y=go[1], z=go[2], w=go[3])),
            size=goal_style.size(GOAL_MARKER_RADIUS), color=goal_style.color)
        self._scene.log(SceneUpdate(entities=[
            SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id="obstacles",
                        spheres=self._obstacle_spheres(rec.obstacle_centers,
                                                       rec.obstacle_radii)),
            SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id="goal", spheres=[goal]),
            SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id="body_spheres",
                        spheres=self._body_spheres(rec.body_sphere_centers, self._body_radii)),
        ]), log_time=ns)

        self._scalars.log(self._scalars_json(rec), log_time=ns)

    def _scalars_json(self, rec: StepRecord) -> bytes:
        """``{"step": .., "t": .., <name>: <value or null>, ...}`` as ``json.dumps`` writes it
        (keys JSON-encoded once per name, floats by ``repr``, non-finite values as null).

        The keys are constant within a run: their text is a ``%``-template made once, which the
        step's values fill in when they are all finite (their sum is), else they are written one
        by one."""
        scalars = rec.scalars
        values = [float(v) for v in scalars.values()]
        names = tuple(scalars)
        if names != self._scalar_names:
            self._scalar_names = names
            self._scalar_template = "".join(
                ['{"step": %d, "t": %r'] + [f", {json.dumps(k).replace('%', '%%')}: %r"
                                             for k in names] + ["}"])
        if math.isfinite(sum(values)):  # (an overflowing sum takes the slow way: the same text)
            return (self._scalar_template % (int(rec.step), float(rec.t), *values)).encode()
        keys = self._scalar_keys
        parts = [f'{{"step": {int(rec.step)}, "t": {float(rec.t)!r}']
        for k, v in zip(names, values):
            key = keys.get(k)
            if key is None:
                key = keys[k] = json.dumps(k)
            parts.append(f"{key}: {v!r}" if math.isfinite(v) else f"{key}: null")
        return (", ".join(parts) + "}").encode()

    def close(self, complete: bool, summary: Mapping[str, object]) -> None:
        """Write the summary metadata, finish the file and rename it to ``path``.

        complete: False if the episode was interrupted. summary: JSON-serialisable values
        (non-serialisable ones are stored as their ``str``). A file whose writing failed (a
        full disk) keeps its ``.active`` name: readable up to its last flush, and incomplete.
        """
        if self._writer is None:
            return
        try:
            if self._failed:
                return
            if self._in_chunk:
                # a chunk cut short by an exception (the sweep's SIGTERM handler, Ctrl-C) while
                # its records were being logged: those before the interrupted one are logged
                # already, that one perhaps in part; logging the chunk again repeated them (a
                # killed run's log held steps 80-98 twice). The log ends there: the steps
                # after it were not flushed, which a killed run may lose.
                self._pending.clear()
                self._in_chunk = False
            self._log_pending()
            self._writer.write_metadata(META_SUMMARY, {
                "complete": "true" if complete else "false",
                "steps": str(self._count),
                "summary_json": json.dumps(dict(summary), default=_jsonable),
            })
        except (OSError, RuntimeError) as exc:
            self._failed = True
            raise write_error(self.active_path, exc, self._count) from exc
        finally:
            self._finish()

    def _finish(self) -> None:
        """Close the writer and the channels; rename the file unless a write failed."""
        writer, self._writer = self._writer, None
        try:
            writer.close()
        except (OSError, RuntimeError):
            self._failed = True
        for ch in (self._joints, self._tf, self._ee, self._scene, self._scalars):
            ch.close()
        if not self._failed:
            os.replace(self.active_path, self.path)


class _HeldWriteErrors(logging.Filter):
    """Holds back the SDK's warning for each message it could not write (a full disk fails
    every message after the first: one warning each, written to a log file on the same full
    disk); the batch's flush raises the failure, or the first warning becomes the error."""

    def __init__(self):
        super().__init__()
        self.first: str | None = None

    def filter(self, record: logging.LogRecord) -> bool:
        if self.first is None:
            self.first = record.getMessage()
        return False


def write_error(path: Path, exc: BaseException, steps: int) -> TamedPumaError:
    """A failed write of the log ``path`` after ``steps`` steps as a one-line error: a
    :class:`DiskFullError` (with the bytes per step written so far) when the file system is
    full, else a :class:`LogError` naming the writer's message."""
    if no_space(exc, path):
        size = path.stat().st_size if path.is_file() else 0
        per_step = size / steps if steps and size else None
        return DiskFullError(path, free_bytes(path), per_step=per_step)
    return LogError(f"cannot write {path}: {' '.join(str(exc).split())}")


def _jsonable(value):
    """JSON fallback for summary values: numpy scalars and arrays, else ``str``."""
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)
