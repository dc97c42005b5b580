"""python -m tamedpuma.recheck: a slow step judged by running its run again."""

import json

import pytest
import yaml

from tamedpuma.app import step_recheck
from tamedpuma.app.step_recheck import SlowRun, judge
from tamedpuma.errors import TamedPumaError

FINAL = {"final_position_error_m": 0.001, "final_orientation_error_rad": 0.01,
         "min_clearance_m": 0.05}


def _summary(path, method="cpm", wall=(0.3, 0.3, 0.3), cpu=None, status="complete"):
    path.mkdir(parents=True, exist_ok=True)
    (path / "summary.json").write_text(json.dumps({
        "status": status, "method": method, "step_compute_ms": list(wall),
        "step_compute_cpu_ms": list(cpu or wall), **FINAL}))


def test_only_complete_runs_of_the_bounded_methods_with_a_step_over_the_bound_are_taken(tmp_path):
    _summary(tmp_path / "a", wall=(0.3, 16.9, 0.4), cpu=(0.3, 16.8, 0.4))
    _summary(tmp_path / "b", wall=(0.3, 9.9))
    _summary(tmp_path / "c", method="modulation_ik", wall=(32.0,))
    _summary(tmp_path / "d", status="failed", wall=(50.0,))
    runs = step_recheck.slow_runs(tmp_path)
    assert [(r.run_dir, r.slow) for r in runs] == [(str(tmp_path / "a"), ((1, 16.9, 16.8),))]
    assert runs[0].steps == 3 and runs[0].final == (0.001, 0.01, 0.05)
    every = step_recheck.slow_runs(tmp_path, methods=())
    assert sorted(r.method for r in every) == ["cpm", "modulation_ik"]


def _again(wall, cpu=None, **final):
    return {"step_compute_ms": list(wall), "step_compute_cpu_ms": list(cpu or wall),
            **FINAL, **final}


def test_a_step_is_the_machines_when_one_run_of_it_keeps_the_bound():
    run = SlowRun("r", "cpm", 3, (0.001, 0.01, 0.05), ((1, 16.9, 16.8), (2, 12.0, 11.9)))
    v = judge(run, [_again((0.3, 0.31, 14.0)), _again((0.3, 11.0, 13.0))], 10.0)
    assert [(x.step, x.least_wall_ms, x.least_cpu_ms, x.reproduced) for x in v] == [
        (1, 0.31, 0.31, False), (2, 12.0, 11.9, True)]


def test_a_rerun_of_another_length_or_final_state_is_not_comparable():
    run = SlowRun("r", "cpm", 3, (0.001, 0.01, 0.05), ((1, 16.9, 16.8),))
    (v,) = judge(run, [_again((0.3, 0.3))], 10.0)
    assert v.reproduced is None and "2 steps" in v.why
    (v,) = judge(run, [_again((0.3, 0.3, 0.3), min_clearance_m=0.0500001)], 10.0)
    assert v.reproduced is None and "another state" in v.why


def test_the_rerun_takes_the_runs_own_overrides_less_its_output(tmp_path):
    (tmp_path / ".hydra").mkdir()
    (tmp_path / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(
        ["method=cpm", "scenario.random_seed=2015", "+experiment=random",
         "output_root=/x", "hydra.launcher.n_jobs=1", "recorder=mcap"]))
    assert step_recheck.rerun_overrides(tmp_path) == [
        "method=cpm", "scenario.random_seed=2015", "+experiment=random"]
    with pytest.raises(TamedPumaError, match="cannot re-run"):
        step_recheck.rerun_overrides(tmp_path / "missing")


def test_a_step_made_slow_in_the_log_is_judged_the_machines_after_a_real_rerun(tmp_path):
    """One real episode, its summary given a 500 ms step: the run again (the same deterministic
    episode, step for step, with the same model) keeps a 100 ms bound at that step (a bound
    no scheduler slice on a busy test machine reaches)."""
    from tamedpuma.app.compose import compose
    from tamedpuma.app.sweep import run_one, write_summary

    overrides = ["method=fabrics", "+experiment=table1", "case=tomato_00",
                 "without_obstacles=true"]
    run_dir = tmp_path / "sweep" / "run"
    (run_dir / ".hydra").mkdir(parents=True)
    (run_dir / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
    summary = run_one(compose("sweep", [*overrides, "recorder=none"]), run_dir)
    summary["status"] = "complete"
    summary["step_compute_ms"][5] = 500.0
    summary["step_compute_cpu_ms"][5] = 499.0
    write_summary(run_dir, summary)  # as the sweep writes it: no obstacle, clearance null
    assert json.loads((run_dir / "summary.json").read_text())["min_clearance_m"] is None
    (v,) = step_recheck.recheck(tmp_path / "sweep", 100.0, 1, ("fabrics",))
    assert (v.step, v.wall_ms, v.reproduced) == (5, 500.0, False), v
    assert v.least_wall_ms < 100.0 and v.least_cpu_ms < 100.0


def test_a_folder_that_is_not_there_is_one_line_and_status_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        step_recheck.main([str(tmp_path / "nothing")])
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().startswith("error: ")
