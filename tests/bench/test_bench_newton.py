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
    wang_stiffness_at,
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


def test_wang_stiffness_samples():
    # zero strain: row 0 of gray-interlock.json doubled, the negative coupling clamped to 0
    np.testing.assert_allclose(wang_stiffness_at(0.0), (33.187664, 0.0, 68.954246, 73.720604))
    # at and beyond 1/6 strain: the 0, 90, 90 and 45 degree rows (rows 1, 5, 5, 3) doubled
    at_sixth = (92.72953, 171.697174, 811.745666, 88.435142)
    np.testing.assert_allclose(wang_stiffness_at(1.0 / 6.0), at_sixth)
    np.testing.assert_allclose(wang_stiffness_at(0.5), at_sixth)
    # linear in between
    mid = 0.5 * (np.array(wang_stiffness_at(0.0)) + np.array(at_sixth))
    np.testing.assert_allclose(np.array(wang_stiffness_at(1.0 / 12.0))[[0, 2, 3]], mid[[0, 2, 3]])


def test_gray_interlock_mapping():
    p = gray_interlock_newton_params(16)
    k0, k1, k2, k3 = wang_stiffness_at(0.02)
    assert p["operating_strain"] == 0.02
    assert k2 == pytest.approx(2.0 * (34.477123 + 0.12 * (405.872833 - 34.477123)))
    np.testing.assert_allclose(p["style3d_tri_aniso_ke"], (k0, k2, 0.5 * k3))
    assert p["density_kg_m2"] == pytest.approx(0.187)
    # VBD: lambda = k1 (clamped to 0 at 2 %), mu = mean of k0/2, k2/2, k3/2
    assert k1 == 0.0 and p["vbd_tri_ka"] == 0.0
    assert p["vbd_tri_ke"] == pytest.approx((k0 + k2 + k3) / 6.0)
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
