"""Numba compilation of plain-Python kernels that call plain-Python helpers: what the step's
compiled kernels (:mod:`tamedpuma.methods._kernels`) and the network's
(:mod:`tamedpuma.puma.single_kernels`) share. numba is imported only when :func:`compile_kernels`
runs."""

from __future__ import annotations

import types
from collections.abc import Callable, Iterable


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
