"""A benchmark worker process: ``python -m tamedpuma.app.bench_worker timing|episode``.

The benchmark (:mod:`tamedpuma.app.bench_workers`) starts one per source tree it times (this
checkout, and with ``--baseline DIR`` another one, each with its own tree on ``PYTHONPATH``), so
that every side is measured by its own code under the same load. The protocol is JSON lines: the
first line read is the set-up, every later line a command answered by one line; ``{"cmd":
"quit"}`` ends it. The answers go to the original stdout; anything the project prints goes to
stderr.

``timing``: set-up ``{"method", "overrides", "seed"}`` (answers ``{"ok", "model"}``), then
``{"cmd": "reset", "n"}`` (obstacles of that count; answers the first call's time ``first_s``)
and ``{"cmd": "time", "calls", "warm"}`` (answers the timed calls ``s`` [s]).

``episode``: set-up ``{"method", "overrides", "recorders"}`` (recorder name -> overrides), then
``{"cmd": "run", "recorder", "physics"}``: one episode through the sweep's ``run_one``; answers
its wall times [s] (``wall_s`` the whole run, ``loop_s`` the episode with its simulator and
recorders as the summary records it), ``steps``, the simulated time ``sim_s``, the controller's
time ``controller_s`` and the recorders' own time ``own`` ({part: s}); with ``physics`` a second
line ``{"physics_s"}``: the simulator alone for as many steps, zero command, no state reads.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

#: the recorders' own time in the current run [s]: their open/write/close
OWN: dict[str, float] = {}


class Channel:
    """The JSON-lines reply channel: the original stdout, with stdout itself sent to stderr."""

    def __init__(self):
        self.reply = os.fdopen(os.dup(1), "w")
        os.dup2(2, 1)  # anything the project prints goes to stderr, not into the protocol

    def send(self, obj: dict) -> None:
        self.reply.write(json.dumps(obj) + "\n")
        self.reply.flush()


def commands(stream):
    """The commands read from ``stream`` until ``quit`` or its end."""
    for line in stream:
        cmd = json.loads(line)
        if cmd["cmd"] == "quit":
            return
        yield cmd


def timing(setup: dict, channel: Channel, stream) -> None:
    """The ``timing`` worker: resets and blocks of timed calls of one method."""
    from tamedpuma.app.bench_timing import first_call, prepare, timed_steps

    bench = prepare(setup["method"], setup["overrides"], setup.get("seed", 0))
    channel.send({"ok": True, "model": bench.model})
    observations, i = [], 0
    for cmd in commands(stream):
        if cmd["cmd"] == "reset":
            observations = bench.reset(cmd["n"])
            channel.send({"first_s": first_call(bench.controller, observations) / 1e3})
            i = 1
            continue
        timed_steps(bench.controller, observations, i, cmd["warm"])
        out = timed_steps(bench.controller, observations, i + cmd["warm"], cmd["calls"])
        i += cmd["warm"] + cmd["calls"]
        channel.send({"s": out})


def _count_own_time(owner, name: str, key: str) -> None:
    """Wrap the public method ``owner.name`` so that its time adds to ``OWN[key]``."""
    f = getattr(owner, name)

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return f(*args, **kwargs)
        finally:
            OWN[key] = OWN.get(key, 0.0) + time.perf_counter() - t0

    setattr(owner, name, timed)


def _count_recorders() -> None:
    from tamedpuma.recording.mcap_writer import McapRecorder
    from tamedpuma.recording.rerun_writer import RerunRecorder

    for cls, label in ((McapRecorder, "mcap"), (RerunRecorder, "rerun")):
        _count_own_time(cls, "write", f"{label}_write")
        _count_own_time(cls, "open", f"{label}_open_close")
        _count_own_time(cls, "close", f"{label}_open_close")


def physics_alone(config, steps: int) -> float:
    """The simulator alone [s]: ``steps`` steps of a zero command, no state reads."""
    import numpy as np

    from tamedpuma.app import sweep
    from tamedpuma.worlds.bullet import Simulator

    built = sweep.build(config)
    with Simulator(built.spec, built.sim_config, built.disturbance) as sim:
        sim.reset(built.scenario)
        zero = np.zeros(built.spec.dof)
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step(zero)
        return time.perf_counter() - t0


def one_episode(config, run_dir: Path) -> dict:
    """One episode through ``run_one``: the answer of a ``run`` command."""
    from tamedpuma.app import sweep

    OWN.clear()
    t0 = time.perf_counter()
    summary = sweep.run_one(config, run_dir)
    wall = time.perf_counter() - t0
    loop = (summary.get("wall_s") or {}).get("episode", wall)
    return {"wall_s": wall, "loop_s": loop, "steps": summary["steps"], "own": dict(OWN),
            "sim_s": summary["duration_s"],
            "controller_s": sum(summary.get("step_compute_ms") or [float("nan")]) / 1e3}


def episode(setup: dict, channel: Channel, stream) -> None:
    """The ``episode`` worker: whole episodes of one method, per recorder setting."""
    from tamedpuma.app.compose import compose

    _count_recorders()
    configs = {name: compose("sweep", [f"method={setup['method']}", *extra, *setup["overrides"]])
               for name, extra in setup["recorders"].items()}
    tmp = Path(tempfile.mkdtemp(prefix="bench_episode_"))
    channel.send({"ok": True})
    try:
        for i, cmd in enumerate(commands(stream)):
            run_dir = tmp / f"run{i}"
            run_dir.mkdir()
            answer = one_episode(configs[cmd["recorder"]], run_dir)
            shutil.rmtree(run_dir, ignore_errors=True)
            channel.send(answer)
            if cmd.get("physics"):
                channel.send({"physics_s": physics_alone(configs["none"], answer["steps"])})
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


KINDS = {"timing": timing, "episode": episode}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1 or argv[0] not in KINDS:
        print(f"usage: python -m tamedpuma.app.bench_worker {{{','.join(KINDS)}}}",
              file=sys.stderr)
        return 2
    channel = Channel()
    setup = json.loads(sys.stdin.readline())
    KINDS[argv[0]](setup, channel, sys.stdin)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
