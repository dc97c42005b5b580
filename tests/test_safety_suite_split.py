"""The safety suite (:mod:`tamedpuma.app.safety_suite`): its classification, the split of success
by PUMA's own joint-limit need, and one short run through its command."""

import numpy as np
import pandas as pd
import pytest

from tamedpuma.analysis.safety import Trace, classify, split_by_puma_limits
from tamedpuma.app import safety_suite


def _runs():
    return pd.DataFrame({
        "task": ["tomato"] * 4, "kind": ["anywhere"] * 4, "seed": [1, 2, 3, 4],
        "label": ["fpm"] * 4, "success_paper": [True, True, False, True],
        "success_whole_body": [True, False, False, True]})


def test_success_is_split_by_whether_puma_alone_passed_a_limit():
    puma = pd.DataFrame({"task": ["tomato"] * 4, "kind": ["anywhere"] * 4, "seed": [1, 2, 3, 4],
                         "method": ["puma"] * 4, "limit_steps": [0, 0, 12, 3]})
    split = split_by_puma_limits(_runs(), puma)
    row = split.loc[("tomato", "anywhere", "fpm")]
    assert row[("n", False)] == 2 and row[("n", True)] == 2
    assert row[("paper", False)] == 1.0 and row[("paper", True)] == 0.5
    assert row[("whole_body", False)] == 0.5 and row[("whole_body", True)] == 0.5


def test_other_methods_rows_and_other_scenarios_are_ignored():
    puma = pd.DataFrame({"task": ["tomato"] * 3, "kind": ["anywhere"] * 3, "seed": [1, 1, 9],
                         "method": ["puma", "cpm", "puma"], "limit_steps": [5, 0, 0]})
    split = split_by_puma_limits(_runs(), puma)
    row = split.loc[("tomato", "anywhere", "fpm")]
    assert row[("n", True)] == 1 and row[("paper", True)] == 1.0


def test_no_common_scenario_is_an_error():
    puma = pd.DataFrame({"task": ["pouring"], "kind": ["anywhere"], "seed": [1],
                         "method": ["puma"], "limit_steps": [0]})
    with pytest.raises(ValueError, match="no scenario"):
        split_by_puma_limits(_runs(), puma)


@pytest.mark.parametrize("content", [None, "a,b\n1,2\n"], ids=["missing", "not-a-suite-csv"])
def test_a_bad_puma_free_file_is_a_one_line_error_before_any_run(tmp_path, capsys, content):
    from analysis.safety_suite import main

    path = tmp_path / "puma_free.csv"
    if content is not None:
        path.write_text(content)
    with pytest.raises(SystemExit) as exit_:
        main(["--out", str(tmp_path / "out.csv"), "--puma-free", str(path)])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "error: --puma-free" in err[-1]
    assert not (tmp_path / "out.csv").exists()


def test_settle_continues_the_run_after_the_reach_and_judges_the_orientation_there():
    """With ``settle`` S the run goes on at least S seconds past the first reach and then until
    the hand rests (the sweep's rule): the position outcome is the same as without, the run is
    at least S/Δt steps past the reach, and the orientation is judged S after the reach (Fabrics
    on a random tomato scenario: no model needed)."""
    run_one = safety_suite.run_one
    spec = {"task": "tomato", "kind": "near_table1", "seed": 2001, "method": "fabrics",
            "models": "", "set": [], "label": "fabrics"}
    at_reach = run_one({**spec, "settle": 0.0})
    settled = run_one({**spec, "settle": 1.0})
    assert at_reach["success_paper"] and settled["success_paper"]
    assert settled["time_to_success"] == at_reach["time_to_success"]
    reach = round(at_reach["time_to_success"] / 0.02)  # Δt = 0.02 s
    assert settled["steps"] >= max(at_reach["steps"], reach + 50 + 1)
    assert settled["success_orientation_paper"] == (settled["settled_orientation_error"] <= 0.2)


