"""The training's fast paths: each fused or batched piece equals the plain one it
replaces, early stopping ends the run on the validator's word, the weights' moving average is
kept, resumed and returned."""

import copy
import shutil

import numpy as np
import pytest
import torch

from tamedpuma.app.train import compose
from tamedpuma.puma import dynamics, evaluation, losses, network, pipeline, training
from tamedpuma.puma import manifold as m
from tamedpuma.puma.network import NetConfig, PumaNet, StateSpec

RNG = np.random.default_rng(0)


def _quats(n, dtype=torch.float64):
    q = torch.as_tensor(RNG.normal(size=(n, 4)), dtype=dtype)
    return q / q.norm(dim=-1, keepdim=True)


@pytest.mark.parametrize("scale", [0.0, 1e-12, 1e-6, 1e-3, 1.0, 30.0])
def test_fused_orientation_step_equals_exp_then_product(scale):
    q = _quats(200)
    w = (torch.as_tensor(RNG.normal(size=(200, 3))) * scale).requires_grad_(True)
    ref = m.quat_mul(m.quat_exp(w * 0.03), q)
    ref = ref / ref.norm(dim=-1, keepdim=True)
    new = m.step_orientation(q, w, 0.03)
    weights = torch.arange(1.0, 5.0, dtype=torch.float64)
    g_ref, = torch.autograd.grad((ref * weights).sum(), w)
    g_new, = torch.autograd.grad((new * weights).sum(), w)
    assert torch.allclose(new, ref, atol=1e-14)
    assert torch.isfinite(g_new).all() and torch.allclose(g_new, g_ref, atol=1e-12)


def test_fused_rotation_matrix_and_product():
    q, a = _quats(300), _quats(300)
    assert torch.allclose(m.quat_to_matrix_flat(q), m.quat_to_matrix(q).flatten(-2), atol=1e-15)
    assert torch.allclose(m.quat_mul_fused(a, q), m.quat_mul(a, q), atol=1e-15)
    q3 = _quats(24, torch.float32).reshape(4, 6, 4)  # batch shapes and float32
    assert torch.allclose(m.quat_to_matrix_flat(q3), m.quat_to_matrix(q3).flatten(-2), atol=1e-6)


def test_batched_dtw_and_frechet_equal_one_pair_at_a_time():
    paths = [RNG.normal(size=(n, 3)) for n in (5, 17, 9, 30)]
    refs = [RNG.normal(size=(n, 3)) for n in (5, 12, 20, 30)]
    got = evaluation.dtw_per_point_batch(paths, refs)
    want = [evaluation.dtw_per_point(a, b) for a, b in zip(paths, refs)]
    assert np.array_equal(got, want)
    costs = [np.linalg.norm(a[:, None] - b[None], axis=-1) for a, b in zip(paths, refs)]
    assert np.array_equal(evaluation._dp_batch(costs, True),
                          [evaluation.frechet(a, b) for a, b in zip(paths, refs)])


def test_compiled_dtw_recurrence_is_the_numpy_sweep_to_the_bit():
    """The DP each validation runs (:func:`evaluation._dp_batch`): the compiled cell-by-cell
    recurrence (and its plain-Python source) gives the anti-diagonal sweep's numbers exactly,
    with NaN, infinite and zero costs among them."""
    rng = np.random.default_rng(5)
    costs = [np.abs(rng.normal(size=shape)) * 10.0 ** rng.uniform(-4, 3)
             for shape in ((1, 1), (1, 7), (9, 1), (13, 29), (31, 17))]
    costs[3][4, 5], costs[4][2, 3], costs[4][7, 7] = np.nan, np.inf, 0.0
    for frechet in (False, True):
        want = evaluation._dp_sweep(costs, frechet)
        plain = [evaluation._dp_cells(c, frechet) for c in costs]
        assert np.array_equal(plain, want, equal_nan=True)
        if evaluation._dp_kernel() is not None:
            assert np.array_equal(evaluation._dp_batch(costs, frechet), want, equal_nan=True)


