"""Checkpoints round-trip and load strictly, with one-line errors."""

import re

import numpy as np
import pytest
import torch

from tamedpuma.errors import CheckpointError
from tamedpuma.puma import checkpoint
from tamedpuma.puma.network import NetConfig, PumaNet, StateSpec
from tamedpuma.puma.primitive import PosePrimitive, load_primitive
from tamedpuma.puma.training import Workspace


def make_net(seed=0, width=32):
    torch.manual_seed(seed)
    return PumaNet(StateSpec(3, True, 2), NetConfig(width, 16), [0.5, 0.7, 0.6],
                   [0.2] * 3 + [1.0] * 3, [1.0] * 3 + [5.0] * 3)


def make_meta():
    return checkpoint.Meta(0.03, "final_pose", {"position": [0.5, 0, 0.1],
                                                "quaternion": [0, 0, 0, 1]}, "m",
                           Workspace((-0.3, -0.1, -0.1), (0.25, 0.7, 0.65), 1.6),
                           {"task": {"name": "t"}, "seed": np.int64(3)}, "ab" * 32, "test",
                           {"x": np.float64(1.5)})


@pytest.fixture
def saved(tmp_path):
    net = make_net()
    return net, checkpoint.save(tmp_path / "puma.pt", net, make_meta())


def test_round_trip_gives_identical_outputs(saved):
    net, path = saved
    net2, meta = checkpoint.load(path)
    quat = torch.nn.functional.normalize(torch.randn(5, 4), dim=-1)
    x = torch.randn(5, 3), quat, torch.randn(5, 6)
    net.eval()
    assert torch.allclose(net(*x), net2(*x))
    assert meta.dt == 0.03 and meta.goal_convention == "final_pose" and meta.config["seed"] == 3
    assert isinstance(load_primitive(path), PosePrimitive)


def _rewrite(path, fn):
    ck = torch.load(path, weights_only=True)
    fn(ck)
    torch.save(ck, path)


def _expect(path, match):
    with pytest.raises(CheckpointError, match=match) as err:
        checkpoint.load(path)
    assert "\n" not in str(err.value)


def test_wrong_format_version(saved):
    _, path = saved
    _rewrite(path, lambda ck: ck.__setitem__("format_version", 99))
    _expect(path, "format version 99")


def test_missing_key(saved):
    _, path = saved
    _rewrite(path, lambda ck: ck.pop("dt"))
    _expect(path, "missing key.*dt")


def test_wrong_shape(saved):
    _, path = saved
    _rewrite(path, lambda ck: ck["state_dict"].__setitem__("encoder.0.weight", torch.zeros(3, 3)))
    _expect(path, r"encoder.0.weight has shape \(3, 3\)")


def test_missing_and_unexpected_parameter(saved):
    _, path = saved
    _rewrite(path, lambda ck: ck["state_dict"].pop("decoder.1.bias"))
    _expect(path, "missing parameter.*decoder.1.bias")
    _rewrite(path, lambda ck: ck["state_dict"].__setitem__("decoder.1.bias", torch.zeros(32)))
    _rewrite(path, lambda ck: ck["state_dict"].__setitem__("extra", torch.zeros(1)))
    _expect(path, "unexpected parameter.*extra")


def test_corrupt_missing_and_foreign_files(tmp_path, saved):
    _, path = saved
    data = path.read_bytes()
    (tmp_path / "trunc.pt").write_bytes(data[: len(data) // 2])
    _expect(tmp_path / "trunc.pt", "truncated or corrupt PyTorch archive")
    _expect(tmp_path / "none.pt", "file not found")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "other.pt")
    _expect(tmp_path / "other.pt", "not a PUMA checkpoint")


class _RunsCode:
    def __reduce__(self):
        import os

        return (os.system, ("true",))


def _bad_files(tmp_path, path):
    """Every kind of broken checkpoint file: (file, the message's expected words)."""
    data = path.read_bytes()
    cases = {"empty.pt": (b"", "empty file"),
             "trunc.pt": (data[: len(data) - 30], "truncated or corrupt PyTorch archive"),
             "random.pt": (np.random.default_rng(0).bytes(4000), "not a PyTorch checkpoint")}
    out = []
    for name, (content, match) in cases.items():
        (tmp_path / name).write_bytes(content)
        out.append((tmp_path / name, match))
    torch.save({"x": _RunsCode()}, tmp_path / "code.pt", _use_new_zipfile_serialization=False)
    out.append((tmp_path / "code.pt", "refused: loading it would run code"))
    (tmp_path / "folder.pt").mkdir()
    out.append((tmp_path / "folder.pt", "is a folder, not a checkpoint file"))
    ck = torch.load(path, weights_only=True)
    torch.save({**ck, "dt": "fast"}, tmp_path / "dt.pt")
    out.append((tmp_path / "dt.pt", "invalid header .*could not convert string to float"))
    torch.save({**ck, "workspace": {"low": 1}}, tmp_path / "ws.pt")
    out.append((tmp_path / "ws.pt", "invalid header"))
    return out


def test_every_broken_file_is_one_line_naming_the_file_and_the_fault(tmp_path, saved):
    for path, match in _bad_files(tmp_path, saved[1]):
        _expect(path, f"checkpoint {path}: {match}")


def test_a_broken_checkpoint_given_to_the_sweep_is_one_line_and_status_2(tmp_path, saved):
    """The command line: each broken file (a folder, a truncated archive, random bytes) → one
    line ``error: checkpoint FILE: ...`` on stderr, status 2, no traceback."""
    import subprocess
    import sys

    cases = {p.name: (p, m) for p, m in _bad_files(tmp_path, saved[1])}
    for name in ("folder.pt", "trunc.pt", "random.pt"):
        path, match = cases[name]
        proc = subprocess.run([sys.executable, "-m", "tamedpuma.sweep", "method=fpm",
                               f"method.checkpoint={path}", f"output_root={tmp_path / 'runs'}"],
                              capture_output=True, text=True, timeout=300)
        lines = [ln for ln in proc.stderr.splitlines() if not ln.startswith("pybullet build")]
        assert proc.returncode == 2, proc.stderr
        assert len(lines) == 1 and re.match(f"error: checkpoint {path}: {match}", lines[0]), lines
