"""Work over the usable cores (tamedpuma/parallel.py): the order and results of a plain loop."""

from __future__ import annotations

import os

from tamedpuma.parallel import process_map


def _square_and_pid(x: int) -> tuple[int, int]:
    return x * x, os.getpid()


def test_process_map_keeps_the_order_and_uses_worker_processes():
    items = list(range(50))
    out = process_map(_square_and_pid, items, jobs=2, min_items=10)
    assert [v for v, _ in out] == [x * x for x in items]
    pids = {pid for _, pid in out}
    assert pids and os.getpid() not in pids  # (a fast worker may take every chunk)


def test_few_items_or_one_job_run_in_this_process():
    for items, jobs in ((range(5), 2), (range(50), 1)):
        out = process_map(_square_and_pid, items, jobs=jobs, min_items=10)
        assert {pid for _, pid in out} == {os.getpid()}
        assert [v for v, _ in out] == [x * x for x in items]
    assert process_map(_square_and_pid, [], jobs=2) == []
