"""Demonstration loading: restricted unpickler, validation, preparation, synthetic generator."""

import os
import pickle

import numpy as np
import pytest

from tamedpuma.errors import DataError
from tamedpuma.puma import data, demos_synthetic, manifold
from tamedpuma.robot import rotations

GOAL_P = [0.58, -0.214, 0.115]
GOAL_Q = [-0.5459, 0.5806, -0.4112, 0.4426]


def _demo_dict(n=40, seed=0):
    raw = demos_synthetic.generate("tomato", GOAL_P, GOAL_Q, 1, seed)[0]
    idx = np.linspace(0, len(raw.pos) - 1, n).astype(int)
    return {"x_pos": list(raw.pos[idx]), "x_rot": list(rotations.quats_to_matrices(raw.quat[idx])),
            "x_dot": list(np.zeros((n, 6))), "delta_t": np.full(n, 0.03)}


def _write(folder, d, i=0):
    folder.mkdir(exist_ok=True)
    with open(folder / f"ee_state_{i}.pk", "wb") as f:
        pickle.dump(d, f)


def test_valid_pickles_load_in_natural_order(tmp_path):
    for i in (0, 2, 10):
        _write(tmp_path, _demo_dict(40 + i), i)
    raws = data.load_pickle_demos(tmp_path)
    assert [len(r.pos) for r in raws] == [40, 42, 50]
    assert raws[0].quat.shape == (40, 4)


class _Evil:
    def __reduce__(self):
        return (os.system, ("touch PWNED_BY_PICKLE",))


def test_restricted_unpickler_rejects_code(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    d = _demo_dict()
    d["x_dot"] = _Evil()
    _write(tmp_path / "demos", d)
    with pytest.raises(DataError, match="not allowed"):
        data.load_pickle_demos(tmp_path / "demos")
    assert not (tmp_path / "PWNED_BY_PICKLE").exists()


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d["x_pos"].__setitem__(3, np.array([np.nan, 0, 0])), "NaN"),
    (lambda d: d.__setitem__("x_pos", np.zeros((40, 2))), "shape"),
    (lambda d: d.__setitem__("x_rot", np.zeros((40, 3, 3))), "rotation"),
    (lambda d: d.__setitem__("delta_t", np.full(39, 0.03)), "lengths"),
    (lambda d: d.pop("delta_t"), "missing key"),
    (lambda d: d.__setitem__("x_pos", "abc"), "numeric"),
])
def test_bad_demonstrations_give_data_error(tmp_path, mutate, match):
    d = _demo_dict()
    mutate(d)
    _write(tmp_path, d)
    with pytest.raises(DataError, match=match):
        data.load_pickle_demos(tmp_path)


def test_missing_folder_and_garbage_file(tmp_path):
    with pytest.raises(DataError, match="not found"):
        data.load_pickle_demos(tmp_path / "nope")
    (tmp_path / "ee_state_0.pk").write_bytes(b"garbage")
    with pytest.raises(DataError):
        data.load_pickle_demos(tmp_path)


def test_synthetic_generator_is_seeded_and_ends_at_goal():
    a = demos_synthetic.generate("pouring", GOAL_P, GOAL_Q, 3, seed=5)
    b = demos_synthetic.generate("pouring", GOAL_P, GOAL_Q, 3, seed=5)
    c = demos_synthetic.generate("pouring", GOAL_P, GOAL_Q, 3, seed=6)
    assert all(np.array_equal(x.pos, y.pos) for x, y in zip(a, b))
    assert not np.array_equal(a[0].pos, c[0].pos)
    for r in a:
        np.testing.assert_allclose(r.pos[-1], GOAL_P, atol=1e-9)
        rel = rotations.quat_mul(r.quat[-1], rotations.quat_conj(np.array(GOAL_Q) /
                                                                     np.linalg.norm(GOAL_Q)))
        assert rotations.quat_angle(rel) < 1e-6
        assert 0.025 < np.mean(r.delta_t[1:]) < 0.035


def test_prepare_is_goal_relative_and_integrates_back():
    raws = demos_synthetic.generate("tomato", GOAL_P, GOAL_Q, 2, seed=0)
    d = data.prepare(raws, 0.03, smoothing=1.0, hold=5)
    for i in range(len(d)):
        np.testing.assert_allclose(d.pos[i][-1], 0.0, atol=1e-12)
        np.testing.assert_allclose(d.quat[i][-1], [0, 0, 0, 1], atol=1e-9)
        # semi-implicit Euler with the stored velocities reproduces the path exactly
        pos = d.pos[i][0] + np.cumsum(d.vel[i][1:, :3] * d.dt, axis=0)
        np.testing.assert_allclose(pos, d.pos[i][1:], atol=1e-9)
        q = d.quat[i][0]
        for k in range(1, len(d.quat[i])):
            q = rotations.quat_mul(manifold.np_quat_exp(d.vel[i][k, 3:] * d.dt), q)
        assert rotations.quat_angle(q) < 1e-6
    assert len(d.data_hash) == 64


def test_lasa_loader():
    raws = data.load_lasa("Angle", every=10)
    assert len(raws) == 7 and raws[0].pos.shape == (100, 2) and raws[0].quat is None
    assert len(data.lasa_names()) == 30
    with pytest.raises(DataError, match="unknown LASA"):
        data.load_lasa("NoSuchShape")
