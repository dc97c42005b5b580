"""Per-run metrics on synthetic logs: the paper and whole-body criteria, each failure cause, the
settle period of the orientation check, the stall class and the step-time statistics."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tamedpuma.analysis.summaries import step_stats
from tamedpuma.analysis.tables import table1
from tamedpuma.metrics import RestMonitor, at_rest, rest_step, run_metrics

DT = 0.02
TOL = 0.05  # the goal tolerance [m] of the synthetic runs
Q_MIN, Q_MAX = -np.ones(7), np.ones(7)


def _log(n=200, reach=100, **events):
    """A synthetic run: the position error falls linearly to 0 at step ``reach``; clear of
    everything unless ``events`` sets a flag array ({'clearance'|'contact'|'ground'|'q'|...})."""
    t = np.arange(n) * DT
    pos = np.clip(0.5 * (1 - np.arange(n) / reach), 0.0, None) if reach is not None \
        else np.full(n, 0.5)
    log = dict(t=t, position_error=pos, orientation_error=np.full(n, 0.1),
               clearance=np.full(n, 0.2), obstacle_contact=np.zeros(n, bool),
               ground_contact=np.zeros(n, bool), q=np.zeros((n, 7)), q_min=Q_MIN, q_max=Q_MAX,
               compute_ms=np.full(n, 1.0), tolerance=TOL)
    log.update(events)
    return log


def _with(name, steps, value, n=200):
    base = _log(n)[name].copy()
    base[steps] = value
    return base


def test_a_clean_run_passes_both_criteria():
    m = run_metrics(**_log())
    assert m.success_paper and m.success_whole_body and m.success
    assert m.failure_paper == m.failure_whole_body == ""
    # reach (error ≤ 0.05 m) first at step 90
    assert m.time_to_success_s == pytest.approx(90 * DT)


@pytest.mark.parametrize("field, value, cause", [
    ("obstacle_contact", True, "obstacle_contact"),
    ("ground_contact", True, "ground_contact"),
])
def test_a_contact_alone_fails_only_the_whole_body_criterion(field, value, cause):
    """A run that only touches a mesh (or the ground): every body sphere clear."""
    m = run_metrics(**_log(**{field: _with(field, slice(40, 45), value)}))
    assert m.success_paper and not m.success_whole_body
    assert m.failure_whole_body == cause and m.failure_paper == ""
    assert m.min_clearance_m > 0


def test_a_joint_limit_violation_fails_only_the_whole_body_criterion():
    q = np.zeros((200, 7))
    q[50:53, 3] = 1.01
    m = run_metrics(**_log(q=q))
    assert m.success_paper and not m.success_whole_body
    assert m.failure_whole_body == "joint_limit" and m.joint_limit_violation_steps == 3


def test_a_sphere_penetration_fails_both_criteria():
    m = run_metrics(**_log(clearance=_with("clearance", slice(30, 35), -0.01)))
    assert not m.success_paper and not m.success_whole_body
    assert m.failure_paper == m.failure_whole_body == "sphere_penetration"


def test_the_first_cause_in_time_is_reported():
    m = run_metrics(**_log(ground_contact=_with("ground_contact", 20, True),
                           clearance=_with("clearance", 60, -0.01)))
    assert m.failure_whole_body == "ground_contact" and m.failure_paper == "sphere_penetration"


def test_events_after_the_reach_do_not_count_for_the_position_success():
    m = run_metrics(**_log(obstacle_contact=_with("obstacle_contact", 150, True),
                           clearance=_with("clearance", 150, -0.01)))
    assert m.success_paper and m.success_whole_body and m.collided


def test_a_reach_after_the_time_limit_fails_as_late():
    m = run_metrics(**_log(), time_limit=90 * DT)
    assert not m.success_paper and m.failure_paper == m.failure_whole_body == "late"
    assert run_metrics(**_log(), time_limit=90 * DT + DT).success_paper


def test_never_reached_is_a_stall_when_the_arm_stopped_and_time_when_it_moved():
    n = 300
    still = np.tile([0.3, 0.0, 0.4], (n, 1))
    moving = still + np.linspace(0, 1, n)[:, None] * [0.5, 0.0, 0.0]
    stalled = run_metrics(**_log(n=n, reach=None), ee_position=still)
    assert stalled.failure_paper == stalled.failure_whole_body == "stall"
    timed = run_metrics(**_log(n=n, reach=None), ee_position=moving)
    assert timed.failure_whole_body == "time"
    assert np.isnan(timed.time_to_success_s)


def test_orientation_is_judged_after_the_settle_time():
    """The orientation converges 1 s after the position reach: success with orientation with a
    2 s settle time, not without one (judged at the reach)."""
    rot = np.full(300, 0.5)
    rot[140:] = 0.05  # reach at step 90, orientation within 0.2 rad from step 140 (1 s later)
    log = _log(n=300, orientation_error=rot)
    settled = run_metrics(**log, settle_time=2.0)
    assert settled.orientation_success_paper and settled.orientation_success_whole_body
    assert settled.settled_orientation_error_rad == pytest.approx(0.05)
    at_reach = run_metrics(**log, settle_time=0.0)
    assert at_reach.success_paper and not at_reach.orientation_success_paper


def test_orientation_fails_if_the_log_ends_before_the_settle_time_or_the_position_drifts():
    short = run_metrics(**_log(n=120), settle_time=2.0)  # reach at 90, log ends 0.6 s later
    assert short.success_paper and not short.orientation_success_paper
    pos = _log(n=300)["position_error"].copy()
    pos[150:] = 0.2  # left the goal again during the settle period
    drift = run_metrics(**_log(n=300, position_error=pos), settle_time=2.0)
    assert drift.success_paper and not drift.orientation_success_paper


def test_a_contact_during_the_settle_period_fails_only_the_whole_body_orientation_success():
    log = _log(n=300, obstacle_contact=_with("obstacle_contact", 150, True, n=300))
    m = run_metrics(**log, settle_time=2.0)
    assert m.success_whole_body and m.orientation_success_paper
    assert not m.orientation_success_whole_body


def test_recovery_time_counts_from_the_disturbance_onset():
    m = run_metrics(**_log(), disturbance_time=1.0)
    assert m.recovery_time_s == pytest.approx(90 * DT - 1.0)
    assert np.isnan(run_metrics(**_log(n=200, reach=None), disturbance_time=1.0).recovery_time_s)


def test_step_time_statistics_cover_every_step_and_show_the_warm_up():
    a = np.array([50.0, 1.0, 1.0, 1.0])
    b = np.array([30.0, 2.0, 2.0, 2.0, 2.0, 2.0])
    st = step_stats([a, b])
    every = np.concatenate([a, b])
    assert st["steps"] == 10 and st["mean_ms"] == pytest.approx(every.mean())
    assert st["std_ms"] == pytest.approx(every.std()) and st["median_ms"] == pytest.approx(2.0)
    assert st["first_mean_ms"] == pytest.approx(40.0)
    assert st["first_max_ms"] == pytest.approx(50.0)


def test_table_rows_are_keyed_by_method_label_with_both_criteria():
    rows = []
    for label, contact in (("cpm", False), ("cpm_literal", True)):
        m = run_metrics(**_log(obstacle_contact=_with("obstacle_contact", 10, contact)))
        rows.append({"path": label, "method": "cpm", "method_label": label, "task": "tomato",
                     "scenario": "s", "n_obstacles": 2, "path_difference_m": np.nan,
                     **m.as_dict()})
    table = table1(pd.DataFrame(rows), {r["path"]: np.ones(5) for r in rows}).set_index("method")
    assert list(table.index) == ["cpm", "cpm_literal"]
    assert table.loc["cpm_literal", "success (paper)"] == "1.00"
    assert table.loc["cpm_literal", "success (whole body)"] == "0.00"
    assert table.loc["cpm_literal", "whole-body failures"] == "obstacle_contact 1"
    assert table.loc["cpm", "success (whole body)"] == "1.00"


def test_with_a_disturbance_only_a_reach_after_its_onset_counts():
    pos = np.full(300, 0.01)  # at the goal from the start ...
    pos[100:150] = 0.3       # ... pushed away at step 100, back at step 150
    m = run_metrics(**_log(n=300, position_error=pos), disturbance_time=100 * DT)
    assert m.success_paper and m.time_to_success_s == pytest.approx(150 * DT)
    assert m.recovery_time_s == pytest.approx(50 * DT)
    never_back = pos.copy()
    never_back[150:] = 0.3
    assert not run_metrics(**_log(n=300, position_error=never_back),
                           disturbance_time=100 * DT).success_paper


def test_the_rest_step_is_the_first_step_at_rest_inside_after_the_reach():
    """rest_step tests the steps one by one up to the first at rest: the first True of
    at_rest & inside at or after the reach, with and without the rotation vector."""
    rng = np.random.default_rng(5)
    t = np.arange(400) * 0.02
    e = np.cumsum(rng.normal(size=(400, 3)) * np.exp(-t / 1.0)[:, None] * 0.01, axis=0)
    r = np.cumsum(rng.normal(size=(400, 3)) * np.exp(-t / 1.5)[:, None] * 0.01, axis=0)
    found = set()
    for inside in (rng.uniform(size=400) < 0.7, np.ones(400, bool), np.zeros(400, bool)):
        for reach in (None, 0, 60, 250, 399, 400):
            for rot, angle in ((None, np.inf), (r, 0.02)):
                got = rest_step(t, e, inside, reach, 1.0, 0.005, rot, angle)
                if reach is None:
                    assert got is None
                    continue
                rest = at_rest(t, e, 1.0, 0.005, rot, angle) & inside
                rest[:reach] = False
                assert got == (int(np.argmax(rest)) if rest.any() else None)
                found.add(got)
    assert len(found) > 3  # steps found at several places, and none


def test_the_online_rest_monitor_agrees_with_the_offline_rest_test():
    rng = np.random.default_rng(3)
    t = np.arange(300) * 0.02
    # a random walk that slows down: moving at first, at rest by the end
    steps = rng.normal(size=(300, 3)) * np.exp(-t / 1.0)[:, None] * 0.01
    e = np.cumsum(steps, axis=0)
    offline = at_rest(t, e, 1.0, 0.005)
    monitor = RestMonitor(1.0, 0.005)
    online = np.array([monitor.update(ti, ei) for ti, ei in zip(t, e)])
    np.testing.assert_array_equal(online, offline)
    assert offline[-1] and not offline[:49].any()  # needs a whole window; rests at the end


def _converging(n=400, **kw):
    """A hand approaching the goal exponentially from 0.5 m (error vector along x)."""
    args = _log(n)
    err = 0.5 * np.exp(-args["t"] / 0.8)
    args.update(position_error=err, error_vector=np.stack([err, 0 * err, 0 * err], axis=1))
    args.update(kw)
    return run_metrics(**args)


def test_a_collision_between_the_reach_and_the_rest_fails_converged_not_reached():
    n = 400
    contact = np.zeros(n, bool)
    contact[150] = True  # the reach is at 1.84 s (step 93), the rest at 4.4 s (step 221)
    m = _converging(n, ground_contact=contact)
    assert m.success_whole_body and not m.converged_whole_body and m.converged_paper
    assert m.time_to_success_s < 3.0 < m.rest_time_s


def test_a_goal_moving_with_the_hand_converges_on_the_error_vector():
    n = 400
    t = np.arange(n) * 0.02
    goal = np.stack([0.01 * t, np.zeros(n), np.zeros(n)], axis=1)  # 1 cm/s
    e = np.stack([np.zeros(n), 0.5 * np.exp(-t / 0.8), np.zeros(n)], axis=1)  # across it
    hand = goal + e
    moving = run_metrics(**dict(_log(n), position_error=e[:, 1], ee_position=hand,
                                error_vector=e))
    by_hand = run_metrics(**dict(_log(n), position_error=e[:, 1], ee_position=hand))
    assert moving.converged_paper and not by_hand.converged_paper


def test_a_rest_outside_the_time_limit_or_off_orientation_is_not_converged():
    late = _converging(time_limit=3.0)
    assert late.success_paper and not late.converged_paper
    n = 400
    off = _converging(n, orientation_error=np.full(n, 0.5))
    assert off.converged_paper and not off.orientation_converged_paper


def test_a_hand_still_turning_is_not_at_rest_in_its_pose():
    """The position rests at 4.4 s while the orientation error falls from 0.6 rad to 0.1 rad
    (time constant 4 s; 0.27 rad then, above the 0.2 rad tolerance): converged is judged at the
    position's rest; converged with orientation at the pose's rest (7.8 s, 0.17 rad), once the
    turning has slowed below rest_angle per window.
    Judged at the position's rest (without the rotation vector, as older logs are), the
    orientation would have failed."""
    n = 700
    t = np.arange(n) * DT
    angle = 0.1 + 0.5 * np.exp(-t / 4.0)
    rotation = np.stack([angle, 0 * angle, 0 * angle], axis=1)
    kw = dict(orientation_error=angle, rest_angle=0.02)
    turning = _converging(n, rotation_vector=rotation, **kw)
    position_only = _converging(n, **kw)
    assert turning.converged_paper and position_only.converged_paper
    assert turning.rest_time_s == position_only.rest_time_s
    assert turning.orientation_converged_paper and not position_only.orientation_converged_paper
    # the pose's rest step: the angle moves 0.5 e^(−(t−1)/4)(1 − e^(−1/4)) over the last 1 s,
    # below 0.02 rad from t = 1 + 4 ln 5.5 = 7.8 s
    offline = at_rest(t, np.zeros((n, 3)), 1.0, 0.005, rotation, 0.02)
    assert t[np.argmax(offline)] == pytest.approx(1.0 + 4.0 * np.log(5.5), abs=0.1)


def test_the_online_rest_monitor_agrees_with_the_offline_test_with_rotations():
    rng = np.random.default_rng(4)
    t = np.arange(400) * 0.02
    decay = np.exp(-t / 1.5)[:, None]
    e = np.cumsum(rng.normal(size=(400, 3)) * np.exp(-t / 0.7)[:, None] * 0.01, axis=0)
    r = np.cumsum(rng.normal(size=(400, 3)) * decay * 0.02, axis=0)
    offline = at_rest(t, e, 1.0, 0.005, r, 0.02)
    monitor = RestMonitor(1.0, 0.005, 0.02)
    online = np.array([monitor.update(ti, ei, ri) for ti, ei, ri in zip(t, e, r)])
    np.testing.assert_array_equal(online, offline)
    position_only = at_rest(t, e, 1.0, 0.005)
    assert offline[-1] and (position_only & ~offline).any()  # the turning rests later
    assert not (offline & ~position_only).any()