def test_stability_weight_ramp():
    from tamedpuma.puma.settings import TrainConfig

    flat = TrainConfig(iterations=100, stability_weight=2.0)
    assert {training.stability_weight(flat, i) for i in (0, 50, 99)} == {2.0}
    ramp = TrainConfig(iterations=100, stability_weight=1.0, stability_weight_end=3.0,
                       stability_ramp_from=0.5)
    assert [training.stability_weight(ramp, i) for i in (0, 50, 75, 100)] == [1.0, 1.0, 2.0, 3.0]


def test_window_curriculum_grows_to_the_full_window_and_slices_the_same_samples():
    from tamedpuma.puma.settings import TrainConfig

    assert {training.window_at(TrainConfig(window=25), i) for i in (0, 500, 2999)} == {25}
    ramp = TrainConfig(iterations=100, window=25, window_start=5, window_ramp=0.5)
    assert [training.window_at(ramp, i) for i in (0, 25, 50, 99)] == [5, 15, 25, 25]
    p = _tiny()
    sampler = training._Sampler.of(p.demos, 8, p.spec.orientation)
    full = sampler.batch(np.random.default_rng(3), 6)
    short = sampler.batch(np.random.default_rng(3), 6, 3)
    assert full[0].shape[1] == 9 and short[0].shape[1] == 4
    for a, b in zip(full, short):
        assert a is None and b is None or torch.equal(a[:, :4], b)


def _net(seed=0):
    torch.manual_seed(seed)
    spec = StateSpec(3, True, 2)
    return PumaNet(spec, NetConfig(32, 8), np.ones(3), np.ones(6), np.ones(6)).double()


def _state(n, seed=1):
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    return (0.3 * torch.randn(n, 3, generator=g, dtype=torch.float64),
            q / q.norm(dim=-1, keepdim=True),
            0.2 * torch.randn(n, 6, generator=g, dtype=torch.float64))


def _grads(net, fn):
    net.zero_grad(set_to_none=True)
    out = fn()
    out.backward()
    return out.detach(), [p.grad.clone() for p in net.parameters()]


def test_shared_goal_gives_the_same_values_and_gradients():
    net = _net()
    net.train()
    s = _state(7)

    def loss():
        states = dynamics.stack(dynamics.rollout(net, s, 0.03, 4))
        return losses.stability_terms(net, states, 0.03, 1e-3)[0] + net(*s).square().mean()

    v0, g0 = _grads(net, loss)
    net.share_goal()
    v1, g1 = _grads(net, loss)
    net.release_goal()
    assert torch.allclose(v0, v1, rtol=1e-12)
    assert all(torch.allclose(a, b, rtol=1e-9, atol=1e-15) for a, b in zip(g0, g1))


def test_layers_as_functions_are_the_modules_to_the_bit():
    """Between share_goal and release_goal the layers run as functions, each Wᵀ taken once for
    all calls: over several calls (rows and a time axis, chained as a rollout chains them) the
    values and every weight's gradient equal the modules' to the bit (float32, as trained)."""
    torch.manual_seed(0)
    net = PumaNet(StateSpec(3, True, 2), NetConfig(32, 8), np.ones(3), np.ones(6), np.ones(6))
    enc, dec = network._functions(net.encoder), network._functions(net.decoder)
    xs = [torch.randn(7, 18), torch.randn(4, 5, 18), torch.randn(7, 18)]

    def run(encoder, decoder):
        net.zero_grad(set_to_none=True)
        total, carry = torch.zeros(()), torch.zeros(6)
        for x in xs:
            x = torch.cat((x[..., :12], x[..., 12:] + carry.mean()), dim=-1)
            out = decoder(torch.cat((encoder(x), x), dim=-1))
            carry = out.reshape(-1, 6)[0]
            total = total + (out * out).sum()
        total.backward()
        return total.detach(), [p.grad.clone() for p in net.parameters()]

    v0, g0 = run(net.encoder, net.decoder)
    v1, g1 = run(lambda x: network._apply(enc, x), lambda y: network._apply(dec, y))
    assert torch.equal(v0, v1)
    assert all(torch.equal(a, b) for a, b in zip(g0, g1))


