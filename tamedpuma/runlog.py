"""The run log's MCAP format read back: :func:`read_mcap` → :class:`RunLog` of pandas DataFrames.

The names the writer (:mod:`tamedpuma.recording.mcap_writer`) and every reader share live here:
metadata records, the attachment, the ``.active`` suffix of a file still being written. This
module sits below the layers that read logs (PUMA's demonstration loader reads recorded runs'
``/ee_pose``, recording, analysis, replay), so none of them imports upwards.

:func:`read_mcap` scans the file front to back (no index needed), so it reads finished files and
``.active`` files left by a killed run alike: it keeps every complete chunk and stops at the first
unreadable record.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap_protobuf.decoder import DecoderFactory

from tamedpuma.errors import LogError

if TYPE_CHECKING:  # pandas is imported where a log is read: a run writing its summary needs
    import pandas as pd  # only SUMMARY_SCHEMA_VERSION (pandas: 0.9 s CPU of a process start)

ACTIVE_SUFFIX = ".active"  # a log still being written (or left by a killed run)
#: the version of a run's ``summary.json`` layout: 2 added ``schema_version``, ``suite``
#: ({name, version} or null) and ``machine``; a summary without the field is version 1
SUMMARY_SCHEMA_VERSION = 3
META_RUN_INFO = "tamedpuma.run_info"
META_CONFIG = "tamedpuma.app.config"
META_SUMMARY = "tamedpuma.summary"
ATTACH_URDF = "model.urdf"

_TOPICS = ("/joint_states", "/tf", "/ee_pose", "/scene", "/scalars")
_JSON_FIELDS = ("joint_names", "link_names", "body_sphere_radii", "velocity_limits")


@dataclass(frozen=True)
class RunLog:
    """One run read from an MCAP file.

    info: the RunInfo fields (``seed`` int, ``dt`` float [s], name lists as lists);
    config_yaml: resolved config; urdf: URDF text ("" if not embedded);
    complete: True only for a finished file whose run ended normally;
    summary: the run's summary (empty if the writer never closed);
    joints: index ``step``; columns t [s], q_0..q_6 [rad], qd_0..qd_6 [rad/s],
    qdd_cmd_0..qdd_cmd_6 [rad/s²];
    ee: index ``step``; columns t, x, y, z [m], qx, qy, qz, qw;
    scalars: index ``step``; columns t and every logged scalar;
    obstacles: long format, columns step, t, id, x, y, z, radius [m];
    read_error: why the scan stopped early (truncated/corrupt file), else None.
    """

    path: str
    info: dict
    config_yaml: str
    urdf: str
    complete: bool
    summary: dict
    joints: pd.DataFrame
    ee: pd.DataFrame
    scalars: pd.DataFrame
    obstacles: pd.DataFrame
    read_error: str | None = None
    metadata: dict = field(default_factory=dict)

    @property
    def n_steps(self) -> int:
        return len(self.joints)


@dataclass
class _Scan:
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    messages: dict = field(default_factory=dict)  # channel id -> list[Message]
    metadata: dict = field(default_factory=dict)
    attachments: dict = field(default_factory=dict)
    error: str | None = None
    footer: bool = False
    n_records: int = 0


_MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")  # opcode, length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK = struct.Struct("<QQQII")  # start, end, uncompressed size and CRC, compression's length
_READERS = {Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read,
            Opcode.METADATA: Metadata.read, Opcode.ATTACHMENT: Attachment.read}


def _scan(path: Path) -> _Scan:
    """Read every record up to the first unreadable one (a truncated or corrupt tail): a whole
    file by :func:`_scan_whole`, any other by the mcap library's stream reader, which says
    where and why it stops."""
    try:
        scan = _scan_whole(path)
    except Exception:  # noqa: BLE001 - the stream reader below reads what it can and says why
        scan = None
    return scan if scan is not None else _scan_stream(path)


def _scan_whole(path: Path) -> _Scan | None:
    """:func:`_scan_stream`'s result for a file that is whole (magic at both ends, a footer,
    every CRC right), or None: the records sliced from the bytes with ``struct`` and the
    messages built straight from each decompressed chunk, skipping the message indexes, which
    the stream reader parses field by field (3x slower over a run's log)."""
    data = Path(path).read_bytes()
    n = len(data)
    if not data.startswith(_MAGIC) or not data.endswith(_MAGIC):
        return None
    scan = _Scan()
    pos = len(_MAGIC)
    while pos + 9 <= n:
        opcode, length = _RECORD.unpack_from(data, pos)
        body, end = pos + 9, pos + 9 + length
        if end > n:
            return None
        if opcode == Opcode.CHUNK:
            if not _chunk_records(scan, data, body, end):
                return None
        elif opcode == Opcode.MESSAGE:
            _add_message(scan, data, body, end)
        elif opcode in _READERS:
            _add_record(scan, _READERS[opcode](ReadDataStream(BytesIO(data[body:end]))))
        elif opcode == Opcode.DATA_END:
            crc = int.from_bytes(data[body:body + 4], "little") if length >= 4 else 0
            if crc and crc != zlib.crc32(memoryview(data)[:pos]):
                return None
            scan.n_records += 1
        elif opcode == Opcode.FOOTER:
            scan.n_records += 1
            scan.footer = end == n - len(_MAGIC)
            return scan if scan.footer else None
        else:  # the indexes, statistics, header: nothing the log needs
            scan.n_records += 1
        pos = end
    return None


def _add_message(scan: _Scan, data: bytes, body: int, end: int) -> None:
    channel_id, sequence, log_time, publish_time = _MESSAGE.unpack_from(data, body)
    scan.messages.setdefault(channel_id, []).append(Message(
        channel_id=channel_id, sequence=sequence, log_time=log_time,
        publish_time=publish_time, data=data[body + 22:end]))
    scan.n_records += 1


def _add_record(scan: _Scan, rec) -> None:
    scan.n_records += 1
    if isinstance(rec, Message):
        scan.messages.setdefault(rec.channel_id, []).append(rec)
    elif isinstance(rec, Channel):
        scan.channels[rec.id] = rec
    elif isinstance(rec, Schema):
        scan.schemas[rec.id] = rec
    elif isinstance(rec, Metadata):
        scan.metadata[rec.name] = dict(rec.metadata)
    elif isinstance(rec, Attachment):
        scan.attachments[rec.name] = rec


def _chunk_records(scan: _Scan, data: bytes, body: int, end: int) -> bool:
    """The records of the chunk record ``data[body:end]`` into ``scan``; False where the chunk
    does not read whole (its CRC, a record past its end, a compression not at hand)."""
    _, _, size, crc, n_comp = _CHUNK.unpack_from(data, body)
    at = body + _CHUNK.size
    compression = data[at:at + n_comp].decode()
    at += n_comp
    n_data = int.from_bytes(data[at:at + 8], "little")
    packed = data[at + 8:at + 8 + n_data]
    if at + 8 + n_data > end:
        return False
    chunk = Chunk(compression=compression, data=packed, message_start_time=0,
                  message_end_time=0, uncompressed_crc=crc, uncompressed_size=size)
    stream, n = get_chunk_data_stream(chunk, validate_crc=True)
    inner = stream.read(n)
    pos = 0
    while pos < n:
        opcode, length = _RECORD.unpack_from(inner, pos)
        start, stop = pos + 9, pos + 9 + length
        if stop > n:
            return False
        if opcode == Opcode.MESSAGE:
            _add_message(scan, inner, start, stop)
        elif opcode in (Opcode.CHANNEL, Opcode.SCHEMA):
            _add_record(scan, _READERS[opcode](ReadDataStream(BytesIO(inner[start:stop]))))
        pos = stop
    return True


def _scan_stream(path: Path) -> _Scan:
    """Read every record up to the first unreadable one, with the mcap library's reader."""
    scan = _Scan()
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, validate_crcs=True).records:
                _add_record(scan, rec)
            scan.footer = True
        except Exception as exc:  # noqa: BLE001 - any parse failure ends the readable prefix
            if f"length {2**64 - 1}" in str(exc):  # chunk length never filled in
                scan.error = "file ends in an unfinished chunk (the writer did not close it)"
            elif not str(exc).strip():  # e.g. EndOfFile: the file is cut inside a record
                scan.error = f"the file ends inside a record ({type(exc).__name__})"
            else:
                scan.error = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
    return scan


