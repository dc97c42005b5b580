"""Training-loss properties: the path-potential hinge is trainable and has the right sign; the
padded stability sampling reaches beyond the workspace box."""

import numpy as np
import torch

from tamedpuma.puma import losses, training
from tamedpuma.puma.network import NetConfig, PumaNet, StateSpec


def _net(seed=0):
    torch.manual_seed(seed)
    return PumaNet(StateSpec(2, False, 2), NetConfig(32, 8), [1.0, 1.0], [1.0, 1.0], [1.0, 1.0])


def _spiral(n=40):
    """A path that winds around the goal (0, 0) towards it: generic encoders do not make the
    latent distance to the goal fall monotonically along it."""
    t = np.linspace(0.0, 1.0, n)
    r, a = 0.9 * (1.0 - t) + 1e-3, 5.0 * np.pi * t
    return torch.as_tensor(np.stack([r * np.cos(a), r * np.sin(a)], -1)[None], dtype=torch.float32)


def _rises(net, path):
    with torch.no_grad():
        d = (net.encode(path, None) - net.goal_latent()).norm(dim=-1)
    return int((d[:, 1:] > d[:, :-1]).sum())


def test_path_potential_loss_counts_rises_and_training_removes_them():
    net, path = _net(), _spiral()
    assert _rises(net, path) > 0  # otherwise the test shows nothing
    # the hinge is positive exactly when ψ rises somewhere (margin 0)
    assert losses.path_potential_loss(net, path, None, 0.0).item() > 0
    # reversed in time, every fall becomes a rise
    assert (losses.path_potential_loss(net, path.flip(1), None, 0.0).item()
            > losses.path_potential_loss(net, path, None, 0.0).item())
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    for _ in range(300):
        loss = losses.path_potential_loss(net, path, None, 1e-4)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert _rises(net, path) == 0


def test_path_potential_loss_on_the_goal_is_the_margin():
    net = _net()
    rest = torch.zeros(3, 5, 2)
    assert abs(losses.path_potential_loss(net, rest, None, 0.25).item() - 0.25) < 1e-6


def test_padded_stability_starts_leave_the_box_evenly():
    ws = training.Workspace((0.0, -1.0), (2.0, 1.0))
    cfg = training.TrainConfig(stability_batch=4000, sample_pad=0.1)
    spec = StateSpec(2, False, 2)
    pos, _, _ = training._random_starts(np.random.default_rng(0), ws.padded(cfg.sample_pad), spec,
                                        cfg, np.ones(2))
    pos = pos.numpy()
    assert np.all(pos >= [-0.2, -1.2]) and np.all(pos <= [2.2, 1.2])
    outside = np.any((pos < ws.low) | (pos > ws.high), axis=1).mean()
    assert abs(outside - (1 - (1 / 1.2) ** 2)) < 0.03  # the padded ring's share of the area
    plain = training._random_starts(np.random.default_rng(0), ws, spec,
                                    training.TrainConfig(stability_batch=500), np.ones(2))[0]
    assert np.all((plain.numpy() >= ws.low) & (plain.numpy() <= ws.high))
