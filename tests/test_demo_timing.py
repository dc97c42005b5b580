"""The demonstrations' orientation timing: arrival in the goal ball, the orientation's lag after
it, and the demonstration's own verdict under the with-orientation criterion."""

from __future__ import annotations

import numpy as np
import pytest

from tamedpuma.analysis import demo_timing
from tamedpuma.puma import data
from tamedpuma.robot import rotations


def _demo(arrive: float, turned: float, total: float = 8.0, dt: float = 0.01) -> data.RawDemo:
    """A straight 0.5 m approach reaching the 5 cm ball at ``arrive`` [s] (linear in time), and
    a turn about z from 1 rad to 0, linear, ending at ``turned`` [s]."""
    t = np.arange(0.0, total + 1e-9, dt)
    speed = 0.45 / arrive  # 0.5 m out at t = 0, 0.05 m at ``arrive``
    dist = np.clip(0.5 - speed * t, 0.0, None)
    pos = np.stack([dist, np.zeros_like(t), 0.3 + np.zeros_like(t)], axis=1)
    angle = np.clip(1.0 - t / turned, 0.0, None)
    quat = np.stack([np.zeros_like(t), np.zeros_like(t), np.sin(angle / 2), np.cos(angle / 2)],
                    axis=1)
    return data.RawDemo(pos=pos, quat=rotations.continuous_quats(quat),
                        delta_t=np.full(len(t), dt), source="synthetic")


def test_a_turn_after_the_arrival_is_its_lag():
    demos = data.prepare([_demo(arrive=2.0, turned=6.0), _demo(arrive=3.0, turned=1.0)], 0.03)
    timing = demo_timing.orientation_timing(demos)
    assert timing.arrival_s == pytest.approx([2.0, 3.0], abs=0.04)
    # the angle falls below 0.2 rad at 0.8 of the turn
    assert timing.lag_s == pytest.approx([0.8 * 6.0 - 2.0, 0.0], abs=0.04)
    assert timing.held_after_settle.tolist() == [False, True]
    assert demo_timing.orientation_timing(demos, settle=3.0).held_after_settle.tolist() == [
        True, True]


def test_without_orientations_there_is_no_timing():
    raw = _demo(2.0, 1.0)
    demos = data.prepare([data.RawDemo(raw.pos, None, raw.delta_t, raw.source)], 0.03)
    assert demo_timing.orientation_timing(demos) is None


def test_the_cli_names_a_missing_folder(tmp_path, capsys):
    assert demo_timing.main([str(tmp_path / "nothing")]) == 2
    out = capsys.readouterr().out
    assert out.startswith("error:") and out.count("\n") == 1


def test_the_table_prepares_the_demonstrations_as_the_learner_does():
    """The CLI's model step and smoothing are the default training's (conf/puma/default.yaml)."""
    import inspect

    from tamedpuma.app.config import load_group

    puma = load_group("puma", "default")
    defaults = inspect.signature(demo_timing.timing_rows).parameters
    assert defaults["dt"].default == puma["dt"]
    assert defaults["smoothing"].default == puma["smoothing"]
