"""Each fabric preset's look in renders."""

import numpy as np

from tryon.fabric import load_fabric
from tryon.fabric.presets import list_presets
from tryon.render.appearance import APPEARANCES, DEFAULT, fabric_colors


def test_every_preset_has_its_own_look_and_prints_follow_the_material():
    assert set(APPEARANCES) >= set(list_presets())
    u, v = np.meshgrid(np.linspace(0, 0.3, 61), np.linspace(0, 0.3, 61))
    uv = np.c_[u.ravel(), v.ravel()]
    dots = fabric_colors("white-dots-on-blk", uv)
    white = dots.mean(1) > 0.9
    assert 0.1 < white.mean() < 0.4 and (dots.mean(1) < 0.1).mean() > 0.5
    assert not np.allclose(fabric_colors("gray-interlock", uv)[0], fabric_colors("tango-red-jet-set", uv)[0])
    assert np.allclose(fabric_colors("my_fabric.json", uv), DEFAULT)
    load_fabric("white-dots-on-blk")
