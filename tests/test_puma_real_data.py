"""The authors' real KUKA demonstrations load and prepare (skipped without ../shared)."""

from pathlib import Path

import numpy as np
import pytest

from tamedpuma.puma import data
from tamedpuma.robot import rotations

DEMOS = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pumafabrics-demos"
pytestmark = pytest.mark.skipif(not DEMOS.is_dir(),
                                reason=f"real demonstrations not available at {DEMOS}")


@pytest.mark.parametrize("folder, count, end", [
    ("pick_tomato_31may", 10, [0.620, -0.198, 0.140]),
    ("pouring_v2", 38, [-0.097, -0.739, 0.210]),
])
def test_real_demos_load_validate_and_prepare(folder, count, end):
    raws = data.load_pickle_demos(DEMOS / folder)
    assert len(raws) == count
    ends = np.array([r.pos[-1] for r in raws])
    np.testing.assert_allclose(ends.mean(0), end, atol=0.02)
    periods = np.concatenate([r.delta_t[1:] for r in raws])
    assert abs(np.median(periods) - 0.030) < 0.002  # about 33 Hz
    d = data.prepare(raws, 0.03, smoothing=2.0)
    assert len(d) == count and d.orientation
    for i in range(count):
        assert np.all(np.isfinite(d.vel[i]))
        np.testing.assert_allclose(d.pos[i][-1], 0.0, atol=1e-12)
        assert rotations.quat_angle(d.quat[i][-1]) < 1e-9
