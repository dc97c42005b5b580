"""A termination asked for by a signal, which the control loop honours at its next step.

A signal handler raises ``SystemExit`` to unwind a run (its logs close as incomplete). Python
loses that exception when the handler happens to run inside a finaliser or a callback invoked
from C (it prints "Exception ignored in ..." and goes on), and the run then kept stepping,
deaf to further SIGTERMs. So the handler also records the request here, and the episode loop
raises it again at the first control step after it (:func:`check`, a list lookup per step).
"""

from __future__ import annotations

_REQUESTED: list[int] = []  # the exit status of the first request, once there is one


def request(status: int) -> None:
    """Ask the running episode to end with ``SystemExit(status)`` (the first request holds)."""
    if not _REQUESTED:
        _REQUESTED.append(status)


def requested() -> bool:
    """Whether a termination was asked for (and not yet cleared)."""
    return bool(_REQUESTED)


def check() -> None:
    """Raise ``SystemExit`` with the requested status if a termination was asked for."""
    if _REQUESTED:
        raise SystemExit(_REQUESTED[0])


def clear() -> None:
    """Forget a request (a new command started in the same process)."""
    _REQUESTED.clear()
