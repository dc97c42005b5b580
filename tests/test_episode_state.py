"""A controller's per-episode state is explicit: everything its ``reset`` and ``step`` write
lives in its ``episode`` attribute (made by ``reset``; a controller inside another, FPM's and
CPM's PumaController, has its own). So a step is a function of (episode state, observation): from
the same (copied) state and observation it gives the same command and the same next state to
the bit, and no other attribute of the controller changes during a step (docs/extending.md,
"Episode state")."""

from __future__ import annotations

import copy
import dataclasses
import functools
import types

import numpy as np
import pytest
from omegaconf import OmegaConf

from tamedpuma.app.bench_timing import observation

METHODS = ["puma", "fabrics", "fpm", "cpm", "fpm_literal", "cpm_literal", "cpm_original",
           "modulation_ik", "joint_attractor"]
#: tomato, random seed 2002, a start anywhere: the hand meets the obstacles on its way
SCENARIO = ["task=tomato", "scenario=random", "scenario.random_seed=2002",
            "scenario.start_kind=anywhere", "recorder=none"]
STEPS = 120  # control steps rolled before and between the checks (2.4 s)


@functools.cache
def _built(method: str):
    from tamedpuma.app.compose import compose_dict
    from tamedpuma.app.sweep import build

    return build(OmegaConf.create(compose_dict("sweep", [*SCENARIO, f"method={method}"])))


def _shared(obj) -> bool:
    """Objects a controller borrows and the walk below does not enter: the robot model
    (pinocchio's buffers), torch modules (PUMA's network), compiled kernels (numba's) and
    modules."""
    import torch

    from tamedpuma.robot.kinematics import Kinematics

    return (isinstance(obj, (Kinematics, torch.nn.Module)) or type(obj).__name__ == "module"
            or type(obj).__module__.startswith("numba."))


def _fingerprint(obj, seen=None):
    """A comparable copy of ``obj``'s data, every ``episode`` attribute left out: numbers,
    arrays and containers by value, objects by their attributes (cycles cut)."""
    seen = {} if seen is None else seen  # id -> the order it was first met in
    if isinstance(obj, (float, np.floating)):
        return ("float", repr(float(obj)))  # NaN equals NaN here
    if isinstance(obj, (int, str, bytes, bool, type(None), complex, np.generic)):
        return obj
    if isinstance(obj, np.ndarray):
        return ("array", obj.dtype.str, obj.shape, obj.tobytes())
    if isinstance(obj, (type, types.FunctionType, types.MethodType, types.BuiltinFunctionType,
                        functools.partial)) or _shared(obj):
        return ("ref", type(obj).__qualname__, getattr(obj, "__qualname__", ""))
    if id(obj) in seen:
        return ("seen", seen[id(obj)])
    seen[id(obj)] = len(seen)
    if isinstance(obj, (list, tuple)):
        return [type(obj).__name__, *(_fingerprint(v, seen) for v in obj)]
    if isinstance(obj, dict):
        return {k: _fingerprint(v, seen) for k, v in obj.items()}
    if isinstance(obj, (set, frozenset)):
        return sorted(repr(v) for v in obj)
    attrs = dict(getattr(obj, "__dict__", {}))
    for name in getattr(type(obj), "__slots__", ()):
        if hasattr(obj, name):
            attrs[name] = getattr(obj, name)
    kind = type(obj).__qualname__
    return (kind, {k: _fingerprint(v, seen) for k, v in attrs.items() if k != "episode"})


def _holders(controller) -> list:
    """The controller and the controllers inside it that keep an ``episode`` (a controller
    whose step writes nothing, the joint attractor, has none)."""
    inner = [v for v in vars(controller).values() if hasattr(v, "episode") and not _shared(v)]
    return [controller, *inner] if hasattr(controller, "episode") else inner


def _reachable(obj, found: dict) -> None:
    """Every object reachable from ``obj`` through attributes and containers, ``episode``
    attributes left out, into ``found`` (id -> object)."""
    if id(obj) in found or isinstance(obj, (int, float, str, bytes, bool, type(None))):
        return
    found[id(obj)] = obj
    if isinstance(obj, (np.ndarray, type, types.FunctionType, types.MethodType)) or _shared(obj):
        return
    if isinstance(obj, (list, tuple, set, frozenset)):
        children = list(obj)
    elif isinstance(obj, dict):
        children = list(obj.values())
    else:
        children = [v for k, v in getattr(obj, "__dict__", {}).items() if k != "episode"]
    for child in children:
        _reachable(child, found)