@pytest.mark.parametrize("window,horizon", [(6, 3), (3, 6), (4, 4)])
def test_joint_rollouts_equal_separate_ones(window, horizon):
    net = _net()
    pos, quat, vel = _state(5 * (window + 1), seed=2)
    target = (pos.reshape(5, window + 1, 3), quat.reshape(5, window + 1, 4),
              vel.reshape(5, window + 1, 6))
    starts = _state(4, seed=3)
    il, st, st_y = training._rollouts(net, target, starts, 0.03, window, horizon)
    il_ref = dynamics.stack(dynamics.rollout(
        net, tuple(x[:, 0] for x in target), 0.03, window))
    st_ref = dynamics.stack(dynamics.rollout(net, starts, 0.03, horizon))
    for got, want in zip(il + st, il_ref + st_ref):
        assert got.shape == want.shape and torch.allclose(got, want, atol=1e-12)
    y_ref = net.encode(*st_ref)  # the reused latents are the rollout states' own
    assert st_y.shape == y_ref.shape and torch.allclose(st_y, y_ref, atol=1e-12)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("g++") is None, reason="torch.compile (inductor) needs g++")
def test_the_compiled_step_gives_the_plain_rollouts_values_and_gradients():
    net = _net()
    net.train()
    start = _state(6, seed=4)

    def run(step):
        net.zero_grad(set_to_none=True)
        net.share_goal()
        states, ys = dynamics.rollout_latents(net, start, 0.03, 4, step)
        states, ys = dynamics.stack(states), torch.stack(ys, dim=1)
        loss = sum((x ** 2).sum() + x.sum() for x in states) + (ys.sin()).sum()
        loss.backward()
        net.release_goal()
        return [*states, ys], [p.grad.clone() for p in net.parameters()]

    values, grads = run(None)
    values_c, grads_c = run(training.compiled_step())
    assert all(torch.allclose(a, b, rtol=1e-12, atol=1e-13) for a, b in zip(values_c, values))
    assert all(torch.allclose(a, b, rtol=1e-10, atol=1e-13) for a, b in zip(grads_c, grads))
    assert training.TrainConfig().compile is False  # opt-in


def _tiny(*overrides):
    cfg = compose("train", ["task=tomato", "puma=tiny", "puma.train.ema=0.9", *overrides])
    return pipeline.prepare(cfg, log=lambda msg: None)


def _flat(state):
    return torch.cat([v.flatten().double() for v in state.values()])


def test_early_stop_returns_the_validated_average_and_resumes_exactly():
    p = _tiny("puma.train.iterations=40", "puma.train.select_every=5", "puma.train.select_from=0")
    calls = []

    def validator(net, final, previous=()):
        calls.append(copy.deepcopy(net.state_dict()))
        return (len(calls),), {"stop": len(calls) == 3}

    args = (p.demos, p.workspace, p.spec, p.net_cfg, p.train_cfg)
    res = training.train(*args, seed=4, progress=False, validator=validator)
    assert res.iterations_run == 15 and len(calls) == 3
    assert [r["chosen"] for r in res.selection] == [False, False, True]
    assert torch.equal(_flat(res.net.state_dict()), _flat(calls[-1]))  # the average, validated
    saved = {}
    calls.clear()
    training.train(*args, seed=4, progress=False, validator=validator,
                   save=lambda s: saved.setdefault(s["it"], copy.deepcopy(s)), save_every=5)
    assert sorted(saved) == [5, 10]
    calls.clear()
    calls.append(None)  # the validation at 5 happened before the save
    again = training.train(*args, seed=4, progress=False, validator=validator, resume=saved[5])
    assert again.iterations_run == 15
    assert torch.equal(_flat(again.net.state_dict()), _flat(res.net.state_dict()))


