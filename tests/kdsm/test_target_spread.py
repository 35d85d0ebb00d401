"""The spread of a target over poses (Table 1's `pose_spread_cm`), accumulated in chunks."""

import numpy as np
import pytest

from tryon.kdsm.evaluate import TargetSpread


def test_spread_of_chunks_is_the_spread_of_all():
    rng = np.random.default_rng(3)
    t = 0.05 + 0.01 * rng.standard_normal((23, 40, 3)) * rng.random((1, 40, 1))   # metres, per-vertex scales
    spread = TargetSpread()
    for chunk in np.split(t, [5, 6, 17]):        # sequences of 5, 1, 11 and 6 poses
        spread.add(chunk)
    direct = 100.0 * np.sqrt(((t - t.mean(0)) ** 2).sum(-1).mean(0))
    assert np.allclose(spread.per_vertex_cm(), direct, rtol=1e-9, atol=1e-9)
    assert spread.count == 23


def test_a_constant_target_does_not_spread_and_nothing_added_is_refused():
    spread = TargetSpread()
    spread.add(np.full((4, 7, 3), 0.3))
    assert np.allclose(spread.per_vertex_cm(), 0.0, atol=1e-6)
    with pytest.raises(ValueError, match="no targets"):
        TargetSpread().per_vertex_cm()
