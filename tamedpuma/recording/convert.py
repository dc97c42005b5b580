"""MCAP (the source of truth) -> Rerun ``.rrd``: rebuild a run's replay from its MCAP log.

:func:`mcap_records` reads a run's MCAP back into the :class:`RunInfo` and the per-step
:class:`StepRecord` s the episode loop handed to the recorders (joint state, link poses from
``/tf``, end effector, body spheres, obstacles and goal from ``/scene``, every scalar);
:func:`mcap_to_rrd` streams them through :class:`RerunRecorder`, so a rebuilt replay is the same
file the live recorder would have written (same recording id, layout and blueprint).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from tamedpuma.records import RunInfo, StepRecord

from ..errors import LogError
from ..runlog import RunLog, _by_topic, _decoded, _scan, read_mcap
from .rerun_writer import RerunRecorder


def run_info(log: RunLog, urdf_path: str | None = None) -> RunInfo:
    """The :class:`RunInfo` stored in a run's MCAP metadata (``urdf_path`` overrides the one
    recorded). Velocity limits missing from older logs are taken from the config's robot."""
    info = log.info
    if "dt" not in info:
        raise LogError(f"run log {log.path} has no control period (dt) in its run info")
    limits = info.get("velocity_limits") or []
    if not limits and log.config_yaml:
        import yaml

        robot = (yaml.safe_load(log.config_yaml) or {}).get("robot") or {}
        limits = robot.get("qd_max") or []
    return RunInfo(
        run_id=info.get("run_id", Path(log.path).parent.name), method=info.get("method", "?"),
        task=info.get("task", "?"), scenario_name=info.get("scenario_name", "?"),
        seed=int(info.get("seed", 0)), config_yaml=log.config_yaml,
        urdf_path=urdf_path or info.get("urdf_path", ""),
        joint_names=info.get("joint_names") or (), link_names=info.get("link_names") or (),
        body_sphere_radii=info.get("body_sphere_radii") or [], dt=float(info["dt"]),
        velocity_limits=limits)


def _tf_by_step(messages, step_of_ns: dict, link_names: list) -> dict:
    """step -> (link positions (n, 3) [m], quaternions (n, 4) xyzw) from the ``/tf`` messages,
    links in ``link_names`` order (or the message's when the log names none)."""
    tf: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for ns, msg in zip(*messages):
        step = step_of_ns.get(int(ns))
        if step is None:
            continue
        by_name = {f.child_frame_id: f for f in msg.transforms}
        names = link_names or list(by_name)
        pos = np.array([[by_name[n].translation.x, by_name[n].translation.y,
                         by_name[n].translation.z] for n in names])
        quat = np.array([[by_name[n].rotation.x, by_name[n].rotation.y, by_name[n].rotation.z,
                          by_name[n].rotation.w] for n in names])
        tf[step] = (pos, quat)
    return tf


def _scene_of(msg) -> dict:
    """One ``/scene`` message: obstacles and body spheres (centres (n, 3), radii (n,) [m]) and
    the goal (position, quaternion; NaN position and identity when the scene has no goal)."""
    ents = {e.id: e for e in msg.entities}
    out = {}
    for key in ("obstacles", "body_spheres"):
        spheres = ents[key].spheres if key in ents else []
        out[key] = (np.array([[s.pose.position.x, s.pose.position.y, s.pose.position.z]
                              for s in spheres]).reshape(-1, 3),
                    np.array([0.5 * s.size.x for s in spheres]))
    goal = ents["goal"].spheres[0].pose if "goal" in ents and ents["goal"].spheres else None
    out["goal"] = (np.array([goal.position.x, goal.position.y, goal.position.z]),
                   np.array([goal.orientation.x, goal.orientation.y, goal.orientation.z,
                             goal.orientation.w])) if goal is not None else (
        np.full(3, np.nan), np.array([0.0, 0.0, 0.0, 1.0]))
    return out


