"""Numba compilation of plain-Python kernels that call plain-Python helpers, once per process:
what the compiled kernels of the kinematics (:mod:`tamedpuma.robot.point_motion`), the step
(:mod:`tamedpuma.methods._kernels`), the network (:mod:`tamedpuma.puma.single_kernels`) and the
DTW recurrence (:mod:`tamedpuma.puma.evaluation`) share. numba is imported only when
:func:`compile_kernels` runs."""

from __future__ import annotations

import types
import warnings
from collections.abc import Callable, Iterable
from typing import TypeVar

T = TypeVar("T")


def compile_once(memo: list, build: Callable[[], T], available: bool, what: str,
                 fallback: str) -> T | None:
    """``build()``'s result, built at the first call and kept in ``memo`` (an empty list the
    caller owns: ``[result]`` after it); None where numba is not installed (``available``
    False) or ``build`` raises (a broken numba install), then with one warning, "numba could
    not compile ``what`` (the error); ``fallback``". No second attempt either way."""
    if not memo:
        result = None
        if available:
            try:
                result = build()
            except Exception as exc:  # noqa: BLE001 - any failure leaves the plain functions
                warnings.warn(f"numba could not compile {what} ({type(exc).__name__}: {exc}); "
                              f"{fallback}", stacklevel=3)
        memo.append(result)
    return memo[0]


def compile_kernels(namespace: dict, kernels: Iterable[Callable],
                    helpers: Iterable[Callable] = ()) -> dict[str, Callable]:
    """``{name: compiled copy}`` of each kernel (``numba.njit(cache=True, nogil=True)``, loaded
    from numba's on-disk cache after the first time), whose calls of the helpers reach compiled
    copies: every function is copied over a copy of ``namespace`` (its module's globals), so the
    module's own functions stay plain."""
    import numba

    space = dict(namespace)

    def jit(fn):
        copy = types.FunctionType(fn.__code__, space, fn.__name__, fn.__defaults__)
        return numba.njit(cache=True, nogil=True)(copy)

    for helper in helpers:
        space[helper.__name__] = jit(helper)
    return {k.__name__: jit(k) for k in kernels}