def _by_topic(scan: _Scan) -> dict[str, tuple[Schema | None, Channel, list[Message]]]:
    out = {}
    for cid, msgs in scan.messages.items():
        ch = scan.channels.get(cid)
        if ch is not None:
            out[ch.topic] = (scan.schemas.get(ch.schema_id), ch, msgs)
    return out


def _decoded(entry, factory: DecoderFactory) -> tuple[np.ndarray, list]:
    """(log times [ns], decoded protobuf messages) of one topic."""
    schema, ch, msgs = entry
    decode = factory.decoder_for(ch.message_encoding, schema)
    if decode is None:
        raise LogError(f"no protobuf decoder for topic {ch.topic}")
    return (np.fromiter((m.log_time for m in msgs), np.int64, len(msgs)),
            [decode(m.data) for m in msgs])


def _parse_info(meta: dict) -> dict:
    info = dict(meta)
    for key in _JSON_FIELDS:
        if key in info:
            info[key] = json.loads(info[key])
    if "seed" in info:
        info["seed"] = int(info["seed"])
    if "dt" in info:
        info["dt"] = float(info["dt"])
    return info


def existing_log(path: str | os.PathLike, what: str) -> Path:
    """``path`` as a Path if the file exists; else :class:`LogError` naming ``what`` (e.g. "run
    log") and, if a killed run left ``<path>.active`` beside it, that file."""
    path = Path(path)
    if not path.is_file():
        alt = Path(f"{path}{ACTIVE_SUFFIX}")
        hint = f" (an interrupted run left {alt.name})" if alt.is_file() else ""
        raise LogError(f"{what} {path} not found{hint}")
    return path


