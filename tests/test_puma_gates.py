"""The gates after training and the stop rule: a demonstration the network cannot follow is named,
``puma.train.strict=true`` refuses the model, and training stops when more iterations stop
helping."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tamedpuma.puma import evaluation, gates
from tamedpuma.puma.data import RawDemo, prepare
from tamedpuma.puma.settings import EvalConfig

ROOT = Path(__file__).resolve().parents[1]
GOAL = np.array([0.5, 0.0, 0.3])


def _path(start, bend, n=70):
    """Samples from ``start`` to GOAL with a lateral arc ``bend`` [m] (half way, along z)."""
    s = np.linspace(0.0, 1.0, n)
    ease = s * s * (3 - 2 * s)
    pos = np.asarray(start) + (GOAL - np.asarray(start)) * ease[:, None]
    pos[:, 2] += bend * 16 * s**2 * (1 - s) ** 2
    return pos


def _demos(bends):
    starts = [GOAL + [0.3, 0.0, 0.0], GOAL + [0.3, 0.0, 0.0], GOAL + [-0.25, 0.3, 0.0],
              GOAL + [0.0, -0.35, 0.1]]
    return {f"d{i}": _path(st, b) for i, (st, b) in enumerate(zip(starts, bends))}


def _write(folder: Path, demos: dict) -> Path:
    folder.mkdir()
    for name, pos in demos.items():
        t = np.arange(len(pos)) * 0.03
        np.savetxt(folder / f"{name}.csv", np.column_stack([t, pos]), delimiter=",",
                   header="t,x,y,z", comments="")
    return folder


def _prepared(demos: dict):
    raws = [RawDemo(p, None, np.full(len(p), 0.03), f"/x/{k}.csv") for k, p in demos.items()]
    return prepare(raws, 0.03, hold=0)


def test_spread_is_the_distance_to_the_nearest_other_demonstration():
    d = _prepared(_demos([0.0, 0.2, 0.0, 0.0]))
    spread, nearest = gates.nearest_demos(d)
    assert gates.demo_names(d) == ["d0.csv", "d1.csv", "d2.csv", "d3.csv"]
    assert list(nearest[:2]) == [1, 0] and np.array_equal(spread, gates.demo_spread(d))
    # d0 and d1 share their start and differ by the arc only: each is the other's nearest
    between = evaluation.dtw_per_point(d.trimmed(1)[0], d.trimmed(0)[0])
    assert spread[0] == pytest.approx(between, rel=0.1) and spread[0] < spread[2]
    assert np.all(spread > 0)


def _evaluation(dtws, converged=1.0, compat=1.0):
    return {"imitation": {"dtw": float(np.mean(dtws)), "dtw_per_demo": list(dtws)},
            "convergence": {"converged_fraction": converged, "starts": 1000,
                            "not_converged": round(1000 * (1 - converged)), "horizon_s": 40.0,
                            "final_pos_error_max": 0.2, "final_angle_error_max": 0.1},
            "compatibility": {"compatible_fraction": compat, "samples": 2000}}


def test_each_gate_fails_alone_and_names_its_demonstrations():
    cfg = EvalConfig()
    spread, names = np.array([0.05, 0.05, 0.2, 0.2]), ["a", "b", "c", "d"]
    assert gates.check(_evaluation([0.004, 0.006, 0.01, 0.02]), spread, names, cfg) == []
    worst = gates.check(_evaluation([0.004, 0.03, 0.01, 0.02]), spread, names, cfg)
    assert [f.gate for f in worst] == ["worst_demo"] and worst[0].demos == ("b",)
    assert "b (3.00 cm > 2.00 cm)" in worst[0].line and "\n" not in worst[0].line
    mean = gates.check(_evaluation([0.03, 0.03, 0.07, 0.07]), spread, names, cfg)
    assert "imitation" in [f.gate for f in mean]
    conv = gates.check(_evaluation([0.004] * 4, converged=0.99), spread, names, cfg)
    assert [f.gate for f in conv] == ["convergence"] and "10 of 1000" in conv[0].line
    psi = gates.check(_evaluation([0.004] * 4, compat=0.98), spread, names, cfg)
    assert [f.gate for f in psi] == ["compatibility"]
    off = EvalConfig(gate_spread=0, gate_worst=0, gate_converged=0, gate_compat=0)
    assert gates.check(_evaluation([1.0] * 4, 0.0, 0.0), spread, names, off) == []
    # a demonstration far from its goal may deviate by gate_extent of that distance
    far = gates.check(_evaluation([0.004, 0.03, 0.01, 0.02]), spread, names, cfg,
                      extent=np.full(4, 0.7))
    assert far == [] and 0.4 * 0.05 < 0.03 < cfg.gate_extent * 0.7
    # below the floor (gate_floor x pos_tol) a demonstration always passes
    assert gates.check(_evaluation([0.0049, 0.0, 0.0, 0.0]), np.zeros(4), names, cfg) == []


def test_a_rollout_on_another_demonstrations_route_is_the_datas_conflict_not_the_learners():
    d = _prepared(_demos([0.0, 0.2, 0.0, 0.0]))
    routes = [d.trimmed(i)[0] for i in range(4)]
    # from d0's start the rollout takes d1's route (they share the start); d2, d3 their own
    rollouts = [routes[1], routes[1] + 0.001, routes[2] + 0.003, routes[3]]
    follows = gates.followed_routes(rollouts, d)
    assert list(follows) == [0] and follows[0].other == 1
    assert follows[0].start_gap == pytest.approx(0.0, abs=1e-9)
    assert follows[0].to_other < 0.002 < follows[0].to_own
    assert follows[0].route_gap == pytest.approx(
        evaluation.dtw_per_point(routes[0], routes[1]), rel=0.05) and follows[0].route_gap > 0.05
    # d2 on d3's route: the two routes lie less than twice their start gap apart on average
    far = gates.followed_routes([routes[0], routes[1], routes[3], routes[3]], d)
    assert 2 not in far and 3 not in far
    spread, names = np.array([0.1, 0.1, 0.2, 0.05]), gates.demo_names(d)
    dtws = [0.05, 0.001, 0.003, 0.03]  # d0 (conflict) and d3 (not learnt) over their limits
    failures = {f.gate: f for f in gates.check(_evaluation(dtws), spread, names, EvalConfig(),
                                                follows=follows)}
    assert set(failures) == {"conflicting_demos", "worst_demo"}
    assert failures["conflicting_demos"].demos == ("d0.csv", "d1.csv")
    assert "d0.csv follows d1.csv (starts 0.00 cm apart, routes " in failures[
        "conflicting_demos"].line
    assert "mean DTW/point of the other 3: 1.13 cm" in failures["conflicting_demos"].line
    assert failures["worst_demo"].demos == ("d3.csv",)
    without = gates.check(_evaluation(dtws), spread, names, EvalConfig())
    assert [f.demos for f in without] == [("d0.csv", "d3.csv")]  # no rollouts: one line


def test_the_plateau_counts_validations_without_a_relative_improvement():
    p = evaluation._Plateau(patience=2, min_delta=0.1)
    assert [p.update(d) for d in (1.0, 0.8, 0.75, 0.74, 0.5, 0.49)] == [
        False, False, False, True, False, False]
    assert p.best == 0.49 and p.stale == 1
    assert not any(evaluation._Plateau(0, 0.1).update(1.0) for _ in range(5))


def test_a_smoothed_plateau_ignores_one_noisy_dip_and_still_finds_a_flat_run():
    trend = (2.0, 1.8, 1.2, 1.6, 1.5, 1.4, 1.3, 1.2)  # falling, with one dip at the third
    raw = evaluation._Plateau(patience=2, min_delta=0.03)
    assert [raw.update(d) for d in trend][4]  # the dip alone declares a plateau
    smoothed = evaluation._Plateau(patience=2, min_delta=0.03, smooth=3)
    assert not any(smoothed.update(d) for d in trend)
    # a rise then a real drop (the median alone would lag behind the drop: a plateau at 1.30)
    falling = evaluation._Plateau(patience=2, min_delta=0.03, smooth=3)
    assert not any(falling.update(d) for d in (1.575, 1.635, 1.301, 1.195, 1.131, 1.062))
    flat = evaluation._Plateau(patience=2, min_delta=0.03, smooth=3)
    assert [flat.update(d) for d in (2.0, 1.5, 1.0, 1.01, 0.99, 1.0, 1.02)][-2:] == [True, True]
    one = evaluation._Plateau(2, 0.03, 1)
    assert [one.update(d) for d in (1.0, 1.01, 0.99)] == [False, False, True]  # the raw count


def _train(folder: Path, out: Path, *extra):
    return subprocess.run(
        [sys.executable, "-m", "tamedpuma.train", "task=from_demos", f"task.demos={folder}",
         "task.workspace_check.action=off", "puma=tiny", "puma.orientation=false",
         "puma.train.iterations=300", "puma.train.window=10", "puma.eval.horizon=6",
         f"out_dir={out}", "progress=false", *extra],
        cwd=ROOT, capture_output=True, text=True, timeout=600)


def test_demonstrations_the_network_cannot_follow_are_named_and_strict_refuses(tmp_path):
    """d0 and d1 leave the same start on two routes (one straight, one over a 25 cm arc): no
    field follows both, so the one it misses is named with its neighbour; d2 and d3 are not."""
    folder = _write(tmp_path / "demos", _demos([0.0, 0.25, 0.0, 0.0]))
    proc = _train(folder, tmp_path / "out")
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    failures = {f["gate"]: f for f in report["gates"]["failures"]}
    named = {n for g in ("worst_demo", "conflicting_demos") for n in failures.get(g, {}).get(
        "demos", ())}
    assert not report["gates"]["passed"] and named and named <= {"d0.csv", "d1.csv"}
    warned = [ln for ln in proc.stderr.splitlines()
              if ln.startswith(("warning: gate worst_demo", "warning: gate conflicting_demos"))]
    assert warned and all("d0.csv" in ln and "d1.csv" in ln for ln in warned)  # the pair
    assert (tmp_path / "out" / "puma.pt").is_file()
    strict = _train(folder, tmp_path / "strict", "puma.train.strict=true")
    assert strict.returncode == 2 and "Traceback" not in strict.stderr
    last = strict.stderr.strip().splitlines()[-1]
    assert last.startswith("error: not saved (puma.train.strict=true)") and "worst_demo" not in last
    assert any(n in last for n in named)
    assert not (tmp_path / "strict" / "puma.pt").exists()
    assert not json.loads((tmp_path / "strict" / "report.json").read_text())["gates"]["passed"]


def test_a_model_that_failed_its_gates_is_named_where_it_is_loaded(tmp_path):
    from tamedpuma.app.models import gate_warnings
    from tamedpuma.puma.primitive import warn_failed_gates

    failures = gates.check(_evaluation([0.004, 0.03, 0.001, 0.001]), np.array([0.05] * 4),
                           ["a", "b", "c", "d"], EvalConfig())
    assert len(failures) == 1
    report = {"gates": gates.as_report(failures, np.array([0.05] * 4), EvalConfig())}
    (tmp_path / "report.json").write_text(json.dumps(report))
    said = []
    assert gate_warnings("tomato", tmp_path, said.append) == [failures[0].line]
    assert "tomato" in said[0] and said[1].endswith(failures[0].line)
    said.clear()
    assert warn_failed_gates(tmp_path / "puma.pt", report, said.append) == [failures[0].line]
    warn_failed_gates(tmp_path / "puma.pt", report, said.append)  # once per model file
    assert len(said) == 2 and "b (3.00 cm" in said[1]
    passed = {"gates": gates.as_report([], np.array([0.05] * 4), EvalConfig())}
    assert warn_failed_gates(tmp_path / "other.pt", passed, said.append) == [] and len(said) == 2


@pytest.mark.parametrize("bend, conflict", [(0.06, False), (0.2, True)])
def test_routes_conflict_only_when_they_part_by_more_than_twice_their_start_gap(bend, conflict):
    # starts 5 cm apart: routes 4.4 cm apart on average are the learner's to follow (a rollout
    # on the other's route is under-fitted, not contradicted); 11 cm apart, a smooth field
    # cannot take both
    d = _prepared({"a": _path(GOAL + [0.3, 0.0, 0.0], 0.0),
                   "b": _path(GOAL + [0.3, 0.05, 0.0], bend),
                   "c": _path(GOAL + [-0.25, 0.3, 0.0], 0.0)})
    routes = [d.trimmed(i)[0] for i in range(3)]
    follows = gates.followed_routes([routes[1], routes[1], routes[2]], d)
    assert (0 in follows) == conflict
    separation = evaluation.dtw_per_point(routes[0], routes[1])
    assert (separation > gates.CONFLICT_RATIO * 0.05) == conflict
