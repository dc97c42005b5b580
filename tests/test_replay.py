"""Replay: an .rrd rebuilt from the MCAP, the replay command, and a rendered picture of the arm."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tamedpuma.recording import read_mcap, read_rrd_joints, read_rrd_scalars
from tamedpuma.recording.convert import mcap_records
from tamedpuma.recording.render import HeadlessViewer, rerun_executable, vulkan_available
from tamedpuma.recording.rerun_writer import (
    LEGEND_CORNERS,
    Camera,
    frame_camera,
    legend_corner,
    plot_groups,
    replay_blueprint,
)

REPO = Path(__file__).resolve().parents[1]
STEPS = 60


def _sweep(out: Path, *args: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.sweep", *args, "recorder=mcap",
                           f"output_root={out}", f"scenario.max_steps={STEPS}",
                           "stop_on_success=false"],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """One short sweep: joint_attractor with and without the default scenario's obstacles."""
    out = tmp_path_factory.mktemp("replay")
    _sweep(out, "-m", "method=joint_attractor", "without_obstacles=false,true")
    runs = sorted((out / "multirun").glob("*/*_joint_attractor_*"))
    assert len(runs) == 2
    return runs


def _replay(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tamedpuma.replay", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=180)


def test_replay_is_rebuilt_from_the_mcap_with_every_step(sweep):
    run = sweep[0]
    assert not (run / "episode.rrd").exists()  # recorder=mcap: no replay was written
    proc = _replay(str(run), "--build", "--reference", "none")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == str(run / "episode.rrd")
    verify = subprocess.run([rerun_executable(), "rrd", "verify", str(run / "episode.rrd")],
                            capture_output=True, timeout=60)
    assert verify.returncode == 0, verify.stderr.decode()[-2000:]

    log = read_mcap(run / "episode.mcap")
    joints = read_rrd_joints(run / "episode.rrd")
    assert log.n_steps == STEPS and len(joints) == log.n_steps
    np.testing.assert_allclose(joints.iloc[:, 1:].to_numpy(),
                               log.joints[[f"q_{i}" for i in range(7)]].to_numpy(), atol=1e-12)
    scalars = read_rrd_scalars(run / "episode.rrd")
    for name in ("clearance_m", "compute_time_ms", "position_error_m"):
        np.testing.assert_allclose(scalars[name].to_numpy(), log.scalars[name].to_numpy())


def test_replay_overlays_the_reference_run_of_the_same_sweep(sweep):
    from tamedpuma.app.replay import find_reference, prepare

    with_obstacles, free = sweep
    assert len(read_mcap(free / "episode.mcap").obstacles) == 0
    found = find_reference(with_obstacles / "episode.mcap", "joint_attractor")
    assert found is not None and found[0] == free / "episode.mcap"
    np.testing.assert_array_equal(found[1],
                                  read_mcap(free / "episode.mcap").ee[["x", "y", "z"]])
    replay = prepare(with_obstacles, reference="joint_attractor")
    assert replay.overlay is not None and replay.overlay.is_file()
    assert find_reference(with_obstacles / "episode.mcap", "fabrics") is None  # not in sweep


def test_replay_mistakes_are_one_line_errors(tmp_path):
    for args in ([str(tmp_path / "missing")], [str(tmp_path)]):
        proc = _replay(*args)
        assert proc.returncode == 2 and proc.stderr.startswith("error: ")
        assert len(proc.stderr.strip().splitlines()) == 1


def test_a_truncated_rrd_is_rebuilt_from_its_mcap_or_refused_in_one_line(sweep, tmp_path):
    """A truncated ``.rrd`` (cut inside a message) next to its MCAP is rebuilt from it (run
    folder or the ``.rrd`` itself given); alone, it is one line ``error: ...``, status 2."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "episode.mcap").write_bytes((sweep[1] / "episode.mcap").read_bytes())
    assert _replay(str(run), "--build", "--reference", "none").returncode == 0
    whole = (run / "episode.rrd").read_bytes()
    for arg in (run, run / "episode.rrd"):
        (run / "episode.rrd").write_bytes(whole[: len(whole) * 2 // 3])
        proc = _replay(str(arg), "--build", "--reference", "none")
        assert proc.returncode == 0, proc.stderr
        assert "is truncated or corrupt" in proc.stdout.splitlines()[0]
        assert proc.stdout.startswith(f"rebuilt {run / 'episode.rrd'} from ")
        assert len(read_rrd_joints(run / "episode.rrd")) == STEPS
    alone = tmp_path / "alone.rrd"
    alone.write_bytes(whole[: len(whole) * 2 // 3])
    proc = _replay(str(alone), "--build")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert proc.stderr.startswith(f"error: rerun log {alone} is truncated or corrupt (")
    assert proc.stderr.strip().endswith("and no alone.mcap next to it to rebuild it from")


def test_plots_split_by_quantity_and_camera_frames_every_point():
    groups = dict(plot_groups(["psi", "psi_rate", "clearance_m", "energy_total", "alpha",
                               "compute_time_ms", "position_error_m"]))
    assert groups["ψ (PUMA potential)"] == ["psi"] and groups["method internals"] == ["alpha"]
    assert groups["clearance [m]"] == ["clearance_m"] and "contacts" not in groups
    replay_blueprint(["psi"], ["j1"], None)  # builds without a camera

    rng = np.random.default_rng(0)
    pts = rng.uniform([-0.3, -0.6, 0.0], [0.8, 0.6, 1.2], size=(300, 3))
    cam = frame_camera(pts, aspect=1.2)
    uv = cam.project(pts, 1200, 1000)
    assert np.all((uv >= 0) & (uv <= [1200, 1000]))  # everything in view...
    span = uv.max(axis=0) - uv.min(axis=0)
    assert span[0] > 0.6 * 1200 or span[1] > 0.6 * 1000  # ...and not from far away
    # projection check: a point on the optical axis lands in the image centre
    np.testing.assert_allclose(cam.project(cam.look_target[None], 1200, 1000), [[600, 500]])


def _arm_mask(with_arm: np.ndarray, without_arm: np.ndarray) -> np.ndarray:
    return np.abs(with_arm.astype(int) - without_arm.astype(int)).max(axis=2) > 40


@pytest.mark.skipif(not vulkan_available(),
                    reason="no Vulkan driver for Rerun's headless viewer (Debian: apt-get "
                           "install mesa-vulkan-drivers)")
def test_rendered_replay_shows_the_arm_where_its_links_project(sweep, tmp_path):
    """Render the scene view at the last step with and without the arm; the pixels that differ
    are the arm's. They must lie along the links projected through the blueprint's camera, and
    each link origin must project onto them."""
    from PIL import Image
    from scipy.spatial import cKDTree

    from tamedpuma.app.replay import prepare

    run = sweep[0]
    replay = prepare(run, reference=None)
    log, records = mcap_records(run / "episode.mcap")
    last = records[-1]
    with HeadlessViewer(size=(1000, 700)) as viewer:
        viewer.open([replay.rrd])
        step = viewer.last_step()
        assert step == last.step == STEPS - 1
        viewer.set_step(step)
        shot = viewer.save(tmp_path / "arm.png", view="scene")
        layout = viewer.client.get_blueprint().blueprint
        key = next(k for k in layout if k.endswith("/EyeControls3D"))
        eye = layout[key]["EyeControls3D"]
        hidden = {k for k, v in layout.items()
                  if v.get("EntityBehavior", {}).get("visible") is False}
        assert any("lbr_iiwa/collision_geometries" in k for k in hidden)  # no z-fighting
        assert any("body_spheres" in k for k in hidden)
        # the same layout with the arm hidden (as the eye icon in the viewer would)
        view = key[: -len("/EyeControls3D")]
        layout[f"{view}/ViewContents/overrides/world/lbr_iiwa/visualizers"] = {
            "EntityBehavior": {"visible": False}}
        viewer.client.set_blueprint(layout, of="recording")
        viewer.set_step(step)
        bare = viewer.save(tmp_path / "bare.png", view="scene")

    a = np.asarray(Image.open(shot).convert("RGB"))
    b = np.asarray(Image.open(bare).convert("RGB"))
    assert a.shape == b.shape and a.std() > 10  # not blank
    mask = _arm_mask(a, b)
    h, w = mask.shape
    assert 0.01 < mask.mean() < 0.6, mask.mean()
    arm_px = np.argwhere(mask)[:, ::-1] + 0.5  # (x, y) pixel centres

    camera = Camera(np.array(eye["position"]), np.array(eye["look_target"]))
    links = last.link_positions
    uv = camera.project(links, w, h)
    assert np.all((uv > 0) & (uv < [w, h])), uv
    tree = cKDTree(arm_px)
    dist_px, _ = tree.query(uv)
    assert np.all(dist_px < 0.03 * h), dist_px  # every link origin lands on the arm

    # every arm pixel lies within the arm's thickness of the projected chain of link origins
    chain = np.concatenate([np.linspace(p, q, 40) for p, q in zip(links[:-1], links[1:])])
    depth = np.linalg.norm(chain - camera.position, axis=1).min()
    f = 0.5 * h / np.tan(np.deg2rad(55.0) / 2)
    reach = f * 0.2 / depth  # link radius ≤ 0.1 m, base ≤ 0.15 m, plus the flange [m]
    near, _ = cKDTree(camera.project(chain, w, h)).query(arm_px)
    assert np.mean(near < reach) > 0.95
    # ...and the test can fail: the chain mirrored left-right does not explain the pixels
    mirrored = camera.project(chain, w, h) * [-1, 1] + [w, 0]
    far, _ = cKDTree(mirrored).query(arm_px)
    assert np.mean(far < reach) < 0.8


def test_ci_installs_the_vulkan_driver():
    script = (REPO / ".ci" / "run").read_text()
    assert "mesa-vulkan-drivers" in script and os.access(REPO / ".ci" / "run", os.X_OK)


def test_foxglove_layout_names_recorded_channels(sweep):
    """docs/foxglove_layout.json: every panel of the mosaic is configured, and every message
    path reads a channel (and for /scalars a field) that the recorder writes."""
    import json

    from mcap.reader import make_reader

    layout = json.loads((REPO / "docs" / "foxglove_layout.json").read_text())
    panels, stack = [], [layout["layout"]]
    while stack:
        node = stack.pop()
        if isinstance(node, str):
            panels.append(node)
        else:
            stack += [node["first"], node["second"]]
    assert set(panels) == set(layout["configById"])
    with open(sweep[0] / "episode.mcap", "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    fields = set(read_mcap(sweep[0] / "episode.mcap").scalars.columns)
    for name, cfg in layout["configById"].items():
        paths = [p["value"] for p in cfg.get("paths", [])] + [cfg.get("topicPath", "")]
        paths += list(cfg.get("topics", {}))
        for path in filter(None, paths):
            topic = "/" + path.lstrip("/").split(".")[0]
            assert topic in topics, (name, path)
        assert all(p["value"].split(".", 1)[1] in fields | {"psi", "min_clearance_m",
                                                            "energy_total", "energy_fabric",
                                                            "energy_execution"}
                   for p in cfg.get("paths", []) if p["value"].startswith("/scalars."))


def test_web_serving_hands_the_files_to_the_viewer_with_cors(sweep):
    """--web: the run's files over HTTP with a CORS header, named in the viewer link."""
    import urllib.parse
    import urllib.request

    from tamedpuma.app.replay import prepare, serve_files, web_url

    replay = prepare(sweep[1], reference=None)
    server = serve_files(replay.rrd.parent, "127.0.0.1", 0)
    try:
        port = server.server_address[1]
        link = web_url("127.0.0.1", 9090, port, replay.files, replay.rrd.parent)
        (url,) = urllib.parse.parse_qs(urllib.parse.urlparse(link).query)["url"]
        with urllib.request.urlopen(url, timeout=10) as resp:
            assert resp.headers["Access-Control-Allow-Origin"] == "*"
            assert resp.read() == replay.rrd.read_bytes()
    finally:
        server.shutdown()
        server.server_close()


def _drawn_cells_under(corner, t, values, names):
    """How many cells of a 60 × 20 drawing of the curves the legend in ``corner`` covers (the
    same box sizes as the recorder: a test of the choice, not of the geometry)."""
    from tamedpuma.recording import rerun_writer as rw

    x = np.repeat((t - t.min()) / np.ptp(t), values.shape[1])
    v = values.ravel()
    y = (v - v.min()) / np.ptp(v)
    cells = {(min(int(a * 60), 59), min(int(b * 20), 19)) for a, b in zip(x, y)}
    h = min(1.0, rw.LEGEND_PAD + rw.LEGEND_ROW * len(names))
    w = min(1.0, rw.LEGEND_PAD_X + rw.LEGEND_CHAR * max(map(len, names)))
    right, top = corner.name.startswith("Right"), corner.name.endswith("Top")
    return sum(((cx + 0.5) / 60 >= 1 - w if right else (cx + 0.5) / 60 <= w)
               and ((cy + 0.5) / 20 >= 1 - h if top else (cy + 0.5) / 20 <= h)
               for cx, cy in cells)


@pytest.mark.parametrize("shape", ["falls", "falls_then_rises", "rises"])
def test_a_plots_legend_takes_the_corner_its_curves_leave_free(shape):
    """The clearance curve starts high and falls (near an obstacle), often rising again as the
    arm leaves it: the legend goes where no curve is drawn, not over it."""
    t = np.linspace(0.0, 17.0, 170)
    s = t / t[-1]
    clearance = {"falls": 0.3 * (1 - s) ** 2,
                 "falls_then_rises": 0.14 - 0.14 * np.sin(np.pi * s / 0.7) * (s < 0.7)
                 + 0.35 * np.clip(s - 0.55, 0, None),
                 "rises": 0.02 + 0.3 * s ** 2}[shape]
    values = np.column_stack([clearance, clearance - 0.01])
    names = ["clearance_m", "min_clearance_m"]
    corner = legend_corner(t, values, names)
    covered = {c: _drawn_cells_under(c, t, values, names) for c in LEGEND_CORNERS}
    assert covered[corner] == min(covered.values()), covered  # the least covered...
    assert shape == "falls_then_rises" or covered[corner] == 0  # ...nothing where one is free
    if shape == "rises":  # the right top, the viewer's default, would cover the curve
        assert covered[LEGEND_CORNERS[0]] > 0 and corner != LEGEND_CORNERS[0]
    assert legend_corner(t, np.full((len(t), 1), np.nan), ["x"]) == LEGEND_CORNERS[0]


def _legends(blueprint) -> dict[str, object]:
    grid = blueprint.root_container.contents[1]
    return {v.name: v.properties["PlotLegend"] for v in grid.contents}


def test_the_replays_legends_take_their_corners_from_the_recorded_curves(sweep, tmp_path):
    from tamedpuma.recording.convert import mcap_to_rrd, run_info
    from tamedpuma.recording.rerun_writer import RerunRecorder

    log, records = mcap_records(sweep[0] / "episode.mcap")
    recorder = RerunRecorder(tmp_path / "episode.rrd")
    recorder.open(run_info(log))
    for record in records:
        recorder.write(record)
    recorder.close(complete=True, summary={})
    legends = _legends(recorder.blueprint())
    t = log.scalars["t"].to_numpy()[::5]
    for title, names in plot_groups(list(records[0].scalars)):
        values = log.scalars[names].to_numpy()[::5]
        assert _corner(legends[title]) == _value(legend_corner(t, values, names)), title
    q = log.joints[[f"q_{i}" for i in range(7)]].to_numpy()[::5]
    assert _corner(legends["joints [rad]"]) == _value(legend_corner(t, q,
                                                                    run_info(log).joint_names))
    # ...which are not all the viewer's default (else this test could not tell)
    assert {_corner(legend) for legend in legends.values()} != {_value(LEGEND_CORNERS[0])}
    assert mcap_to_rrd(sweep[0] / "episode.mcap", tmp_path / "again.rrd") == len(records)


def _corner(legend) -> int:
    return legend.corner.as_arrow_array().to_pylist()[0]


def _value(corner) -> int:
    import rerun.blueprint as rrb

    return _corner(rrb.PlotLegend(corner=corner))


def test_the_reference_paths_label_is_drawn_below_its_end_not_on_the_strip(tmp_path):
    """The strip keeps its label for hover but does not draw it; the drawn label is a point
    0.15 m below the path's end (the goal, which the arm reaches from above)."""
    from rerun.chunk import RrdReader

    from tamedpuma.recording.rerun_writer import REFERENCE_PATH, write_reference_overlay

    points = np.array([[0.5, 0.3, 0.8], [0.5, 0.1, 0.5], [0.6, -0.1, 0.3]])
    path = write_reference_overlay(tmp_path / "ref.rrd", "run", points, label="puma, no obst")
    store = RrdReader(path).stream().collect()
    row = store.reader(index=None, contents=f"{REFERENCE_PATH}/**").to_pandas().iloc[0]
    assert list(row[f"{REFERENCE_PATH}:LineStrips3D:show_labels"]) == [False]
    assert list(row[f"{REFERENCE_PATH}:LineStrips3D:labels"]) == ["puma, no obst"]
    assert list(row[f"{REFERENCE_PATH}/label:Points3D:show_labels"]) == [True]
    assert list(row[f"{REFERENCE_PATH}/label:Points3D:labels"]) == ["puma, no obst"]
    (anchor,) = row[f"{REFERENCE_PATH}/label:Points3D:positions"]
    np.testing.assert_allclose(anchor, points[-1] - [0.0, 0.0, 0.15], atol=1e-6)