def read_mcap(path: str | os.PathLike) -> RunLog:
    """Read a run's MCAP file (finished or ``.active``) into DataFrames.

    Steps are kept only if all their per-step messages were read. Raises :class:`LogError` if the
    file is missing, is not MCAP, or holds no readable run data.
    """
    import pandas as pd

    path = existing_log(path, "run log")
    scan = _scan(path)
    if META_RUN_INFO not in scan.metadata and not scan.messages:
        why = f": {scan.error}" if scan.error else ""
        raise LogError(f"run log {path} has no readable data{why}")

    topics = _by_topic(scan)
    factory = DecoderFactory()

    # /scalars (JSON): one parse of the whole topic; it carries the step index of each log time.
    if "/scalars" in topics:
        _, _, msgs = topics["/scalars"]
        rows = json.loads(b"[" + b",".join(m.data for m in msgs) + b"]")
        scalars = pd.DataFrame.from_records(rows)
        scalars.insert(0, "log_time", [m.log_time for m in msgs])
    else:
        scalars = pd.DataFrame(columns=["log_time", "step", "t"])

    # Keep only the steps whose every per-step message was read (a chunk may end mid-step).
    times = set(scalars["log_time"].tolist())
    for topic in _TOPICS[:-1]:
        present = topics.get(topic)
        times &= {m.log_time for m in present[2]} if present else set()
    scalars = scalars[scalars["log_time"].isin(times)]
    step_of = dict(zip(scalars["log_time"].tolist(), scalars["step"].tolist()))
    t_of = dict(zip(scalars["log_time"].tolist(), scalars["t"].tolist()))
    scalars = scalars.drop(columns="log_time").astype({"step": int}).set_index("step")
    scalars = scalars.astype(float)  # JSON null (a non-finite scalar) -> NaN

    info = _parse_info(scan.metadata.get(META_RUN_INFO, {}))
    joints = _joints_frame(topics, factory, step_of, t_of, len(info.get("joint_names") or ()))
    ee = _ee_frame(topics, factory, step_of, t_of)
    obstacles = _obstacles_frame(topics, factory, step_of, t_of)

    summary_meta = scan.metadata.get(META_SUMMARY, {})
    summary = json.loads(summary_meta.get("summary_json", "{}")) if summary_meta else {}
    complete = (scan.error is None and scan.footer and not str(path).endswith(ACTIVE_SUFFIX)
                and summary_meta.get("complete") == "true")
    urdf = scan.attachments.get(ATTACH_URDF)
    return RunLog(
        path=str(path),
        info=info,
        config_yaml=scan.metadata.get(META_CONFIG, {}).get("yaml", ""),
        urdf=urdf.data.decode() if urdf is not None else "",
        complete=complete,
        summary=summary,
        joints=joints, ee=ee, scalars=scalars, obstacles=obstacles,
        read_error=scan.error,
        metadata=scan.metadata,
    )


def _joint_columns(n: int) -> list[str]:
    return (["t"] + [f"q_{i}" for i in range(n)] + [f"qd_{i}" for i in range(n)]
            + [f"qdd_cmd_{i}" for i in range(n)])


