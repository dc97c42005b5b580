"""Recording layer: MCAP and Rerun round trips, crash safety, corrupt files (synthetic data)."""

from __future__ import annotations

import importlib.util
import math
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from tamedpuma.errors import LogError
from tamedpuma.recording import (
    McapRecorder,
    RerunRecorder,
    RunInfo,
    StepRecord,
    active_path,
    make_recorders,
    read_mcap,
    read_rrd_joints,
    read_rrd_scalars,
    recover_mcap,
)

REPO = Path(__file__).resolve().parents[1]
K_BODY = 6
#: the KUKA iiwa's joint and link names (``pybullet_data/kuka_iiwa/model.urdf``), the robot of
#: these recordings
IIWA_JOINT_NAMES = tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8))
IIWA_LINK_NAMES = tuple(f"lbr_iiwa_link_{i}" for i in range(0, 8))


def _urdf(tmp_path: Path) -> Path:
    """A 7-joint chain with the iiwa's joint and link names and primitive geometry."""
    links = "".join(
        f'<link name="lbr_iiwa_link_{i}"><visual><geometry><cylinder radius="0.05" '
        f'length="0.15"/></geometry></visual></link>' for i in range(8))
    joints = "".join(
        f'<joint name="lbr_iiwa_joint_{i}" type="revolute"><parent link="lbr_iiwa_link_{i - 1}"/>'
        f'<child link="lbr_iiwa_link_{i}"/><origin xyz="0 0 0.15" rpy="0 0 0"/>'
        f'<axis xyz="0 {i % 2} {(i + 1) % 2}"/><limit lower="-3" upper="3" effort="1" '
        f'velocity="1"/></joint>' for i in range(1, 8))
    path = tmp_path / "robot.urdf"
    path.write_text(f'<?xml version="1.0"?><robot name="lbr_iiwa">{links}{joints}</robot>')
    return path


def _info(urdf: Path, run_id: str = "run-1") -> RunInfo:
    return RunInfo(run_id=run_id, method="tamedpuma", task="pick", scenario_name="clutter",
                   seed=7, config_yaml="method:\n  name: tamedpuma\nseed: 7\n",
                   urdf_path=str(urdf), body_sphere_radii=np.linspace(0.05, 0.1, K_BODY),
                   dt=0.02, joint_names=IIWA_JOINT_NAMES, link_names=IIWA_LINK_NAMES)


