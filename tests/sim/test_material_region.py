"""Material regions (a print, a patch): the cloth is heavier and stiffer where they lie,
in the mass, the forces, the energies the drape report measures, and the gradient tape."""

import numpy as np
import pytest
import torch

from tryon.drape.fit_metrics import potential_energy
from tryon.errors import SceneError
from tryon.fabric import load_fabric
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.loop import run
from tryon.sim.mesh import grid_mesh
from tryon.sim.model import ClothModel, MaterialRegion, PinGroup

FABRIC = load_fabric("gray-interlock")
DENIM = load_fabric("11oz-black-denim")


def _model(regions=None, res=(8, 4), pins=None):
    mesh = grid_mesh(res, (0.4, 0.2))
    return ClothModel(mesh, FABRIC, regions=regions, pins=pins)


def test_a_region_adds_its_areal_density_to_the_mass():
    plain = _model()
    faces = np.arange(0, plain.faces.shape[0], 3)
    printed = _model([MaterialRegion(faces, added_density=0.15)])
    added = float((printed.mass() - plain.mass()).sum())
    area = float(plain.rest_area[faces].sum())
    assert added == pytest.approx(0.15 * area, rel=1e-12)
    assert float(printed.mass().sum()) == pytest.approx(float(FABRIC.density) * float(plain.rest_area.sum()) + added)


def test_stiffness_multipliers_scale_the_energies_where_the_region_lies():
    plain = _model()
    everywhere = np.arange(plain.faces.shape[0])
    stiff = _model([MaterialRegion(everywhere, stretch_scale=3.0, bend_scale=10.0)])
    rng = np.random.default_rng(0)
    x = plain.mesh.x.numpy() + 0.01 * rng.standard_normal(plain.mesh.x.shape)
    e0, e1 = potential_energy(plain, x), potential_energy(stiff, x)
    assert e1["membrane_J"] == pytest.approx(3.0 * e0["membrane_J"], rel=1e-10)
    assert e1["bending_J"] == pytest.approx(10.0 * e0["bending_J"], rel=1e-10)
    half = _model([MaterialRegion(everywhere[: len(everywhere) // 2], bend_scale=10.0)])
    assert e0["bending_J"] < potential_energy(half, x)["bending_J"] < e1["bending_J"]
    # a hinge between a printed and a plain face takes the mean of the two
    h = half.hinge_faces.numpy()
    inside = h < len(everywhere) // 2
    expect = np.where(inside.all(1), 10.0, np.where(inside.any(1), 5.5, 1.0))
    assert np.allclose(half.hinge_bend_scale.numpy(), expect)


def test_overlapping_regions_multiply_stiffness_and_add_density():
    plain = _model()
    f = np.arange(4)
    both = _model([MaterialRegion(f, 2.0, 3.0, 0.1), MaterialRegion(f, 4.0, 5.0, 0.2)])
    assert np.allclose(both.face_stretch_scale.numpy()[:4], 8.0)
    assert float((both.mass() - plain.mass()).sum()) == pytest.approx(0.3 * float(plain.rest_area[f].sum()))


@pytest.mark.parametrize("region, words", [
    (MaterialRegion(np.array([10_000])), "face indices"),
    (MaterialRegion(np.array([0]), stretch_scale=-1.0), "stretch_scale"),
    (MaterialRegion(np.array([0]), bend_scale=float("nan")), "bend_scale"),
    (MaterialRegion(np.array([0]), added_density=-0.1), "added_density"),
])
def test_bad_regions_are_refused_by_name(region, words):
    with pytest.raises(SceneError, match=words):
        _model([region])


def _tip_drop(regions_for) -> float:
    """A denim strip 10 cm long clamped along one short side (two rows of vertices),
    drooping under gravity: how far its free end has fallen after 1 s (m)."""
    mesh = grid_mesh((12, 3), (0.1, 0.025))
    x = mesh.x.numpy()
    clamp = torch.from_numpy(np.flatnonzero(x[:, 0] < 1.5 * 0.1 / 11))
    model = ClothModel(mesh, DENIM, pins=[PinGroup(clamp)], regions=regions_for(mesh))
    state = run(ImplicitEulerSolver(model), model.initial_state(), 0.01, until=100).state
    tip = x[:, 0] > 0.1 - 1e-9
    return float(-(state.x.numpy()[tip, 2] - x[tip, 2]).mean())


def test_a_stiffer_region_droops_less_and_a_heavier_one_more():
    every = lambda mesh: np.arange(mesh.faces.shape[0])  # noqa: E731
    plain = _tip_drop(lambda mesh: None)
    stiff = _tip_drop(lambda mesh: [MaterialRegion(every(mesh), bend_scale=30.0)])
    heavy = _tip_drop(lambda mesh: [MaterialRegion(every(mesh), bend_scale=30.0, added_density=0.3)])
    assert plain > 0.08            # hangs down from the clamp
    assert stiff < 0.7 * plain     # holds itself out
    assert heavy > 1.1 * stiff     # and sags under the ink's weight
