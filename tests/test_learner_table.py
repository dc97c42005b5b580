"""The learner table's summaries: the families of sets (LASA's shapes) per seed, and the targets
with the median training time over the table and over the robot sets alone."""

from tamedpuma.puma import learner_table


def _row(name, seed=0, order=2, unit="m", dtw=0.008, worst=0.02, train=60.0, conv=1.0,
         compat=0.999, gates=()):
    return {"set": name, "order": order, "seed": seed, "n_demos": 7, "unit": unit, "dtw": dtw,
            "dtw_worst": worst, "frechet": 2 * dtw, "converged": conv, "compatible": compat,
            "iterations": 1000, "train_s": train, "wall_s": train + 2, "cpu_s": train + 1,
            "gates_failed": list(gates)}


def test_a_family_of_sets_is_summarised_per_seed():
    rows = [_row("tomato"),
            _row("lasa:Angle", unit="mm", dtw=1.0, worst=2.0, train=40.0),
            _row("lasa:Sine", unit="mm", dtw=2.0, worst=5.5, train=50.0, compat=0.99,
                 gates=["worst_demo"]),
            _row("lasa:Angle", seed=1, unit="mm", dtw=0.5, worst=0.9, train=44.0, conv=0.998)]
    assert learner_table.families(rows) == [
        "- lasa, seed 0: 2 sets, mean DTW 1.50 mm (largest 2.00 mm), worst demonstration "
        "5.50 mm (lasa:Sine), converged ≥ 100.0%, ψ-compatible ≥ 99.00%, every gate passed by "
        "1, median training 45 s",
        "- lasa, seed 1: 1 sets, mean DTW 0.50 mm (largest 0.50 mm), worst demonstration "
        "0.90 mm (lasa:Angle), converged ≥ 99.8%, ψ-compatible ≥ 99.90%, every gate passed by "
        "1, median training 44 s"]
    text = learner_table.markdown(rows)
    assert text.count("- lasa, seed") == 2 and "| lasa:Sine | 2 | 0 |" in text
    assert learner_table.families([_row("tomato")]) == []
    assert "- " not in learner_table.markdown([_row("tomato")]).split("Medians")[1]


def test_the_targets_name_each_miss_and_both_training_medians():
    rows = [_row("tomato", train=60.0), _row("pouring_v2", dtw=0.018, worst=0.04, train=140.0),
            _row("pouring_v2", order=1, dtw=0.033, worst=0.07, train=80.0),
            _row("pouring_other", train=130.0, compat=0.99),
            *[_row(f"lasa:S{i}", unit="mm", dtw=1.0, worst=2.0, train=45.0) for i in range(3)]]
    text = learner_table.targets(rows)
    assert "met by 1 of 4 models" in text
    assert ("missed by pouring_v2 order 2 seed 0 (DTW, worst demo); pouring_v2 order 1 seed 0 "
            "(DTW, worst demo); pouring_other order 2 seed 0 (ψ)") in text
    # second order: 45, 45, 45, 60, 130, 140 over the table; 60, 130, 140 for the robot sets
    assert ("Median training of a second-order model: 52 s over the table's 6 (target ≤ 90 s: "
            "met); 130 s over the robot sets' 3 alone.") in text
    robot_only = learner_table.targets(rows[:4])
    assert robot_only.endswith("130 s over the table's 3 (target ≤ 90 s: missed).")
    assert learner_table.targets(rows[4:]).startswith("No robot set in the table")