def _step_records(log: RunLog, tf: dict, scene: dict) -> list[StepRecord]:
    """One :class:`StepRecord` per step present in the joints, ``tf`` and ``scene``."""
    n = len([c for c in log.joints.columns if c.startswith("q_")])
    q = log.joints[[f"q_{i}" for i in range(n)]]
    qd = log.joints[[f"qd_{i}" for i in range(n)]]
    qdd = log.joints[[f"qdd_cmd_{i}" for i in range(n)]]
    scalar_cols = [c for c in log.scalars.columns if c != "t"]
    records = []
    for step in log.scalars.index:
        if step not in tf or step not in scene or step not in log.joints.index:
            continue
        ee = log.ee.loc[step]
        obs_c, obs_r = scene[step]["obstacles"]
        body_c, _ = scene[step]["body_spheres"]
        goal_p, goal_q = scene[step]["goal"]
        row = log.scalars.loc[step]
        records.append(StepRecord(
            step=int(step), t=float(row["t"]), q=q.loc[step].to_numpy(),
            qd=qd.loc[step].to_numpy(), qdd_cmd=qdd.loc[step].to_numpy(),
            link_positions=tf[step][0], link_quaternions=tf[step][1],
            ee_position=ee[["x", "y", "z"]].to_numpy(dtype=float),
            ee_quaternion=ee[["qx", "qy", "qz", "qw"]].to_numpy(dtype=float),
            body_sphere_centers=body_c, obstacle_centers=obs_c, obstacle_radii=obs_r,
            goal_position=goal_p, goal_quaternion=goal_q,
            scalars={c: float(row[c]) for c in scalar_cols}))
    return records


def mcap_records(path: str | os.PathLike) -> tuple[RunLog, list[StepRecord]]:
    """A run's MCAP (finished or ``.active``) as its :class:`RunLog` and one
    :class:`StepRecord` per fully read step. Raises :class:`LogError` for an unreadable file."""
    log = read_mcap(path)
    topics = _by_topic(_scan(Path(path)))
    if "/tf" not in topics or "/scene" not in topics:
        raise LogError(f"run log {path} has no /tf or /scene channel")
    from mcap_protobuf.decoder import DecoderFactory

    factory = DecoderFactory()
    t_ns = np.round(log.scalars["t"].to_numpy() * 1e9).astype(np.int64)
    step_of_ns = dict(zip(t_ns.tolist(), log.scalars.index.tolist()))
    tf = _tf_by_step(_decoded(topics["/tf"], factory), step_of_ns,
                     list(log.info.get("link_names") or []))
    scene = {}
    for ns, msg in zip(*_decoded(topics["/scene"], factory)):
        step = step_of_ns.get(int(ns))
        if step is not None:
            scene[step] = _scene_of(msg)
    return log, _step_records(log, tf, scene)


def mcap_to_rrd(mcap: str | os.PathLike, rrd: str | os.PathLike, overwrite: bool = False) -> int:
    """Write ``rrd`` from the run log ``mcap`` through :class:`RerunRecorder`; returns the number
    of steps written. The robot model is the recorded URDF path when it exists on this machine,
    else the URDF embedded in the MCAP (its meshes may then be missing). A log that is
    incomplete (killed run) gives a replay whose summary says ``complete = false``.
    Raises :class:`LogError` for an unreadable log, FileExistsError if ``rrd`` exists."""
    log, records = mcap_records(mcap)
    urdf = log.info.get("urdf_path", "")
    with tempfile.TemporaryDirectory() as tmp:
        if not Path(urdf).is_file() and log.urdf:
            urdf = str(Path(tmp) / "model.urdf")
            Path(urdf).write_text(log.urdf)
        info = run_info(log, urdf_path=urdf)
        recorder = RerunRecorder(rrd, overwrite=overwrite)
        recorder.open(info)
        try:
            for rec in records:
                recorder.write(rec)
        finally:
            recorder.close(complete=log.complete,
                           summary={**log.summary, "rebuilt_from": str(mcap)})
    return len(records)
