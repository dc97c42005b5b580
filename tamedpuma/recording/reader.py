"""Read recorded runs back: the MCAP log (:mod:`tamedpuma.runlog`: :func:`read_mcap` →
:class:`RunLog`), its recovery (:func:`recover_mcap` copies the readable records of a killed
run's file into a new, valid MCAP file) and the Rerun ``.rrd`` (checks, scalar series).
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from mcap.records import Attachment, Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from ..errors import LogError
from ..runlog import RunLog, _scan, existing_log, read_mcap

__all__ = ["RunLog", "check_rrd", "read_mcap", "read_rrd_joints", "read_rrd_scalars",
           "read_rrd_series", "recover_mcap"]


def recover_mcap(src: str | os.PathLike, dst: str | os.PathLike) -> int:
    """Copy every readable record of ``src`` (e.g. a killed run's ``.active``) into a valid ``dst``.

    Returns the number of messages copied. The result carries a ``tamedpuma.recovered`` metadata
    record (source, and the error that ended the scan); a killed run's file has no summary record,
    so its copy still reads as incomplete.
    Raises :class:`LogError` if ``src`` is missing or has no readable data, FileExistsError if
    ``dst`` exists.
    """
    from mcap.writer import Writer

    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise LogError(f"run log {src} not found")
    if dst.exists():
        raise FileExistsError(f"{dst} exists")
    scan = _scan(src)
    if not scan.messages and not scan.metadata:
        raise LogError(f"run log {src} has no readable data"
                       + (f": {scan.error}" if scan.error else ""))
    # Re-read in order so records keep their original interleaving.
    count = 0
    with open(src, "rb") as f, open(dst, "wb") as out:
        writer = Writer(out)
        writer.start(profile="", library="tamedpuma.recover_mcap")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        try:
            for rec in StreamReader(f, validate_crcs=True).records:
                if isinstance(rec, Schema):
                    schema_ids[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
                elif isinstance(rec, Channel):
                    channel_ids[rec.id] = writer.register_channel(
                        rec.topic, rec.message_encoding, schema_ids.get(rec.schema_id, 0),
                        dict(rec.metadata))
                elif isinstance(rec, Message) and rec.channel_id in channel_ids:
                    writer.add_message(channel_ids[rec.channel_id], rec.log_time, rec.data,
                                       rec.publish_time, rec.sequence)
                    count += 1
                elif isinstance(rec, Metadata):
                    writer.add_metadata(rec.name, dict(rec.metadata))
                elif isinstance(rec, Attachment):
                    writer.add_attachment(rec.create_time, rec.log_time, rec.name,
                                          rec.media_type, rec.data)
        except Exception:  # noqa: BLE001 - the readable prefix ends here (reported below)
            pass
        writer.add_metadata("tamedpuma.recovered",
                            {"source": str(src), "error": scan.error or ""})
        writer.finish()
    return count


# -- Rerun (.rrd) -------------------------------------------------------------------------------


def check_rrd(path: str | os.PathLike) -> None:
    """Raise :class:`LogError` (one line) if the ``.rrd`` file cannot be read to its end (e.g.
    truncated within a message); a killed run's file without a footer is readable."""
    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():  # no footer: whole-file scan
            warnings.simplefilter("ignore")
            RrdReader(Path(path)).stream().collect()
    except Exception as exc:  # noqa: BLE001 - rerun raises assorted errors for bad files
        why = (str(exc).splitlines() or [type(exc).__name__])[-1]
        why = why.replace(f"Failed to read RRD file at {path}: ", "")
        raise LogError(f"rerun log {path} is truncated or corrupt ({why})") from None


def read_rrd_series(path: str | os.PathLike, root: str) -> pd.DataFrame:
    """Every ``Scalars`` series under ``root`` (e.g. ``/metrics``) of a ``.rrd`` file.

    Returns a DataFrame indexed by ``step`` with column ``t`` [s] and one column per entity
    below ``root`` (the entity name, e.g. ``clearance_m``). Raises :class:`LogError` if the file
    is missing or unreadable.
    """
    from rerun.chunk import RrdReader

    path = existing_log(path, "rerun log")
    root = "/" + root.strip("/")
    try:
        with warnings.catch_warnings():  # a killed run's file has no footer: whole-file scan
            warnings.simplefilter("ignore")
            store = RrdReader(path).stream().collect()
        raw = store.reader(index="step", contents=f"{root}/**").to_pandas()
    except Exception as exc:  # noqa: BLE001 - rerun raises assorted errors for bad files
        raise LogError(f"rerun log {path} unreadable: {type(exc).__name__}: "
                       f"{str(exc).splitlines()[0] if str(exc) else ''}") from None
    raw = raw[raw["step"].notna()]
    out = pd.DataFrame(index=pd.Index(raw["step"].astype(int).to_numpy(), name="step"))
    out["t"] = raw["time"].dt.total_seconds().to_numpy() if "time" in raw else np.nan
    for col in raw.columns:
        if col.endswith(":Scalars:scalars"):
            name = col[len(root) + 1:-len(":Scalars:scalars")]
            out[name] = [v[0] if v is not None and len(v) else np.nan for v in raw[col]]
    return out.sort_index()


def read_rrd_scalars(path: str | os.PathLike) -> pd.DataFrame:
    """The ``/metrics/<name>`` scalars of a ``.rrd`` file: index step; columns t and names."""
    return read_rrd_series(path, "/metrics")


def read_rrd_joints(path: str | os.PathLike) -> pd.DataFrame:
    """The ``/joints/<joint>`` positions [rad] of a ``.rrd``: index step; columns t, joint names.

    Steps with a missing joint value (the last, partly written batch of a killed run) are left
    out, so every row is a whole configuration."""
    joints = read_rrd_series(path, "/joints")
    return joints.dropna(subset=[c for c in joints.columns if c != "t"])