def _record(i: int) -> StepRecord:
    rng = np.random.default_rng(i)
    quats = rng.normal(size=(8, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    n_obs = 1 + i % 3  # the obstacle count may change between steps
    return StepRecord(
        step=i, t=0.02 * i, q=rng.uniform(-2, 2, 7), qd=rng.normal(size=7),
        qdd_cmd=rng.normal(size=7), link_positions=rng.normal(size=(8, 3)),
        link_quaternions=quats, ee_position=rng.normal(size=3), ee_quaternion=quats[-1],
        body_sphere_centers=rng.normal(size=(K_BODY, 3)),
        obstacle_centers=rng.normal(size=(n_obs, 3)), obstacle_radii=rng.uniform(0.05, 0.2, n_obs),
        goal_position=[0.5, 0.0, 0.5], goal_quaternion=[0.0, 0.0, 0.0, 1.0],
        scalars={"compute_time_ms": float(rng.uniform()), "clearance_m": float(rng.normal()),
                 "alpha": float(i)})


def _write_mcap(path: Path, urdf: Path, n: int, **kw) -> list[StepRecord]:
    recs = [_record(i) for i in range(n)]
    rec = McapRecorder(path, **kw)
    rec.open(_info(urdf))
    for r in recs:
        rec.write(r)
    rec.close(complete=True, summary={"success": True, "steps": n, "reason": "goal"})
    return recs


@pytest.fixture(scope="module")
def mcap_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("mcap")
    urdf = _urdf(tmp)
    path = tmp / "episode.mcap"
    recs = _write_mcap(path, urdf, 250, flush_every=100)
    return path, urdf, recs


def test_records_validate_shapes():
    with pytest.raises(ValueError, match="qd must have shape"):
        StepRecord(**{**_record(0).__dict__, "q": np.zeros(6)})  # 6 positions, 7 velocities
    with pytest.raises(ValueError, match="obstacle_radii"):
        StepRecord(**{**_record(0).__dict__, "obstacle_radii": np.zeros(7)})
    assert IIWA_JOINT_NAMES[0] == "lbr_iiwa_joint_1" and len(IIWA_LINK_NAMES) == 8


def test_mcap_round_trip(mcap_run):
    path, urdf, recs = mcap_run
    assert path.is_file() and not active_path(path).exists()
    log = read_mcap(path)
    assert log.complete and log.read_error is None
    assert log.summary == {"success": True, "steps": 250, "reason": "goal"}
    assert log.n_steps == len(log.ee) == len(log.scalars) == 250
    assert list(log.joints.index) == list(range(250))

    q = np.array([r.q for r in recs])
    qd = np.array([r.qd for r in recs])
    qdd = np.array([r.qdd_cmd for r in recs])
    np.testing.assert_array_equal(log.joints[[f"q_{i}" for i in range(7)]].to_numpy(), q)
    np.testing.assert_array_equal(log.joints[[f"qd_{i}" for i in range(7)]].to_numpy(), qd)
    np.testing.assert_array_equal(log.joints[[f"qdd_cmd_{i}" for i in range(7)]].to_numpy(), qdd)
    np.testing.assert_array_equal(log.joints["t"].to_numpy(), [r.t for r in recs])
    np.testing.assert_array_equal(log.ee[["x", "y", "z"]].to_numpy(),
                                  [r.ee_position for r in recs])
    np.testing.assert_array_equal(log.ee[["qx", "qy", "qz", "qw"]].to_numpy(),
                                  [r.ee_quaternion for r in recs])
    for name in ("compute_time_ms", "clearance_m", "alpha"):
        np.testing.assert_array_equal(log.scalars[name].to_numpy(),
                                      [r.scalars[name] for r in recs])

    obs = log.obstacles
    assert list(obs.columns) == ["step", "t", "id", "x", "y", "z", "radius"]
    assert len(obs) == sum(len(r.obstacle_radii) for r in recs)
    np.testing.assert_array_equal(obs[["x", "y", "z"]].to_numpy(),
                                  np.concatenate([r.obstacle_centers for r in recs]))
    np.testing.assert_allclose(obs["radius"].to_numpy(),
                               np.concatenate([r.obstacle_radii for r in recs]), rtol=1e-15)

    assert log.config_yaml == _info(urdf).config_yaml
    assert log.urdf == urdf.read_text()
    assert log.info["run_id"] == "run-1" and log.info["seed"] == 7 and log.info["dt"] == 0.02
    assert log.info["joint_names"] == list(IIWA_JOINT_NAMES)


def test_mcap_schemas_and_index(mcap_run):
    path, _, _ = mcap_run
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    names = {s.name for s in summary.schemas.values()}
    assert {"foxglove.JointStates", "foxglove.FrameTransforms", "foxglove.SceneUpdate",
            "foxglove.PoseInFrame"} <= names
    topics = {c.topic for c in summary.channels.values()}
    assert topics == {"/joint_states", "/tf", "/ee_pose", "/scene", "/scalars"}
    assert set(summary.statistics.channel_message_counts.values()) == {250}
    assert len(summary.chunk_indexes) >= 3  # flushed every 100 steps


_KILLED_WRITER = textwrap.dedent("""
    import os, signal, sys
    sys.path.insert(0, {repo!r}); sys.path.insert(0, {tests!r})
    from test_recording import _info, _record
    from tamedpuma.recording import McapRecorder, RerunRecorder
    from pathlib import Path
    recs = [McapRecorder({path!r}, flush_every=100), RerunRecorder({rrd!r}, batch=50)]
    for rec in recs:
        rec.open(_info(Path({urdf!r})))
    for i in range(230):
        for rec in recs:
            rec.write(_record(i))
    os.kill(os.getpid(), signal.SIGKILL)
""")


def test_killed_writer_leaves_readable_active_file(tmp_path):
    urdf = _urdf(tmp_path)
    path, rrd = tmp_path / "episode.mcap", tmp_path / "episode.rrd"
    script = _KILLED_WRITER.format(repo=str(REPO), tests=str(REPO / "tests"), path=str(path),
                                   rrd=str(rrd), urdf=str(urdf))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=60)
    assert proc.returncode == -9, proc.stderr.decode()[-2000:]
    assert not path.exists() and active_path(path).is_file()

    with pytest.raises(LogError, match="interrupted run"):
        read_mcap(path)
    log = read_mcap(active_path(path))
    assert not log.complete and log.summary == {}
    assert 200 <= log.n_steps <= 230
    # the file ends at the last flush (steps after it are logged at the next flush, as one
    # chunk) or, killed while a chunk is written, in that unfinished chunk
    assert log.read_error in ("file ends in an unfinished chunk (the writer did not close it)",
                              "the file ends inside a record (EndOfFile)")
    np.testing.assert_array_equal(log.joints.index, np.arange(log.n_steps))
    np.testing.assert_array_equal(log.joints[[f"q_{i}" for i in range(7)]].to_numpy(),
                                  [_record(i).q for i in range(log.n_steps)])
    assert log.config_yaml and log.info["run_id"] == "run-1"

    fixed = tmp_path / "recovered.mcap"
    copied = recover_mcap(active_path(path), fixed)
    assert copied >= 5 * 200
    with open(fixed, "rb") as f:  # a valid, indexed file now
        assert make_reader(f).get_summary().statistics.message_count == copied
    again = read_mcap(fixed)
    assert not again.complete and again.n_steps == log.n_steps
    assert again.urdf == urdf.read_text()

    # Rerun: same convention; every batch sent before the kill is readable.
    assert not rrd.exists() and active_path(rrd).is_file()
    with pytest.raises(LogError, match="interrupted run"):
        read_rrd_joints(rrd)
    joints = read_rrd_joints(active_path(rrd))
    assert 200 <= len(joints) <= 230
    np.testing.assert_array_equal(joints[list(IIWA_JOINT_NAMES)].to_numpy(),
                                  [_record(i).q for i in range(len(joints))])


def test_truncated_and_corrupt_files(mcap_run, tmp_path):
    path, _, _ = mcap_run
    data = path.read_bytes()

    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    log = read_mcap(cut)
    assert not log.complete and log.read_error is not None
    assert 0 < log.n_steps < 250

    flipped = bytearray(data)
    mid = len(data) // 2
    flipped[mid: mid + 64] = bytes(64)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(flipped))
    log = read_mcap(bad)  # stops at the damaged chunk, no traceback
    assert not log.complete and log.n_steps < 250

    for name, content in [("empty.mcap", b""), ("tiny.mcap", data[:20]),
                          ("junk.mcap", b"not an mcap file at all" * 10)]:
        p = tmp_path / name
        p.write_bytes(content)
        with pytest.raises(LogError, match="no readable data"):
            read_mcap(p)
        with pytest.raises(LogError):
            recover_mcap(p, tmp_path / f"fixed-{name}")
    with pytest.raises(LogError, match="not found"):
        read_mcap(tmp_path / "missing.mcap")