def test_models_folder_is_given_to_the_methods_with_a_model_only():
    """``--models`` names the checkpoint of the learned methods (Modulation-IK's first-order
    one under ``<task>_position``); Fabrics, which has none, runs with it as without it (it
    used to stop the whole suite with Hydra's "Could not override 'method.checkpoint'")."""
    model_path, run_one = safety_suite.model_path, safety_suite.run_one
    assert model_path("/m", "tomato", "fpm") == "/m/tomato/puma.pt"
    assert model_path("/m", "pouring", "modulation_ik") == "/m/pouring_position/puma.pt"
    spec = {"task": "tomato", "kind": "near_table1", "seed": 2001, "method": "fabrics",
            "set": ["scenario.max_steps=20"], "label": "fabrics"}
    with_folder = run_one({**spec, "models": "/nowhere"})
    without = run_one({**spec, "models": ""})
    assert with_folder["steps"] == without["steps"] == 20
    assert with_folder["final_error"] == without["final_error"]


def _trace(n=60, **changes):
    base = {"t": np.arange(n) * 0.02, "error": np.linspace(0.2, 0.0, n),
            "clearance": np.full(n, 0.1), "contact": np.zeros(n, bool),
            "ground": np.zeros(n, bool), "alpha": np.zeros(n), "speed_ratio": np.zeros(n),
            "command_ratio": np.zeros(n), "speed": np.full(n, 0.3),
            "sphere_ground": np.full(n, 0.2), "orientation_error": np.zeros(n),
            "mesh_ground": np.full(n, 0.1), "q": np.zeros((n, 3))}
    return Trace(**{**base, **changes})


@pytest.mark.parametrize("changes, paper, whole, failure", [
    ({}, True, True, ""),
    ({"contact": np.r_[np.zeros(10, bool), True, np.zeros(49, bool)]}, True, False, "mesh"),
    ({"clearance": np.r_[np.full(10, 0.1), -0.01, np.full(49, 0.1)]}, False, False, "contact"),
    ({"mesh_ground": np.r_[np.full(10, 0.1), -0.01, np.full(49, 0.1)],
      "error": np.full(60, 0.2)}, False, False, "ground"),
    ({"q": np.r_[np.zeros((10, 3)), np.full((1, 3), 2.0), np.zeros((49, 3))],
      "error": np.full(60, 0.2)}, False, False, "joint_limit"),
    ({"error": np.full(60, 0.2), "speed": np.zeros(60)}, False, False, "stall"),
    ({"error": np.full(60, 0.2)}, False, False, "time"),
])
def test_each_outcome_gets_its_class(changes, paper, whole, failure):
    """The first class that applies; a joint count of three: nothing assumes the iiwa's seven."""
    out = classify(_trace(**changes), goal_tolerance=0.01, dt=0.02, q_min=-np.ones(3),
                   q_max=np.ones(3))
    assert (out.paper, out.whole_body, out.failure) == (paper, whole, failure)


def test_the_command_writes_its_csv_and_summary(tmp_path, capsys):
    """The suite's command on one short Table-1 run of Fabrics (no model needed)."""
    out = tmp_path / "suite.csv"
    assert safety_suite.main(["--tasks", "tomato", "--kinds", "table1", "--seeds", "0",
                              "--methods", "fabrics", "--set", "scenario.max_steps=20",
                              "--out", str(out)]) == 0
    df = pd.read_csv(out)
    assert len(df) == 1 and df.steps[0] == 20 and df.failure[0] == "time"
    assert "fabrics" in capsys.readouterr().out and not (tmp_path / "suite.partial.csv").exists()


def test_bad_seeds_are_one_line_errors(capsys):
    with pytest.raises(SystemExit) as exc:
        safety_suite.main(["--seeds", "1000-x", "--out", "x.csv"])
    assert exc.value.code == 2 and "--seeds 1000-x" in capsys.readouterr().err
