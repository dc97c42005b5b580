"""compile_once: one attempt per process, a warning and the plain path where it fails."""

import warnings

import pytest

from tamedpuma.jit import compile_once


def test_the_result_is_built_once_and_kept():
    memo, calls = [], []

    def build():
        calls.append(1)
        return {"kernel": len(calls)}

    first = compile_once(memo, build, True, "the kernels", "plain")
    assert first == {"kernel": 1} and compile_once(memo, build, True, "the kernels", "plain") \
        is first
    assert calls == [1] and memo == [first]


def test_without_numba_nothing_is_built_and_nothing_warned():
    memo = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert compile_once(memo, lambda: pytest.fail("built"), False, "x", "y") is None
    assert memo == [None]


def test_a_failing_build_warns_once_naming_the_kernels_and_the_fallback():
    memo, calls = [], []

    def broken():
        calls.append(1)
        raise ImportError("numba built for another numpy")

    with pytest.warns(UserWarning, match=r"numba could not compile the DTW recurrence "
                                         r"\(ImportError: numba built for another numpy\); it "
                                         r"runs in numpy"):
        assert compile_once(memo, broken, True, "the DTW recurrence", "it runs in numpy") is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no second attempt, no second warning
        assert compile_once(memo, broken, True, "the DTW recurrence", "it runs in numpy") is None
    assert calls == [1]