def test_a_whole_log_is_scanned_fast_to_the_stream_readers_records(mcap_run, tmp_path):
    """read_mcap slices a whole file's records from its bytes (runlog._scan_whole): the same
    schemas, channels, messages, metadata and attachment as the mcap library's stream reader;
    a file that is not whole (cut, damaged, still being written) is left to the stream reader,
    which reads up to the damage and says why it stops."""
    from tamedpuma import runlog

    path, _, _ = mcap_run
    whole, stream = runlog._scan_whole(path), runlog._scan_stream(path)
    assert whole is not None and whole.footer and whole.error is None
    for name in ("schemas", "channels", "metadata", "attachments", "messages", "n_records"):
        assert getattr(whole, name) == getattr(stream, name), name
    assert sum(len(m) for m in whole.messages.values()) == 5 * 250
    data = path.read_bytes()
    damaged = bytearray(data)
    damaged[len(data) // 2] ^= 0xFF  # one bit pattern inside the data section
    for name, content in [("cut.mcap", data[:-1]), ("flipped.mcap", bytes(damaged)),
                          ("half.mcap", data[: len(data) // 2])]:
        p = tmp_path / name
        p.write_bytes(content)
        try:
            whole = runlog._scan_whole(p)
        except Exception:  # noqa: BLE001 - a damaged chunk's CRC: the stream reader's turn
            whole = None
        assert whole is None, name
        scan = runlog._scan(p)
        assert scan.error is not None or not scan.footer, name


def test_a_missing_log_names_the_active_file_a_killed_run_left(tmp_path):
    """Both readers: a missing log is a LogError naming it, and the ``.active`` file beside it."""
    for read, name, what in ((read_mcap, "episode.mcap", "run log"),
                             (read_rrd_scalars, "episode.rrd", "rerun log")):
        path = tmp_path / name
        with pytest.raises(LogError, match=f"^{what} .*{name} not found$"):
            read(path)
        active_path(path).write_bytes(b"")
        with pytest.raises(LogError, match=rf"not found \(an interrupted run left {name}.active\)"):
            read(path)


def test_rerun_round_trip(tmp_path):
    urdf = _urdf(tmp_path)
    path = tmp_path / "episode.rrd"
    recs = [_record(i) for i in range(120)]
    rec = RerunRecorder(path, batch=50)
    rec.open(_info(urdf))
    for r in recs:
        rec.write(r)
    rec.close(complete=True, summary={"success": True})

    joints = read_rrd_joints(path)
    assert list(joints.index) == list(range(120))
    np.testing.assert_array_equal(joints[list(IIWA_JOINT_NAMES)].to_numpy(),
                                  [r.q for r in recs])
    np.testing.assert_allclose(joints["t"].to_numpy(), [r.t for r in recs], atol=1e-9)
    scalars = read_rrd_scalars(path)
    np.testing.assert_array_equal(scalars["alpha"].to_numpy(), np.arange(120.0))

    rerun = shutil.which("rerun", path=os.path.dirname(sys.executable)) or "rerun"
    proc = subprocess.run([rerun, "rrd", "verify", str(path)], capture_output=True, timeout=60)
    assert proc.returncode == 0, proc.stderr.decode()[-2000:]

    with pytest.raises(LogError, match="not found"):
        read_rrd_joints(tmp_path / "missing.rrd")
    junk = tmp_path / "junk.rrd"
    junk.write_bytes(b"not an rrd file" * 10)
    with pytest.raises(LogError, match="unreadable"):
        read_rrd_joints(junk)
    with pytest.raises(FileExistsError):
        RerunRecorder(path).open(_info(urdf))


def test_existing_files_are_not_clobbered(mcap_run, tmp_path):
    path, urdf, _ = mcap_run
    with pytest.raises(FileExistsError):
        McapRecorder(path).open(_info(urdf))
    target = tmp_path / "again.mcap"
    active_path(target).write_bytes(b"stale")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        McapRecorder(target).open(_info(urdf))
    rec = McapRecorder(target, overwrite=True)
    rec.open(_info(urdf))
    rec.write(_record(0))
    rec.close(complete=False, summary={"reason": "interrupted", "n": np.int64(1),
                                       "v": np.array([1.0, 2.0])})
    log = read_mcap(target)
    assert not log.complete and log.n_steps == 1 and not active_path(target).exists()
    assert log.summary == {"reason": "interrupted", "n": 1, "v": [1.0, 2.0]}


def test_non_finite_scalars_are_null_in_json(tmp_path):
    urdf = _urdf(tmp_path)
    path = tmp_path / "nan.mcap"
    rec = McapRecorder(path)
    rec.open(_info(urdf))
    base = _record(0)
    rec.write(StepRecord(**{**base.__dict__, "scalars": {"clearance_m": float("inf"),
                                                         "alpha": float("nan")}}))
    rec.close(complete=True, summary={})
    with open(path, "rb") as f:
        data = [m.data for _, c, m in make_reader(f).iter_messages(topics=["/scalars"])]
    assert b"null" in data[0] and b"Infinity" not in data[0] and b"NaN" not in data[0]
    log = read_mcap(path)
    assert np.isnan(log.scalars["clearance_m"].iloc[0]) and np.isnan(log.scalars["alpha"].iloc[0])


def test_scalars_json_is_what_json_dumps_writes_step_by_step(tmp_path):
    """Every step's /scalars text is ``json.dumps`` of its values (non-finite ones as null),
    whether all are finite or not, and when a step brings other names."""
    import json

    urdf = _urdf(tmp_path)
    path = tmp_path / "scalars.mcap"
    rec = McapRecorder(path)
    rec.open(_info(urdf))
    base = _record(0)
    steps = [{"a%s": 0.1, 'b"q': 1e300, "c": -0.0}, {"a%s": float("nan"), 'b"q': 1e308, "c": 2.5},
             {"a%s": 1e308, 'b"q': 1e308, "c": float("-inf")}, {"a%s": 3.0, 'b"q': 4.0, "c": 5.0},
             {"other": 1.0 / 3.0}, {"a%s": 1, 'b"q': np.float32(0.5), "c": True}]
    for i, scalars in enumerate(steps):
        rec.write(StepRecord(**{**base.__dict__, "step": i, "t": 0.02 * i, "scalars": scalars}))
    rec.close(complete=True, summary={})
    with open(path, "rb") as f:
        data = [m.data for _, c, m in make_reader(f).iter_messages(topics=["/scalars"])]
    for i, (scalars, text) in enumerate(zip(steps, data)):
        values = {k: float(v) for k, v in scalars.items()}
        expected = {"step": i, "t": 0.02 * i,
                    **{k: v if math.isfinite(v) else None for k, v in values.items()}}
        assert text == json.dumps(expected).encode()


@pytest.mark.skipif(importlib.util.find_spec("pybullet_data") is None,
                    reason="pybullet_data not installed")
def test_rerun_loads_kuka_urdf(tmp_path):
    spec = importlib.util.find_spec("pybullet_data")
    urdf = Path(spec.submodule_search_locations[0]) / "kuka_iiwa" / "model.urdf"
    path = tmp_path / "kuka.rrd"
    (mcap_rec, rerun_rec) = make_recorders(["mcap", "rerun"], tmp_path)
    assert isinstance(rerun_rec, RerunRecorder) and isinstance(mcap_rec, McapRecorder)
    rec = RerunRecorder(path)
    rec.open(_info(urdf))
    for i in range(3):
        rec.write(_record(i))
    rec.close(complete=False, summary={"reason": "interrupted"})
    from rerun.chunk import RrdReader

    entities = RrdReader(path).stream().collect().summary()
    assert "/world/lbr_iiwa/visual_geometries/lbr_iiwa_link_7" in entities  # meshes loaded
    assert "Asset3D:blob" in entities
    assert len(read_rrd_joints(path)) == 3


def test_rerun_sends_after_max_wait_and_keeps_every_row(tmp_path):
    """A step is on disk ``max_wait`` seconds after it was written whatever ``batch`` is (a
    killed run loses at most that), and the column buffers keep every row: obstacle counts
    that change between steps, a scalar missing at one step (NaN), the whole path."""
    from rerun.chunk import RrdReader

    urdf = _urdf(tmp_path)
    path = tmp_path / "episode.rrd"
    recs = [_record(i) for i in range(130)]  # the path spans two blocks (PATH_BLOCK = 100)
    recs[7] = StepRecord(**{**recs[7].__dict__, "scalars": {"alpha": 7.0}})
    rec = RerunRecorder(path, batch=10_000, max_wait=1e-9)
    rec.open(_info(urdf))
    for r in recs[:20]:
        rec.write(r)
    joints = read_rrd_joints(active_path(path))  # the run is still open
    assert list(joints.index) == list(range(20))
    for r in recs[20:]:
        rec.write(r)
    rec.close(complete=True, summary={})
    scalars = read_rrd_scalars(path)
    np.testing.assert_array_equal(scalars["alpha"].to_numpy(), np.arange(130.0))
    assert np.isnan(scalars.loc[7, "clearance_m"]) and scalars.loc[8, "clearance_m"] == \
        recs[8].scalars["clearance_m"]
    store = RrdReader(path).stream().collect()
    df = store.reader(index="step", contents="/world/**").to_pandas().set_index("step")
    centers = df["/world/obstacles:Ellipsoids3D:centers"]
    for i in (0, 1, 2, 99, 100, 129):
        np.testing.assert_allclose(np.stack(centers[i]), recs[i].obstacle_centers, rtol=1e-6)
    # the path strip of step s holds every end-effector point of its block up to s, starting
    # at the previous block's last point
    strip = df["/world/ee_path/00001:LineStrips3D:strips"][129][0]
    np.testing.assert_allclose(np.stack(strip), [r.ee_position for r in recs[99:130]],
                               rtol=1e-6)


def test_mcap_static_obstacles_are_logged_every_step_and_changes_seen(tmp_path):
    """Obstacles that stay put for a few steps (their scene primitives reused by the writer)
    and then move or change in number read back step by step as written."""
    urdf = _urdf(tmp_path)
    base = [_record(i) for i in range(6)]
    same = {"obstacle_centers": base[0].obstacle_centers, "obstacle_radii": base[0].obstacle_radii}
    recs = [base[0], *(StepRecord(**{**r.__dict__, **same}) for r in base[1:4]), *base[4:]]
    path = tmp_path / "static.mcap"
    rec = McapRecorder(path)
    rec.open(_info(urdf))
    for r in recs:
        rec.write(r)
    rec.close(complete=True, summary={})
    obs = read_mcap(path).obstacles
    assert list(obs["step"]) == [r.step for r in recs for _ in r.obstacle_radii]
    np.testing.assert_array_equal(obs[["x", "y", "z"]].to_numpy(),
                                  np.concatenate([r.obstacle_centers for r in recs]))


def test_a_chunk_cut_short_leaves_every_step_once(tmp_path, monkeypatch):
    """An exception (a signal handler's, as the sweep's SIGTERM handler raises) while a chunk's
    records are being logged: closing the log as incomplete must not log the chunk's records
    again (a killed sweep run's log held steps 80-98 twice). The log ends before the
    interrupted record; every step in it appears once."""
    urdf = _urdf(tmp_path)
    path = tmp_path / "episode.mcap"
    rec = McapRecorder(path, flush_every=20)
    rec.open(_info(urdf))
    original, raised = McapRecorder._log, []

    class Terminated(Exception):
        pass

    def log_or_interrupt(self, r):
        if r.step == 29 and not raised:  # the second chunk (steps 20-39), its 10th record
            raised.append(r.step)
            raise Terminated
        original(self, r)

    monkeypatch.setattr(McapRecorder, "_log", log_or_interrupt)
    with pytest.raises(Terminated):
        for i in range(100):
            rec.write(_record(i))
    rec.close(complete=False, summary={"success": False})
    log = read_mcap(path)
    assert not log.complete
    assert list(log.joints.index) == list(range(log.n_steps))
    assert log.n_steps == 29


def test_a_robot_of_three_joints_is_logged_and_read_with_three(tmp_path):
    """The log names the joints the robot has: three joints give q_0..q_2 (no seven assumed)."""
    import dataclasses

    names = ("a", "b", "c")
    info = dataclasses.replace(_info(_urdf(tmp_path)), joint_names=names)
    recs = []
    for i in range(5):
        r = _record(i)
        recs.append(StepRecord(**{**r.__dict__, "q": r.q[:3], "qd": r.qd[:3],
                                  "qdd_cmd": r.qdd_cmd[:3]}))
    path = tmp_path / "episode.mcap"
    writer = McapRecorder(path)
    writer.open(info)
    for r in recs:
        writer.write(r)
    writer.close(complete=True, summary={"steps": 5})
    log = read_mcap(path)
    assert log.info["joint_names"] == list(names)
    assert [c for c in log.joints.columns if c.startswith("q_")] == ["q_0", "q_1", "q_2"]
    np.testing.assert_array_equal(log.joints[["q_0", "q_1", "q_2"]].to_numpy(),
                                  np.array([r.q for r in recs]))