def _borrowed(controller) -> dict:
    """A deepcopy memo that shares everything reachable outside the episodes (the network,
    the robot model, the settings, the fabric: what an episode borrows, never its own)."""
    found: dict = {}
    _reachable(controller, found)
    return dict(found)


def _state(controller) -> list:
    return copy.deepcopy([h.episode for h in _holders(controller)], _borrowed(controller))


def _restore(controller, state: list) -> None:
    for holder, episode in zip(_holders(controller), copy.deepcopy(state,
                                                                     _borrowed(controller))):
        holder.episode = episode


def _roll(controller, scenario, steps: int, start=None):
    """``steps`` control steps of the joints integrated by Euler (q̇ += q̈Δt within the speed
    limits, q += q̇Δt): no simulator, the controller alone. Returns the next (q, q̇, k)."""
    dt, qd_max = scenario.dt, _built("fpm").spec.qd_max
    q, qd, k0 = start or (scenario.q0.copy(), np.zeros_like(scenario.q0), 0)
    for k in range(k0, k0 + steps):
        cmd = controller.step(_obs(scenario, q, qd, k))
        qd = np.clip(qd + cmd.qdd * dt, -qd_max, qd_max)
        q = q + qd * dt
    return q, qd, k0 + steps


def _obs(scenario, q, qd, k):
    t = k * scenario.dt
    obs = observation(scenario, q.copy(), qd.copy(), scenario.obstacles, t=t, step=k)
    return dataclasses.replace(obs, obstacle_centers=scenario.obstacles.at(t))


def _untimed(scalars: dict) -> dict:
    """The log scalars but the solvers' own timings (``*_ms``: wall time)."""
    return {k: v for k, v in scalars.items() if not k.endswith("_ms")}


def _same(a, b) -> bool:
    return _fingerprint(a) == _fingerprint(b)


@pytest.mark.parametrize("method", METHODS)
def test_a_step_is_a_function_of_the_episode_state_and_the_observation(method):
    built = _built(method)
    controller, scenario = built.controller, built.scenario
    controller.reset(scenario)
    at = None
    for _ in range(3):  # after 2.4, 4.8 and 7.2 s
        at = _roll(controller, scenario, STEPS, at)
        obs = _obs(scenario, *at)
        before = _state(controller)
        first = controller.step(obs)
        after_first = _state(controller)
        _restore(controller, before)
        second = controller.step(obs)
        assert np.array_equal(first.qdd, second.qdd, equal_nan=True)
        assert _same(_untimed(first.scalars), _untimed(second.scalars))
        assert _same(after_first, _state(controller))


@pytest.mark.parametrize("method", METHODS)
def test_a_step_writes_nothing_outside_the_episode_state(method):
    built = _built(method)
    controller, scenario = built.controller, built.scenario
    controller.reset(scenario)
    at = _roll(controller, scenario, 1)  # the first step's own work done
    kept = _fingerprint(controller)
    at = _roll(controller, scenario, STEPS, at)
    assert _fingerprint(controller) == kept


@pytest.mark.parametrize("method", METHODS)
def test_a_reset_writes_nothing_outside_the_episode_state(method):
    """Δt, the goal's IK solution and every other per-episode value live in the episode: a
    reset for another scenario (another Δt and start) leaves the rest as it was."""
    built = _built(method)
    controller, scenario = built.controller, built.scenario
    controller.reset(scenario)
    kept = _fingerprint(controller)
    other = dataclasses.replace(scenario, dt=scenario.dt / 2, q0=scenario.q0 + 0.05)
    try:
        controller.reset(other)
        assert _fingerprint(controller) == kept
    finally:
        controller.reset(scenario)


def test_the_fingerprint_sees_a_change_outside_the_episode():
    class Holder:
        def __init__(self):
            self.gain, self.buffer, self.episode = 1.0, np.zeros(2), {"n": 0}

    h = Holder()
    kept = _fingerprint(h)
    h.episode["n"] = 1
    assert _fingerprint(h) == kept
    h.buffer[0] = 1.0
    assert _fingerprint(h) != kept
