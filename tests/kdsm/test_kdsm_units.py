"""Small pieces of the KDSM that need no body: picking one parent per point."""

import numpy as np

from tryon.kdsm.embed import _best_per_point


def test_one_pick_per_point_the_best_scoring():
    assert len(_best_per_point(np.zeros(0, np.int64), np.zeros(0))) == 0
    point = np.array([2, 1, 2, 1, 5])
    score = np.array([0.1, 0.5, 0.3, 0.2, -1.0])
    pick = _best_per_point(point, score)
    assert dict(zip(point[pick].tolist(), score[pick].tolist())) == {1: 0.5, 2: 0.3, 5: -1.0}
