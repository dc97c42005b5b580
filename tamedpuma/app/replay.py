"""``python -m tamedpuma.replay RUN``: look at a recorded run in the Rerun viewer.

RUN is a run folder, its ``episode.mcap`` or its ``episode.rrd``. The MCAP is the source of
truth: when the ``.rrd`` is missing (``recorder=mcap`` runs) it is rebuilt from the MCAP next to
it (``--rebuild`` rebuilds it anyway). When the same sweep holds PUMA's obstacle-free run of the
same task and scenario, its end-effector path is added as ``/world/reference_path`` (a small
``episode.reference.rrd`` overlay; the run's own files are not modified).

    python -m tamedpuma.replay runs/<run>                         # native viewer (needs a display)
    python -m tamedpuma.replay runs/<run> --web                   # headless machine: a browser link
    python -m tamedpuma.replay runs/<run> --screenshot shot.png [--at 3.5] [--view scene]
    python -m tamedpuma.replay runs/<run> --build                 # only write the .rrd files

``--web`` serves the Rerun web viewer's files and the recording over plain HTTP (with a CORS
header) and prints the address to open; nothing is computed while nobody looks (``rerun
--serve-web FILE`` keeps a core busy instead). ``--screenshot`` renders with Rerun's native viewer
in headless mode (Vulkan; without a GPU, Debian's ``mesa-vulkan-drivers``), by default at the
last step. A mistake (missing run, unreadable log, no display) prints one line ``error: ...``
and exits with status 2.
"""

from __future__ import annotations

import argparse
import functools
import http.server
import json
import os
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

from tamedpuma.app.cli import fail
from tamedpuma.errors import LogError, TamedPumaError

MCAP_NAME = "episode.mcap"
RRD_NAME = "episode.rrd"
OVERLAY_NAME = "episode.reference.rrd"
REFERENCE_METHOD = "puma"


@dataclass(frozen=True)
class Replay:
    """The files of one replay: the run's ``.rrd`` (built if needed), the MCAP it came from (if
    any), an optional reference-path overlay, and what was done to get them."""

    rrd: Path
    mcap: Path | None
    overlay: Path | None
    rebuilt: bool
    reference_run: Path | None
    why: str = ""  # why the .rrd was rebuilt although it existed (it was unreadable)

    @property
    def files(self) -> list[Path]:
        return [self.rrd] + ([self.overlay] if self.overlay else [])


def locate(run: Path) -> tuple[Path | None, Path]:
    """(MCAP or None, where the ``.rrd`` is or goes) for a run folder, ``.mcap`` or ``.rrd``."""
    if run.is_dir():
        mcap = next((p for p in (run / MCAP_NAME, run / f"{MCAP_NAME}.active") if p.is_file()),
                    None)
        rrd = run / RRD_NAME
        if mcap is None and not rrd.is_file():
            raise TamedPumaError(_no_run_here(run))
        return mcap, rrd
    if not run.exists():
        raise TamedPumaError(f"{run} not found")
    name = run.name
    if name.endswith(".mcap") or name.endswith(".mcap.active"):
        stem = name[: name.index(".mcap")]
        return run, run.with_name(f"{stem}.rrd")
    if name.endswith(".rrd"):
        return None, run
    raise TamedPumaError(f"{run} is not a run folder, .mcap or .rrd file")


def _no_run_here(folder: Path, shown: int = 5) -> str:
    """Why ``folder`` cannot be replayed: a folder of runs (named, the first ``shown``), or a
    folder holding no log at all."""
    from tamedpuma.analysis.runs import find_logs

    runs = sorted({p.parent for p in find_logs(folder)})
    if not runs:
        return f"{folder} holds no {MCAP_NAME} or {RRD_NAME}, nor run folders below it"
    names = ", ".join(str(r.relative_to(folder)) for r in runs[:shown])
    more = f" and {len(runs) - shown} more" if len(runs) > shown else ""
    return (f"{folder} is a folder of {len(runs)} runs, not one run: replay one of them "
            f"({names}{more}), e.g. python -m tamedpuma.replay {runs[0]}")


def incomplete_note(mcap: Path | None) -> str | None:
    """One line when the run's log is incomplete (killed, interrupted or truncated), else
    None: a replay then shows the run up to where its log ends."""
    from tamedpuma.recording import read_mcap

    if mcap is None:
        return None
    try:
        log = read_mcap(mcap)
    except TamedPumaError:
        return None
    if log.complete:
        return None
    why = f": {log.read_error}" if log.read_error else ""
    return (f"incomplete run: {mcap} ends at step {log.n_steps} (the run was killed, "
            f"interrupted or its log truncated{why})")


