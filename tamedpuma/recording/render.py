"""Render a replay without a display: Rerun's native viewer in headless mode, driven over gRPC.

:class:`HeadlessViewer` starts ``rerun --headless`` on a free port (it needs a Vulkan driver; on a
machine without a GPU, Debian's ``mesa-vulkan-drivers`` provides the lavapipe software
rasterizer), opens ``.rrd`` files (files sharing a recording id merge into one recording), moves
the time cursor, hides entities, and saves screenshots of the whole viewer or of one view.
:func:`screenshot` is the one-call form used by ``python -m tamedpuma.replay --screenshot``.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from ..errors import TamedPumaError

#: Seconds a freshly opened viewer shows its start-up notices ("software rasterizer detected",
#: ...); a whole-viewer screenshot waits this long so they have faded.
NOTICE_SECONDS = 6.0


class RenderError(TamedPumaError):
    """The headless viewer could not be started or did not answer."""


def rerun_executable() -> str:
    """The native ``rerun`` binary shipped with rerun-sdk (not the Python wrapper script, so a
    kill reaches the viewer itself), else ``rerun`` on PATH."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / "rerun"
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    found = shutil.which("rerun")
    if found is None:
        raise RenderError("the rerun executable was not found (pip install rerun-sdk)")
    return found


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def vulkan_available() -> bool:
    """Whether a Vulkan driver (GPU or Mesa's lavapipe) is installed: the native viewer needs
    one. Checks the loader's ICD manifests (the standard locations)."""
    dirs = ["/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d"]
    return any(Path(d).is_dir() and any(Path(d).glob("*.json")) for d in dirs)


class HeadlessViewer:
    """A headless Rerun viewer process and a client to drive it (use as a context manager).

    size: window size (width, height) in logical points; screenshots are taken at the viewer's
    pixel density (2 pixels per point here). timeout: seconds to wait for the viewer to listen.
    """

    def __init__(self, size: tuple[int, int] = (1280, 720), timeout: float = 30.0):
        self.size = size
        self.timeout = timeout
        self._proc: subprocess.Popen | None = None
        self.client = None
        self.opened_at = 0.0

    def __enter__(self) -> HeadlessViewer:
        from rerun.experimental import ViewerClient

        port = _free_port()
        env = {**os.environ, "RERUN_APP_ONLY": "true"}
        env.setdefault("XDG_RUNTIME_DIR", tempfile.gettempdir())
        cmd = [rerun_executable(), "--headless", "--window-size", f"{self.size[0]}x{self.size[1]}",
               "--port", str(port), "--hide-welcome-screen", "--memory-limit", "2GB"]
        self._log = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(cmd, env=env, stdout=self._log, stderr=subprocess.STDOUT,
                                      start_new_session=True)
        deadline = time.monotonic() + self.timeout
        while True:
            if self._proc.poll() is not None:
                self._log.seek(0)
                tail = self._log.read().decode(errors="replace").strip().splitlines()[-3:]
                self._cleanup()
                raise RenderError("the headless Rerun viewer exited: " + " | ".join(tail))
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                    break
            except OSError:
                if time.monotonic() > deadline:
                    self.__exit__(None, None, None)
                    raise RenderError(f"the headless Rerun viewer did not listen within "
                                      f"{self.timeout:.0f} s") from None
                time.sleep(0.1)
        self.client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
        return self

    def __exit__(self, *exc) -> None:
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGTERM)
                proc.wait(timeout=5)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        self._cleanup()

    def _cleanup(self) -> None:
        if getattr(self, "_log", None) is not None:
            self._log.close()
            self._log = None

    # -- driving ---------------------------------------------------------------------------

    def open(self, paths: Sequence[str | os.PathLike]) -> None:
        """Open the files (absolute paths) and wait until they are loaded."""
        result = self.client.open([str(Path(p).resolve()) for p in paths])
        deadline = time.monotonic() + self.timeout
        while result.loading or self.client.get_state().loading:
            if time.monotonic() > deadline:
                raise RenderError(f"the viewer did not finish loading {list(map(str, paths))}")
            time.sleep(0.2)
            result = type(result)(store_ids=result.store_ids, loading=[])
        self.opened_at = time.monotonic()

    def last_step(self, timeline: str = "step") -> int:
        """The last index of ``timeline`` in the active recording."""
        state = self.client.get_state()
        rec = next(r for r in state.recordings if r.store_id == state.active_recording)
        line = next((t for t in rec.timelines if t.name == timeline), None)
        if line is None:
            raise RenderError(f"the recording has no {timeline!r} timeline")
        return int(line.end)

    def set_step(self, step: int, timeline: str = "step") -> None:
        """Pause the time cursor at ``step`` (the plots' x-axis then counts steps, #0 ...)."""
        self.client.set_time(timeline, sequence=int(step), play_state="paused")

    def last_time(self, timeline: str = "time") -> float:
        """The end of the duration timeline ``timeline`` in the active recording [s]."""
        return self.last_step(timeline) / 1e9

    def set_time(self, seconds: float, timeline: str = "time") -> None:
        """Pause the time cursor at ``seconds`` of the duration timeline (the blueprint's own:
        the plots' x-axis in seconds)."""
        self.client.set_time(timeline, duration=float(seconds), play_state="paused")

    def view_id(self, name: str) -> str:
        """The id of the view called ``name`` in the active blueprint."""
        views = self.client.get_state().views
        for v in views:
            if v.name == name:
                return v.view_id
        raise RenderError(f"no view named {name!r} (views: {[v.name for v in views]})")

    def save(self, out: str | os.PathLike, view: str | None = None) -> Path:
        """Screenshot the whole viewer (after the start-up notices faded) or one named view."""
        out = Path(out).resolve()
        out.parent.mkdir(parents=True, exist_ok=True)
        if view is None:
            wait = NOTICE_SECONDS - (time.monotonic() - self.opened_at)
            if wait > 0:
                time.sleep(wait)
            self.client.save_screenshot(str(out))
        else:
            self.client.save_screenshot(str(out), view_id=self.view_id(view))
        return out


def screenshot(paths: Sequence[str | os.PathLike], out: str | os.PathLike,
               at: float | None = None, size: tuple[int, int] = (1280, 720),
               view: str | None = None) -> tuple[Path, float]:
    """Render ``paths`` (``.rrd`` files of one recording) at simulated time ``at`` [s] (default:
    the end) to the PNG ``out``: the whole viewer, or only the view named ``view`` (e.g.
    ``"scene"``). Returns (the PNG's path, the time shown [s]). Raises :class:`RenderError`."""
    with HeadlessViewer(size=size) as viewer:
        viewer.open(paths)
        last = viewer.last_time()
        shown = last if at is None else min(max(float(at), 0.0), last)
        viewer.set_time(shown)
        return viewer.save(out, view=view), shown
