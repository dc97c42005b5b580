"""The data's own first-order field (:mod:`tamedpuma.puma.data_field`): it follows
demonstrations that keep apart, misses demonstrations that cross with other velocities, and a
first-order model's gate names those as the data's cause."""

import numpy as np
import pytest

from tamedpuma.puma import data_field, gates
from tamedpuma.puma.data import RawDemo, prepare
from tamedpuma.puma.settings import EvalConfig

GOAL = np.array([0.5, 0.0, 0.3])
H = 0.005  # [m] the gates' bandwidth with the default settings (0.5 x 1 cm)


def _along(points, n=90):
    """Samples along the polyline ``points`` (goal-relative [m], ending at 0) at a smooth speed
    (zero at both ends), in world coordinates."""
    points = np.asarray(points, float)
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.linspace(0.0, 1.0, n)
    where = arc[-1] * s * s * (3 - 2 * s)
    path = np.column_stack([np.interp(where, arc, points[:, k]) for k in range(3)])
    return GOAL + path


def _prepared(paths):
    raws = [RawDemo(p, None, np.full(len(p), 0.03), f"/x/d{i}.csv") for i, p in enumerate(paths)]
    return prepare(raws, 0.03, smoothing=2.0, hold=10, use_orientation=False)


#: two routes to the goal; the second crosses the first at (0.15, 0, 0) heading -y
STRAIGHT = [[0.3, 0.0, 0.0], [0.0, 0.0, 0.0]]
CROSSING = [[0.15, 0.15, 0.0], [0.15, -0.1, 0.0], [0.0, 0.0, 0.0]]
APART = [[0.15, 0.15, 0.1], [0.15, -0.1, 0.1], [0.0, 0.0, 0.0]]  # the same, 10 cm above


def _raised(points, dz=0.01):
    """The route ``points`` with every point but the goal ``dz`` [m] higher: a neighbour."""
    return [[x, y, z + dz] for x, y, z in points[:-1]] + [points[-1]]


def test_the_field_follows_demonstrations_that_keep_apart():
    demos = _prepared([_along(STRAIGHT), _along(APART)])
    dtw = data_field.first_order_dtw(demos, H)
    assert np.all(dtw < H), dtw


def test_the_field_misses_demonstrations_that_cross_with_other_velocities():
    """At the crossing the field averages the two velocities: its rollouts leave the routes by
    centimetres, where the same routes kept apart are followed to a fraction of h."""
    apart = data_field.first_order_dtw(_prepared([_along(STRAIGHT), _along(APART)]), H)
    crossing = data_field.first_order_dtw(_prepared([_along(STRAIGHT), _along(CROSSING)]), H)
    assert crossing.min() > 2 * H and crossing.min() > 5 * apart.max(), (crossing, apart)


def test_rollouts_start_on_the_demonstrations_and_keep_their_length():
    demos = _prepared([_along(STRAIGHT), _along(CROSSING, n=120)])
    paths = data_field.rollouts(demos, H)
    for i, path in enumerate(paths):
        ref = demos.trimmed(i)[0]
        assert path.shape == ref.shape and np.array_equal(path[0], ref[0])
    with pytest.raises(ValueError, match="bandwidth"):
        data_field.rollouts(demos, 0.0)


def _evaluation(dtw_per_demo):
    return {"imitation": {"dtw": float(np.mean(dtw_per_demo)), "dtw_per_demo": dtw_per_demo},
            "convergence": {"converged_fraction": 1.0},
            "compatibility": {"compatible_fraction": 1.0}}


def test_a_first_order_model_missing_what_no_first_order_field_follows_is_told_so():
    """The crossing demonstration that the model misses and the data's field misses too gets
    the ``first_order_data`` line (train order 2); without the field (a second-order model)
    it stays the learner's ``worst_demo``. (A neighbour 1 cm from it sets its gate's limit to
    about 1 cm, below what the field reaches at the crossing.)"""
    demos = _prepared([_along(STRAIGHT), _along(CROSSING), _along(_raised(CROSSING))])
    cfg = EvalConfig()
    spread, nearest = gates.nearest_demos(demos)
    field = data_field.first_order_dtw(demos, gates.field_bandwidth(cfg))
    names = gates.demo_names(demos)
    ev = _evaluation([0.001, 0.06, 0.001])
    first = {f.gate: f for f in gates.check(ev, spread, names, cfg, "m", nearest,
                                            gates.demo_extent(demos), None, field)}
    second = {f.gate: f for f in gates.check(ev, spread, names, cfg, "m", nearest,
                                             gates.demo_extent(demos), None, None)}
    assert "first_order_data" in first and "worst_demo" not in first
    assert "d1.csv" in first["first_order_data"].demos
    assert "puma.order=2" in first["first_order_data"].line
    assert "worst_demo" in second and "first_order_data" not in second


def test_a_first_order_model_missing_what_the_field_follows_is_the_learners():
    demos = _prepared([_along(STRAIGHT), _along(APART), _along(_raised(APART))])
    cfg = EvalConfig()
    spread, nearest = gates.nearest_demos(demos)
    field = data_field.first_order_dtw(demos, gates.field_bandwidth(cfg))
    failures = {f.gate for f in gates.check(_evaluation([0.001, 0.06, 0.001]), spread,
                                            gates.demo_names(demos), cfg, "m", nearest,
                                            gates.demo_extent(demos), None, field)}
    assert "worst_demo" in failures and "first_order_data" not in failures


def test_the_learner_table_shows_the_datas_first_order_field_beside_first_order_models():
    from tamedpuma.puma import learner_table

    row = {"set": "pouring_v2", "order": 2, "seed": 0, "n_demos": 38, "unit": "m", "dtw": 0.018,
           "dtw_worst": 0.04, "frechet": 0.04, "converged": 1.0, "compatible": 0.998,
           "iterations": 2100, "train_s": 116.0, "wall_s": 123.0, "cpu_s": 122.0,
           "gates_failed": []}
    first = {**row, "order": 1, "dtw": 0.033, "field_dtw": 0.0153, "field_dtw_worst": 0.0495}
    assert "first-order field" not in learner_table.markdown([row])
    lines = learner_table.markdown([row, first]).splitlines()
    assert lines[0].endswith("| first-order field of the data (mean / worst) |")
    assert lines[1].count("---|") == 15
    assert lines[2].endswith("| none | — |") and lines[3].endswith("| none | 1.53 / 4.95 cm |")