def check_reference(method: str) -> None:
    """A ``--reference`` that names no method config (``conf/method``) is a mistake."""
    from tamedpuma.app.config import group_options

    known = group_options("method")
    if method not in known:
        raise TamedPumaError(f"--reference {method}: no such method; choose one of "
                             f"{', '.join(known)} or none")


def _summary(run_dir: Path) -> dict:
    try:
        return json.loads((run_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return {}


def find_reference(mcap: Path, method: str = REFERENCE_METHOD) -> tuple[Path, object] | None:
    """PUMA's obstacle-free run of the same task and scenario in the same sweep folder (a sibling
    run folder): (its MCAP, its (T, 3) end-effector path [m]), or None."""
    from tamedpuma.recording import read_mcap

    run_dir = mcap.parent
    try:
        own = read_mcap(mcap).info
    except TamedPumaError:
        return None
    for sibling in sorted(run_dir.parent.iterdir()):
        path = sibling / MCAP_NAME
        if sibling == run_dir or not path.is_file():
            continue
        summary = _summary(sibling)
        if summary and (summary.get("method") != method or summary.get("task") != own.get("task")
                        or summary.get("scenario") != own.get("scenario_name")):
            continue
        try:
            log = read_mcap(path)
        except TamedPumaError:
            continue
        info = log.info
        if (info.get("method") == method and info.get("task") == own.get("task")
                and info.get("scenario_name") == own.get("scenario_name")
                and len(log.obstacles) == 0 and log.n_steps > 1):
            return path, log.ee[["x", "y", "z"]].to_numpy()
    return None


def prepare(run: Path, rebuild: bool = False,
            reference: str | None = REFERENCE_METHOD) -> Replay:
    """Find or build the replay files of ``run`` (see the module docstring); ``reference``: the
    method whose obstacle-free run in the same sweep is overlaid (None: none)."""
    from tamedpuma.recording.convert import mcap_to_rrd
    from tamedpuma.recording.reader import check_rrd, read_mcap
    from tamedpuma.recording.rerun_writer import write_reference_overlay

    mcap, rrd = locate(run)
    rebuilt, why = False, ""
    if rrd.is_file() and not rebuild:
        try:
            check_rrd(rrd)
        except LogError as exc:
            mcap = mcap or next((p for p in (rrd.with_suffix(".mcap"),
                                             rrd.with_suffix(".mcap.active")) if p.is_file()),
                                None)
            if mcap is None:
                raise LogError(f"{exc}, and no {rrd.with_suffix('.mcap').name} next to it "
                               "to rebuild it from") from None
            rebuild, why = True, str(exc)
    if mcap is not None and (rebuild or not rrd.is_file()):
        mcap_to_rrd(mcap, rrd, overwrite=True)
        rebuilt = True
    overlay, ref_run = None, None
    if reference and mcap is not None:
        found = find_reference(mcap, reference)
        if found is not None:
            ref_run, points = found
            run_id = read_mcap(mcap).info.get("run_id", mcap.parent.name)
            overlay = write_reference_overlay(rrd.with_name(OVERLAY_NAME), run_id, points,
                                              label=f"{reference}, no obstacles")
    return Replay(rrd=rrd, mcap=mcap, overlay=overlay, rebuilt=rebuilt, reference_run=ref_run,
                  why=why)


# -- ways to look ----------------------------------------------------------------------------


def open_native(replay: Replay) -> int:
    """The native viewer (blocks until it is closed)."""
    from tamedpuma.recording.render import rerun_executable

    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                 or os.environ.get("WAYLAND_DISPLAY")):
        raise TamedPumaError("no display: use --web (browser) or --screenshot FILE.png")
    return subprocess.call([rerun_executable(), *map(str, replay.files)])


class _CorsHandler(http.server.SimpleHTTPRequestHandler):
    """Static files with ``Access-Control-Allow-Origin: *`` (the web viewer fetches the .rrd
    from another port), quiet."""

    def end_headers(self):
        self.send_header("Access-Control-Allow-Origin", "*")
        super().end_headers()

    def log_message(self, *args):
        pass


def serve_files(folder: Path, host: str, port: int) -> http.server.ThreadingHTTPServer:
    """An HTTP server for ``folder`` (with CORS) on a background thread."""
    handler = functools.partial(_CorsHandler, directory=str(folder))
    server = http.server.ThreadingHTTPServer((host, port), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def web_url(host: str, web_port: int, file_port: int, files: list[Path], folder: Path) -> str:
    from urllib.parse import quote

    urls = "&".join("url=" + quote(f"http://{host}:{file_port}/{f.relative_to(folder)}", safe="")
                    for f in files)
    return f"http://{host}:{web_port}/?{urls}"


def viewer_command(host: str, web_port: int, urls: list[str]) -> list[str]:
    """The Rerun CLI hosting only the web viewer's own files on ``host:web_port`` (``--bind``:
    the Python SDK's ``serve_web_viewer`` has no address and listens on every interface); the
    viewer loads the recordings from ``urls`` (nothing is computed while nobody looks)."""
    from tamedpuma.recording.render import rerun_executable

    return [rerun_executable(), "--serve-web", "--bind", host, "--web-viewer-port",
            str(web_port), *urls]


def serve_web(replay: Replay, host: str, web_port: int, file_port: int) -> int:
    """Host the web viewer and the files on ``host`` until Ctrl-C."""
    folder = replay.rrd.parent
    files = [f for f in replay.files if f.parent == folder]
    server = serve_files(folder, host, file_port)
    link = web_url(host, web_port, server.server_address[1], files, folder)
    urls = [part.removeprefix("url=") for part in link.split("?", 1)[1].split("&")]
    from urllib.parse import unquote

    viewer = subprocess.Popen(viewer_command(host, web_port, [unquote(u) for u in urls]),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    print(f"open {link}")
    print("(Ctrl-C stops serving)")
    try:
        code = viewer.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        viewer.terminate()
        viewer.wait()
        server.shutdown()
    raise TamedPumaError(f"the Rerun web viewer stopped (exit status {code}); is port "
                         f"{web_port} in use? (--port)")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    return w, h


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tamedpuma.replay",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="run folder, episode.mcap or episode.rrd")
    parser.add_argument("--web", action="store_true", help="serve a browser viewer")
    parser.add_argument("--screenshot", type=Path, metavar="FILE.png",
                        help="render to a PNG without a display")
    parser.add_argument("--at", type=float, default=None, metavar="TIME",
                        help="simulated time [s] of the screenshot (default: the last step)")
    parser.add_argument("--view", default=None,
                        help="screenshot only this view (e.g. scene); default: the whole viewer")
    parser.add_argument("--size", type=_size, default=(1600, 900), metavar="WxH",
                        help="screenshot window size in points (default 1600x900)")
    parser.add_argument("--rebuild", action="store_true", help="rebuild the .rrd from the MCAP")
    parser.add_argument("--build", action="store_true",
                        help="only build the replay files and print where they are")
    parser.add_argument("--reference", default=REFERENCE_METHOD, metavar="METHOD",
                        help="overlay this method's obstacle-free path from the same sweep "
                             "(default: puma; 'none' for no overlay)")
    parser.add_argument("--host", default="127.0.0.1", help="--web address (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=9090, help="--web viewer port (default 9090)")
    args = parser.parse_args(argv)
    try:
        reference = None if args.reference.lower() == "none" else args.reference
        if reference is not None:
            check_reference(reference)
        replay = prepare(args.run, rebuild=args.rebuild, reference=reference)
        if replay.rebuilt:
            print(f"rebuilt {replay.rrd} from {replay.mcap}"
                  + (f" ({replay.why})" if replay.why else ""))
        if replay.reference_run is not None:
            print(f"reference path: {replay.reference_run.parent.name} ({reference}, "
                  "no obstacles)")
        elif reference is not None and args.reference != REFERENCE_METHOD:
            print(f"reference path: none (no obstacle-free {reference} run of this task and "
                  "scenario beside this run)")
        note = incomplete_note(replay.mcap)
        if note:
            print(note)
        if args.build:
            print("\n".join(map(str, replay.files)))
            return 0
        if args.screenshot is not None:
            return _screenshot(replay, args)
        if args.web:
            return serve_web(replay, args.host, args.port, 0)
        return open_native(replay)
    except (TamedPumaError, FileExistsError, OSError) as exc:
        fail(str(exc))
    return 2


def _screenshot(replay: Replay, args) -> int:
    from tamedpuma.recording.render import HeadlessViewer, RenderError, vulkan_available

    if not vulkan_available():
        raise RenderError("no Vulkan driver for the headless viewer (Debian: apt-get install "
                          "mesa-vulkan-drivers)")
    with HeadlessViewer(size=args.size) as viewer:
        viewer.open(replay.files)
        # on the "time" timeline (the layout's): the plots' x-axis in seconds, not #steps
        at = viewer.last_time() if args.at is None else float(args.at)
        viewer.set_time(at)
        where = f"t = {at:g} s" + (f" (the last step, {viewer.last_step()})"
                                    if args.at is None else "")
        out = viewer.save(args.screenshot, view=args.view)
    print(f"screenshot of {replay.rrd} at {where}: {out}")
    return 0
