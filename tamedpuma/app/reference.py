"""The reference motion that ``clutter.keep_clear=path`` keeps clutter clear of.

The reference is a run of ``clutter.reference`` (a method option, e.g. ``fpm``) on the same
scenario with only the scenario's own obstacles (no clutter), for ``clutter.reference_max_steps``
steps, the same seed and the same robot, task and simulator settings as the run being built. It
counts only if it *succeeds under the whole-body criterion* (reaches the goal; no body-sphere
penetration, no obstacle or ground contact; ``tamedpuma/metrics.py``): then its joint path is a
collision-free motion to the goal, and clutter kept clear of its swept volume
(:mod:`tamedpuma.worlds.clutter`) leaves the cluttered scene feasible. Otherwise the run fails
with a one-line :class:`~tamedpuma.errors.ScenarioError` naming the reference's failure class.

The reference is deterministic (the controller and PyBullet are), so every method and every
obstacle count of a case sees the same clutter for a seed; it is computed once per process and
configuration (a sweep's later runs reuse it).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable

import numpy as np
from omegaconf import DictConfig, OmegaConf

from tamedpuma.errors import ScenarioError

_CACHE: dict[str, np.ndarray] = {}


def _method_node(name: str) -> dict:
    """``conf/method/<name>.yaml`` composed with its defaults (interpolations unresolved); in a
    sweep's job, on the job's config search path."""
    from tamedpuma.app.compose import compose

    cfg = compose("sweep", [f"method={name}"])
    return OmegaConf.to_container(cfg.method, resolve=False)


def reference_config(cfg: DictConfig) -> DictConfig:
    """The reference run's config: ``cfg`` with ``method`` = ``clutter.reference``, no clutter,
    ``scenario.max_steps`` = ``clutter.reference_max_steps``, no recorder."""
    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    clutter = cfg.clutter
    ref = OmegaConf.create(OmegaConf.to_container(cfg, resolve=False))
    ref.method = _method_node(str(clutter.reference))
    ref.clutter.count, ref.clutter.total, ref.clutter.keep_clear = 0, None, "start_goal"
    ref.scenario.max_steps = int(clutter.reference_max_steps)
    ref.recorder.mcap = ref.recorder.rerun = False
    ref.without_obstacles = bool(cfg.without_obstacles)
    return ref


def reference_motion(cfg: DictConfig, build: Callable) -> np.ndarray:
    """The joint path (T, dof) [rad] of the reference run for ``cfg`` (see the module
    docstring); ``build``: the sweep's config -> ``Built`` function."""
    from tamedpuma.episode import RestTest, run_episode
    from tamedpuma.worlds.bullet import Simulator

    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    ref = reference_config(cfg)
    plain = OmegaConf.to_container(ref, resolve=True)
    key = hashlib.sha256(json.dumps(plain, sort_keys=True, default=str).encode()).hexdigest()
    if key in _CACHE:
        return _CACHE[key]
    built = build(ref)
    with Simulator(built.spec, built.sim_config, built.disturbance) as sim:
        result = run_episode(built.scenario, built.controller, sim,
                             stop_on_success=built.run.stop_on_success,
                             settle_time=built.run.settle_time,
                             rest=RestTest(built.run.rest_window, built.run.rest_distance,
                                           built.run.rest_angle))
    m = result.metrics
    if not m.success_whole_body:
        raise ScenarioError(
            f"clutter.keep_clear=path: the reference run ({cfg.clutter.reference} on "
            f"{built.scenario.name}, own obstacles only) did not succeed "
            f"[{m.failure_whole_body}], so there is no verified collision-free path to keep "
            f"clear; choose another clutter.reference or keep_clear=start_goal")
    path = np.array(result.q, dtype=float)
    path.setflags(write=False)
    _CACHE[key] = path
    return path
