"""Signals while an entry point loads its modules (seconds: torch, pinocchio, Hydra).

Ctrl-C then printed the whole import chain as a traceback, and SIGTERM ended the process
without a word. :func:`starting` turns either into one line and the conventional status
(130 for Ctrl-C, 143 for SIGTERM); nothing has run yet, so nothing is left behind.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator


class _Terminated(BaseException):
    """SIGTERM while loading (raised by the handler :func:`starting` installs)."""


def _terminate(signum, frame) -> None:
    raise _Terminated


@contextlib.contextmanager
def starting() -> Iterator[None]:
    """Around an entry point's imports: Ctrl-C or SIGTERM inside is one line
    ``interrupted (Ctrl-C|SIGTERM) while starting: nothing was run`` and exit status 130|143;
    the previous SIGTERM handler is restored after (only the main thread handles signals: in
    another one this does nothing)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    except (KeyboardInterrupt, _Terminated) as exc:
        name, status = ("SIGTERM", 143) if isinstance(exc, _Terminated) else ("Ctrl-C", 130)
        sys.stderr.write(f"interrupted ({name}) while starting: nothing was run\n")
        raise SystemExit(status) from None
    finally:
        signal.signal(signal.SIGTERM, previous)