def _joints_frame(topics, factory, step_of: dict, t_of: dict, n: int = 0) -> pd.DataFrame:
    """Per step: t, q_i, qd_i, qdd_cmd_i for each of the robot's joints (``n``: the run's
    joint count from its names; 0 for a log that names none: the messages' own count)."""
    import pandas as pd

    empty = pd.DataFrame(columns=_joint_columns(n), index=pd.Index([], name="step", dtype=int))
    if "/joint_states" not in topics:
        return empty
    times, decoded = _decoded(topics["/joint_states"], factory)
    keep = [i for i, t in enumerate(times.tolist()) if t in step_of]
    if not keep:
        return empty
    values = np.array([[v for j in decoded[i].joints for v in (j.position, j.velocity,
                                                              j.acceleration)]
                       for i in keep], dtype=float).reshape(len(keep), -1, 3)
    cols = _joint_columns(values.shape[1])
    t = np.array([t_of[tn] for tn in times[keep].tolist()], dtype=float)
    data = np.column_stack([t, values[:, :, 0], values[:, :, 1], values[:, :, 2]])
    index = pd.Index([step_of[t] for t in times[keep].tolist()], name="step", dtype=int)
    return pd.DataFrame(data, columns=cols, index=index)


def _ee_frame(topics, factory, step_of: dict, t_of: dict) -> pd.DataFrame:
    import pandas as pd

    cols = ["t", "x", "y", "z", "qx", "qy", "qz", "qw"]
    if "/ee_pose" not in topics:
        return pd.DataFrame(columns=cols, index=pd.Index([], name="step", dtype=int))
    times, decoded = _decoded(topics["/ee_pose"], factory)
    keep = [i for i, t in enumerate(times.tolist()) if t in step_of]
    rows = []
    for i in keep:
        p, o = decoded[i].pose.position, decoded[i].pose.orientation
        rows.append((t_of[int(times[i])], p.x, p.y, p.z, o.x, o.y, o.z, o.w))
    index = pd.Index([step_of[t] for t in times[keep].tolist()], name="step", dtype=int)
    return pd.DataFrame(np.array(rows, dtype=float).reshape(-1, len(cols)), columns=cols,
                        index=index)


def _obstacles_frame(topics, factory, step_of: dict, t_of: dict) -> pd.DataFrame:
    import pandas as pd

    cols = ["step", "t", "id", "x", "y", "z", "radius"]
    if "/scene" not in topics:
        return pd.DataFrame(columns=cols)
    times, decoded = _decoded(topics["/scene"], factory)
    rows = []
    for t, msg in zip(times.tolist(), decoded):
        step = step_of.get(t)
        if step is None:
            continue
        for ent in msg.entities:
            if ent.id != "obstacles":
                continue
            for j, s in enumerate(ent.spheres):
                p = s.pose.position
                rows.append((step, t_of[t], j, p.x, p.y, p.z, 0.5 * s.size.x))
    frame = pd.DataFrame.from_records(rows, columns=cols)
    return frame.astype({"step": int, "id": int, "t": float, "x": float, "y": float,
                         "z": float, "radius": float})


def upgrade_summary(summary: dict) -> dict:
    """A ``summary.json`` of any version up to :data:`SUMMARY_SCHEMA_VERSION` in the current
    layout: the fields a version lacks are added as null (version 1: ``suite``, ``machine``;
    version 2: the step thread's CPU times ``step_compute_cpu_ms`` and ``compute_cpu_ms_*``).
    A newer summary (written by a later tamedpuma) is a :class:`LogError` naming both
    versions."""
    version = summary.get("schema_version", 1)
    if not isinstance(version, int) or version > SUMMARY_SCHEMA_VERSION:
        raise LogError(f"summary.json of schema version {version!r}: this tamedpuma reads "
                       f"versions up to {SUMMARY_SCHEMA_VERSION} (upgrade tamedpuma)")
    out = dict(summary)
    if version < 2:
        out.setdefault("suite", None)
        out.setdefault("machine", None)
    if version < 3:
        out.setdefault("step_compute_cpu_ms", None)
        for key in ("median", "p99", "max"):
            out.setdefault(f"compute_cpu_ms_{key}", None)
    out["schema_version"] = SUMMARY_SCHEMA_VERSION
    return out