def test_without_validation_the_average_is_returned():
    p = _tiny("puma.train.iterations=12", "puma.train.select_every=0")
    args = (p.demos, p.workspace, p.spec, p.net_cfg, p.train_cfg)
    res = training.train(*args, seed=0, progress=False)
    run = training._start(*args, 0)
    for _ in range(12):
        training._iteration(run, p.spec, p.train_cfg)
    assert torch.equal(_flat(res.net.state_dict()), _flat(run.ema.state_dict()))
    assert not torch.equal(_flat(res.net.state_dict()), _flat(run.net.state_dict()))


def test_the_output_scale_is_a_typical_demonstrations_peak_that_one_spike_does_not_set():
    p = _tiny()
    spiked = copy.deepcopy(p.demos)
    v = spiked.vel[0]
    v[len(v) // 2:, 0] += 0.5  # a jump in one component of one demonstration: one spike
    spec, ws = p.spec, p.workspace
    top = training.scales(spiked, ws, spec.order)[2]
    median = training.scales(spiked, ws, spec.order, 0.5)[2]
    peaks = sorted(np.abs(np.diff(v, axis=0) / p.demos.dt)[:, :3].max() for v in p.demos.vel)
    assert top[0] > 5 * median[0]  # the maximum is the spike's
    assert peaks[len(peaks) // 2 - 1] <= median[0] <= peaks[len(peaks) // 2 + 1]
    assert np.array_equal(training.scales(p.demos, ws, spec.order, 1.0)[2],
                          training.scales(p.demos, ws, spec.order)[2])
    acc = np.concatenate([np.diff(v, axis=0, append=v[-1:]) / p.demos.dt for v in p.demos.vel])
    assert top[3] == np.abs(acc[:, 3:]).max()  # 1: the largest over all samples, as before


def test_the_stop_target_is_the_smallest_of_the_gate_the_spread_and_the_absolute_line():
    import dataclasses

    from tamedpuma.puma import gates

    p = _tiny()
    limit = gates.imitation_limit(p.spread, gates.demo_extent(p.demos), p.eval_cfg)

    def target(**kw):
        return pipeline.stop_target(dataclasses.replace(
            p, train_cfg=dataclasses.replace(p.train_cfg, **{
                "stop_gate": 0.0, "stop_spread": 0.0, "stop_dtw": 0.0, **kw})))

    assert target() == 0.0
    assert target(stop_gate=0.5) == pytest.approx(0.5 * min(limit, p.eval_cfg.pos_tol))
    assert target(stop_spread=0.1) == pytest.approx(0.1 * float(np.median(p.spread)))
    assert target(stop_gate=0.5, stop_dtw=1e-4) == pytest.approx(1e-4)
    assert target(stop_gate=0.5, stop_spread=0.1) == pytest.approx(
        min(0.5 * min(limit, p.eval_cfg.pos_tol), 0.1 * float(np.median(p.spread))))


def test_the_default_config_stops_on_the_data_not_on_a_fixed_line():
    t = compose("train", ["task=tomato"])["puma"]["train"]
    assert t["stop_dtw"] == 0 and t["keep_dtw"] == 0  # no absolute DTW line
    assert 0 < t["stop_spread"] < 1 and t["patience"] >= 2 and 0 < t["min_delta"] < 0.2
    assert t["path_weight"] > 0 and t["ema"] > 0 and t["val_confirm"] + t["val_starts"] >= 1000
    candidate = compose("train", ["task=tomato", "puma=candidate"])["puma"]
    assert 0 < candidate["train"]["stop_gate"] < 1 and candidate["train"]["stop_spread"] == 0
    assert candidate["network"]["out_quantile"] == 0.5 and candidate["train"]["lr"] == 0.003


def test_a_plateau_starts_the_final_decay_and_the_run_ends_after_it():
    p = _tiny("puma.train.iterations=100", "puma.train.select_every=5", "puma.train.select_from=0",
              "puma.train.anneal=10")
    calls = []

    def validator(net, final, previous=()):
        calls.append(final)
        return (0,), {"stop": False, "plateau": len(calls) >= 2, "passed": True, "dtw": 1.0}

    args = (p.demos, p.workspace, p.spec, p.net_cfg, p.train_cfg)
    saved = {}
    res = training.train(*args, seed=4, progress=False, validator=validator,
                         save=lambda s: saved.setdefault(s["it"], copy.deepcopy(s)), save_every=5)
    assert res.iterations_run == 20 and calls == [False, False, False, True]  # 10 + 10
    start, lr10 = saved[15]["anneal"]
    lr = p.train_cfg.lr
    assert start == 10 and lr10 < lr  # the cosine had begun to fall
    assert saved[15]["opt"]["param_groups"][0]["lr"] == pytest.approx(
        lr10 + (0.02 * lr - lr10) * 0.5)  # half way down
    calls[:] = [False, False, False]
    again = training.train(*args, seed=4, progress=False, validator=validator, resume=saved[15])
    assert again.iterations_run == 20
    assert torch.equal(_flat(again.net.state_dict()), _flat(res.net.state_dict()))


def test_a_stop_keeps_the_best_validated_weights_not_the_last():
    """The run's last validation passes and ends it, but an earlier one passed with a better
    score (a lower DTW): the earlier weights are kept and marked chosen."""
    p = _tiny("puma.train.iterations=40", "puma.train.select_every=5", "puma.train.select_from=0")
    dtws, calls = [3.0, 1.5, 2.0, 1.8], []

    def validator(net, final, previous=()):
        calls.append(copy.deepcopy(net.state_dict()))
        dtw = dtws[len(calls) - 1]
        passed = len(calls) >= 2
        return (passed, -dtw), {"stop": len(calls) == 4, "passed": passed, "dtw": dtw}

    res = training.train(p.demos, p.workspace, p.spec, p.net_cfg, p.train_cfg, seed=4,
                         progress=False, validator=validator)
    assert res.iterations_run == 20 and len(calls) == 4
    assert [r["chosen"] for r in res.selection] == [False, True, False, False]
    assert torch.equal(_flat(res.net.state_dict()), _flat(calls[1]))
    assert not torch.equal(_flat(calls[1]), _flat(calls[3]))


def _checking_validator(dtws, checked, passes):
    """A validator with the given DTW per validation (weights seen before: their DTW); it
    measures (checks) only those numbered in ``checked`` (1 = the first) and the final ones, and
    those pass where ``passes(weights)``; it records each call's (number, final, weights)."""
    calls = []

    def validator(net, final, previous=()):
        n = len(previous) + 1
        state = copy.deepcopy(net.state_dict())
        seen = [i for i, (_, _, w) in enumerate(calls) if torch.equal(_flat(w), _flat(state))]
        calls.append((n, final, state))
        dtw = dtws[seen[0]] if seen else dtws[n - 1]
        if not (final or n in checked):
            return (False, False, 0.0, -dtw), {"stop": False, "passed": False, "dtw": dtw}
        ok = passes(state)
        info = {"stop": False, "passed": ok, "dtw": dtw, "converged_fraction": float(ok)}
        return (ok, ok, float(ok), -dtw), info
    return validator, calls


def test_the_lowest_dtw_left_unchecked_is_checked_at_the_end_and_kept_where_it_passes():
    """Validation 2 has the run's lowest DTW, but the rule did not check it; the training then
    leaves it (the DTW rises). At the end its weights are checked: they pass and are kept."""
    p = _tiny("puma.train.iterations=30", "puma.train.select_every=5", "puma.train.select_from=0")
    validator, calls = _checking_validator([3.0, 1.0, 2.5, 2.0, 2.2, 2.1], {4}, lambda s: True)
    res = training.train(p.demos, p.workspace, p.spec, p.net_cfg, p.train_cfg, seed=4,
                         progress=False, validator=validator)
    assert [(n, final) for n, final, _ in calls] == [(1, False), (2, False), (3, False),
                                                    (4, False), (5, False), (6, True), (7, True)]
    assert torch.equal(_flat(calls[-1][2]), _flat(calls[1][2]))  # the weights of validation 2
    chosen = [r for r in res.selection if r["chosen"]]
    assert len(chosen) == 1 and chosen[0]["it"] == 10 and chosen[0]["rechecked"]
    assert torch.equal(_flat(res.net.state_dict()), _flat(calls[1][2]))


def test_unchecked_weights_that_fail_their_check_leave_the_choice_as_it_was():
    p = _tiny("puma.train.iterations=30", "puma.train.select_every=5", "puma.train.select_from=0")
    # every weights pass their check but validation 2's (calls: the validator's own record)
    validator, calls = _checking_validator([3.0, 1.0, 2.5, 2.0, 2.2, 2.1], {4},
                                           lambda s: not torch.equal(_flat(s), _flat(calls[1][2])))
    res = training.train(p.demos, p.workspace, p.spec, p.net_cfg, p.train_cfg, seed=4,
                         progress=False, validator=validator)
    assert len(calls) == 7 and calls[-1][1]  # the check ran ...
    assert torch.equal(_flat(calls[-1][2]), _flat(calls[1][2]))
    chosen = [r for r in res.selection if r["chosen"]]
    assert [r["it"] for r in chosen] == [20]  # ... and the checked validation 4 stays chosen
    assert torch.equal(_flat(res.net.state_dict()), _flat(calls[3][2]))


def test_a_lowest_dtw_that_was_checked_needs_no_second_check():
    p = _tiny("puma.train.iterations=30", "puma.train.select_every=5", "puma.train.select_from=0")
    validator, calls = _checking_validator([3.0, 1.0, 2.5, 2.0, 2.2, 2.1], {2}, lambda s: True)
    res = training.train(p.demos, p.workspace, p.spec, p.net_cfg, p.train_cfg, seed=4,
                         progress=False, validator=validator)
    assert len(calls) == 6 and [r["it"] for r in res.selection if r["chosen"]] == [10]


def _plateau_validator(passing: set):
    """A validator whose DTW is flat from its second validation on (a plateau) and whose weights
    pass only at the validations numbered in ``passing`` (1 = the first); it counts from the
    earlier DTWs it is given, so a resumed run sees the same sequence."""
    seen = []

    def validator(net, final, previous=()):
        n = len(previous) + 1
        seen.append((n, final, copy.deepcopy(net.state_dict())))
        passed = n in passing
        return (passed, -n), {"stop": False, "plateau": n >= 2, "passed": passed, "dtw": 1.0}
    return validator, seen


def test_a_plateau_of_weights_that_fail_the_validation_does_not_end_the_run():
    p = _tiny("puma.train.iterations=60", "puma.train.select_every=5", "puma.train.select_from=0",
              "puma.train.anneal=10")
    args = (p.demos, p.workspace, p.spec, p.net_cfg, p.train_cfg)
    # the plateau from the 2nd validation on; the weights pass at the 5th only (iteration 25)
    validator, seen = _plateau_validator({5})
    saved = {}
    res = training.train(*args, seed=4, progress=False, validator=validator,
                         save=lambda s: saved.setdefault(s["it"], copy.deepcopy(s)), save_every=5)
    assert saved[20]["anneal"][0] is None  # three failing plateaus: the schedule runs on
    assert saved[30]["anneal"][0] == 25
    assert res.iterations_run == 35 and seen[-1][:2] == (7, True)  # the decay from 25, then end
    chosen = [r["it"] for r in res.selection if r["chosen"]]
    assert chosen == [25]  # the weights that passed, not the decay's end that did not
    assert torch.equal(_flat(res.net.state_dict()), _flat(seen[4][2]))
    again = training.train(*args, seed=4, progress=False, validator=validator, resume=saved[15])
    assert again.iterations_run == 35
    assert torch.equal(_flat(again.net.state_dict()), _flat(res.net.state_dict()))


def test_weights_that_never_pass_train_to_the_last_iteration():
    p = _tiny("puma.train.iterations=40", "puma.train.select_every=5", "puma.train.select_from=0",
              "puma.train.anneal=10")
    validator, seen = _plateau_validator(set())
    res = training.train(p.demos, p.workspace, p.spec, p.net_cfg, p.train_cfg, seed=4,
                         progress=False, validator=validator)
    assert res.iterations_run == 40 and [n for n, *_ in seen] == list(range(1, 9))
    assert [final for _, final, _ in seen] == [False] * 7 + [True]


def test_on_a_plateau_the_validation_checks_but_only_stops_where_told():
    from tamedpuma.puma import evaluation

    p = _tiny()
    net = training.build_net(p.demos, p.workspace, p.spec, p.net_cfg).eval()
    net.cache_goal()
    d = evaluation.imitation_dtw(net, p.demos)
    kw = dict(starts=20, patience=2, min_delta=0.03, stop_compat=0.5, horizon=1.0)
    annealing = evaluation.validator(p.demos, p.workspace, p.eval_cfg, plateau_stops=False, **kw)
    with torch.no_grad():
        _, fresh = annealing(net, False, ())
        _, flat = annealing(net, False, (d, d))
        _, ending = evaluation.validator(p.demos, p.workspace, p.eval_cfg, **kw)(net, False, (d, d))
    assert "converged_fraction" not in fresh and not fresh["plateau"] and not fresh["passed"]
    assert flat["plateau"] and "converged_fraction" in flat and not flat["stop"]
    assert flat["passed"] == (flat["converged_fraction"] == 1.0
                              and flat["compatible_fraction"] >= 0.5)
    assert ending["stop"] == ending["passed"] == (ending["converged_fraction"] == 1.0
                                                  and ending["compatible_fraction"] >= 0.5)


def test_selection_without_a_stop_rule_ranks_psi_when_asked():
    """Without a stop rule the score is (converged, −DTW); with stop_compat it ranks ψ as the
    stop rule does: (ψ passes and all converge, ψ passes, converged, −DTW), so weights that fail
    ψ never outrank weights that pass it, whatever their DTW."""
    from tamedpuma.puma import evaluation

    p = _tiny()
    net = training.build_net(p.demos, p.workspace, p.spec, p.net_cfg).eval()
    net.cache_goal()
    kw = dict(starts=20, horizon=1.0)
    with torch.no_grad():
        plain, info = evaluation.validator(p.demos, p.workspace, p.eval_cfg, **kw)(net)
        strict, sinfo = evaluation.validator(p.demos, p.workspace, p.eval_cfg, stop_compat=1.01,
                                             **kw)(net)  # no model is 101 % compatible
        loose, linfo = evaluation.validator(p.demos, p.workspace, p.eval_cfg, stop_compat=1e-9,
                                            **kw)(net)
    frac, dtw = info["converged_fraction"], info["dtw"]
    assert plain == (frac, -dtw) and "compatible_fraction" not in info
    assert strict == (False, False, frac, -dtw) and 0 <= sinfo["compatible_fraction"] <= 1
    psi_ok = linfo["compatible_fraction"] >= 1e-9
    assert loose == (psi_ok and frac == 1.0, psi_ok, frac, -dtw)


def test_compile_without_a_cpp_compiler_is_a_one_line_config_error(monkeypatch):
    from tamedpuma.errors import ConfigError

    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(ConfigError, match=r"puma\.train\.compile=true needs a C\+\+ compiler"):
        training.compiled_step()


def test_the_uniform_compat_states_cover_the_box_beyond_the_goals_ball():
    """ψ's extra hinge states are drawn as the evaluation draws its own: uniform in the (not
    padded) box, none within exclude × the box's largest side of the goal."""
    ws = training.Workspace((-1.0, -2.0), (3.0, 2.0))
    spec = StateSpec(2, False, 2)
    pos, quat = training.compat_states(np.random.default_rng(0), ws, spec, 4000, 0.1)
    p = pos.numpy()
    assert quat is None and pos.dtype == torch.float32
    assert np.all(p >= ws.low) and np.all(p <= ws.high)
    assert np.all(np.linalg.norm(p, axis=1) > 0.4)
    assert 3700 < len(p) < 4000  # the ball (r = 0.4) holds about 3% of the 4 x 4 box
    assert p[:, 0].min() < -0.9 and p[:, 0].max() > 2.9 and p[:, 1].max() > 1.9
    ows = training.Workspace((-0.1, -0.1, -0.1), (0.1, 0.1, 0.1), 0.5)
    pos, quat = training.compat_states(np.random.default_rng(1), ows, StateSpec(3, True, 2),
                                       2000, 0.5)  # r = 0.1 m and 0.1 rad
    near = pos.norm(dim=1) <= 0.1
    assert bool(near.any())  # kept where the orientation is far from the goal's
    assert np.all(np.linalg.norm(m.np_quat_log(quat[near].double().numpy()), axis=1) > 0.1)


def test_the_compat_hinge_is_on_the_stability_starts_by_default_else_on_uniform_states():
    """Off (the default), an iteration's ψ term is the hinge on the stability starts with the
    step ``compat_eps``, as before; with ``compat_uniform`` it is the hinge on that many uniform
    states drawn next from the run's generator instead, with ``compat_eps_rel`` × the box."""
    off = _tiny("puma.train.select_every=0")
    on = _tiny("puma.train.select_every=0", "puma.train.compat_uniform=32",
               "puma.train.compat_eps_rel=0.02")
    ws, spec = off.workspace, off.spec
    assert off.train_cfg.compat_uniform == 0 and off.train_cfg.compat_eps_rel == 0
    assert training.compat_step(off.train_cfg, ws) == off.train_cfg.compat_eps
    size = float(np.max(np.subtract(ws.high, ws.low)))
    assert training.compat_step(on.train_cfg, ws) == pytest.approx(0.02 * size)
    for p in (off, on):
        cfg = p.train_cfg
        args = (p.demos, ws, spec, p.net_cfg, cfg)
        run, twin = training._start(*args, 3), training._start(*args, 3)
        terms = training._iteration(run, spec, cfg)
        twin.sampler.batch(twin.rng, cfg.batch_windows, training.window_at(cfg, 0))
        pos, quat, _, _ = training._stability_starts(twin, spec, cfg)
        if cfg.compat_uniform:
            pos, quat = training.compat_states(twin.rng, ws, spec, 32, cfg.compat_exclude)
            assert len(pos) > 16
        want = losses.compat_loss(twin.net, pos, quat, training.compat_step(cfg, ws), cfg.margin)
        assert terms["compat"] == pytest.approx(want.item(), rel=1e-5, abs=1e-9)


def test_fresh_starts_join_the_continued_rollouts_and_only_those_go_on():
    """With ``fresh_starts`` F each iteration's stability rollouts are the B continued (or
    restarted) ones and F new workspace samples; the rollouts carried to the next iteration are
    the B, so the fresh ones never become chains. F = 0 (``puma=tiny``'s, as ``v1``'s) leaves
    the B alone."""
    off = _tiny("puma.train.select_every=0")
    on = _tiny("puma.train.select_every=0", "puma.train.fresh_starts=8")
    assert off.train_cfg.fresh_starts == 0
    cfg, spec = on.train_cfg, on.spec
    b = cfg.stability_batch
    run = training._start(on.demos, on.workspace, spec, on.net_cfg, cfg, 0)
    first = training._stability_starts(run, spec, cfg)
    assert len(first[0]) == len(first[3]) == b + 8
    training._iteration(run, spec, cfg)
    assert len(run.chain[0]) == len(run.chain_rest) == b
    chain = run.chain[0]
    pos = training._stability_starts(run, spec, cfg)[0]
    continued = (pos[:, None, :] == chain[None]).all(-1).any(-1)  # rows equal to a chain's end
    assert continued[:b].any() and not continued[b:].any()
    lo, hi = (torch.as_tensor(x, dtype=pos.dtype) for x in (run.start_ws.low, run.start_ws.high))
    assert torch.all((pos[b:] >= lo) & (pos[b:] <= hi))
    base = training._start(off.demos, off.workspace, spec, off.net_cfg, off.train_cfg, 0)
    assert len(training._stability_starts(base, spec, off.train_cfg)[0]) == b
