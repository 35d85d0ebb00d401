"""The optional in-process Newton comparison of `tryon bench sim` (tryon.bench.newton_ref).

Newton is not installed in the project's environment (nor in CI): there the tests check the
error that tells the user how to install it. The real run is skipped unless Newton is
importable; run it in an environment with `pip install newton==1.8.0 warp-lang==1.19.0`.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from tryon.bench.newton_ref import (
    gray_interlock_newton_params,
    hanging_grid,
    max_edge_stretch,
    newton_available,
    run_newton_hanging,
)
from tryon.errors import SceneError, TryonError
from tryon.sim.mesh import grid_corner, grid_mesh

HAS_NEWTON = newton_available()


def test_available_matches_importability():
    importable = importlib.util.find_spec("newton") is not None and importlib.util.find_spec("warp") is not None
    assert newton_available() is importable


@pytest.mark.skipif(HAS_NEWTON, reason="newton is installed here; the missing-package error cannot occur")
def test_missing_newton_raises_with_install_hint():
    assert newton_available() is False
    with pytest.raises(TryonError, match=r"pip install newton==1\.8\.0 warp-lang==1\.19\.0"):
        run_newton_hanging(16, 3)


@pytest.mark.parametrize(
    "kwargs",
    [{"grid": 1, "frames": 3}, {"grid": 16, "frames": 0}, {"grid": 16, "frames": 3, "solver": "xpbd"}],
)
def test_bad_arguments_raise_scene_error(kwargs):
    with pytest.raises(SceneError):
        run_newton_hanging(**kwargs)


def test_grid_matches_tryon_hanging_layout():
    x, uv, faces, pins = hanging_grid(5)
    mesh = grid_mesh((5, 5), (1.0, 1.0), (-0.5, -0.5, 1.5))
    np.testing.assert_allclose(x, mesh.x.numpy())
    np.testing.assert_allclose(uv, mesh.uv.numpy())
    np.testing.assert_array_equal(faces, mesh.faces.numpy())
    assert pins == [grid_corner((5, 5), "top-left"), grid_corner((5, 5), "top-right")]
    assert np.allclose(x[pins, 1], 0.5) and np.allclose(x[:, 2], 1.5)


def test_max_edge_stretch():
    x, _, faces, _ = hanging_grid(4)
    assert max_edge_stretch(x, x, faces) == pytest.approx(1.0)
    stretched = x.copy()
    stretched[:, 0] *= 1.2  # edges along x grow by 20 %, diagonals by less
    assert max_edge_stretch(stretched, x, faces) == pytest.approx(1.2)


def test_gray_interlock_mapping():
    p = gray_interlock_newton_params(16)
    # ARCSim doubles the zero-strain row of gray-interlock.json: k0 = 2 * 16.59, k2 = 2 * 34.48, k3 = 2 * 36.86
    np.testing.assert_allclose(p["style3d_tri_aniso_ke"], (33.187664, 68.954246, 36.860302))
    assert p["density_kg_m2"] == pytest.approx(0.187)
    # VBD: lambda = k1 = 0 (gray-interlock's negative coupling is clamped), mu = mean of k0/2, k2/2, k3/2
    assert p["vbd_tri_ka"] == 0.0
    assert p["vbd_tri_ke"] == pytest.approx((33.187664 + 68.954246 + 73.720604) / 6.0)
    # Bergou bending k = ARCSim ke / 12; Style3D's order is (edge along v, edge along u, diagonal)
    np.testing.assert_allclose(p["style3d_edge_aniso_ke"], np.array([1.4267624e-05, 2.3191698e-05, 2.4749964e-05]) / 12)
    # ke / (4 h) with h = 1/15: a finer grid gets a proportionally larger per-length stiffness
    assert gray_interlock_newton_params(31)["vbd_edge_ke"] / p["vbd_edge_ke"] == pytest.approx(2.0)


@pytest.mark.skipif(not HAS_NEWTON, reason="optional newton package not installed")
def test_newton_style3d_hanging_runs():
    r = run_newton_hanging(16, 3, solver="style3d")
    assert r["finite"]
    assert r["max_stretch"] < 1.5
    assert r["s_per_frame"] > 0.0 and r["s_per_frame_median"] > 0.0
    assert r["vertices"] == 256 and r["frames"] == 3 and r["wind"] is False
    assert r["newton_version"].startswith("1.") and r["warp_version"]
