"""Fabric classes for fabric from video: bins placed by a sensitivity analysis, every
measured fabric in a class, fabrics drawn inside a class, and the tests' physics."""

import numpy as np
import pytest

from tryon.errors import FabricError
from tryon.fabric.wang2011 import MEASURED_FABRICS, WangFabric
from tryon.perceive.fabric_classes import BEND_BINS, STRETCH_BINS, FabricClasses, default_classes
from tryon.perceive.fabric_sensitivity import Response, deformation, equal_deformation_edges, measured_range, scaled_fabric


def test_the_shipped_classes_are_the_chapters_54_over_the_measured_fabrics():
    classes = default_classes()
    assert (classes.stretch_bins, classes.bend_bins, classes.count) == (STRETCH_BINS, BEND_BINS, 54)
    for axis, edges in (("stretching", classes.stretch_edges), ("bending", classes.bend_edges)):
        lo, hi = measured_range(axis)
        assert edges[0] == pytest.approx(lo) and edges[-1] == pytest.approx(hi)
    presets = classes.preset_classes()
    assert set(presets) == set(MEASURED_FABRICS) and all(0 <= c < 54 for c in presets.values())
    assert all(classes.inside(WangFabric.from_preset(n)) for n in MEASURED_FABRICS)
    # the denim is stiffer in both than the sweat fleece: not in a softer bin on either axis
    (sd, bd), (sn, bn) = classes.bins(presets["11oz-black-denim"]), classes.bins(presets["navy-sparkle-sweat"])
    assert sd >= sn and bd >= bn and (sd, bd) != (sn, bn)


def test_a_fabric_drawn_in_a_class_is_of_that_class_and_the_draw_repeats():
    classes = default_classes()
    for c in (0, 8, 27, 45, 53):
        rng = np.random.default_rng(c)
        fabric = classes.sample_fabric(c, rng)
        assert classes.class_of(fabric) == c, (c, classes.position(fabric), classes.box(c))
        again = classes.sample_fabric(c, np.random.default_rng(c))
        assert np.allclose(fabric.parameters().numpy(), again.parameters().numpy())
    # a draw keeps its base fabric's density: what the class does not fix still varies
    densities = {round(float(classes.sample_fabric(20, np.random.default_rng(s)).density), 4) for s in range(12)}
    assert len(densities) > 2


def test_a_class_centre_fabric_sits_at_the_centre_on_the_nearest_measured_base():
    classes = default_classes()
    for c in (0, 22, 53):
        centre = np.array(classes.centre(c))
        ranked = classes.nearest_measured(c, count=len(MEASURED_FABRICS))
        assert sorted(ranked) == sorted(MEASURED_FABRICS) and ranked[0] == classes.nearest_measured(c)
        spans = np.array([classes.stretch_edges[-1] - classes.stretch_edges[0],
                          classes.bend_edges[-1] - classes.bend_edges[0]])
        away = [np.linalg.norm((np.array(classes.position(WangFabric.from_preset(n))) - centre) / spans) for n in ranked]
        assert away == sorted(away)
        fabric = classes.centre_fabric(c)
        assert classes.position(fabric) == pytest.approx(tuple(centre), abs=1e-5) and classes.class_of(fabric) == c
        base = WangFabric.from_preset(ranked[0])
        assert float(fabric.density) == pytest.approx(float(base.density))  # what the class does not fix: the base's
        other = classes.centre_fabric(c, base="11oz-black-denim")
        assert classes.position(other) == pytest.approx(tuple(centre), abs=1e-5)
        assert float(other.density) == pytest.approx(float(WangFabric.from_preset("11oz-black-denim").density))


def test_fabrics_beyond_the_range_fall_in_the_outer_bins_and_bad_input_is_named():
    classes = FabricClasses((2.0, 2.5, 3.0), (-4.8, -4.3, -3.8))
    stiff = WangFabric.from_preset("paper")  # a stiff isotropic sheet, far beyond the cloth
    assert not classes.inside(stiff)
    assert classes.bins(classes.class_of(stiff))[0] == 1
    assert classes.distance(classes.index(0, 0), classes.index(1, 1)) == 1
    assert classes.distance(0, 0) == 0 and classes.name(classes.index(1, 0)) == "S2B1"
    with pytest.raises(FabricError, match="outside 0-3"):
        classes.bins(4)
    with pytest.raises(FabricError, match="must rise"):
        FabricClasses((2.0, 1.0), (-4.0, -3.0))
    with pytest.raises(FabricError, match="malformed"):
        FabricClasses.from_dict({"stretch_edges_log10_N_m": [1, 2]})


def test_edges_sit_at_equal_steps_of_deformation():
    s = np.linspace(2.0, 4.0, 9)
    # deformation falling by a factor 10^0.3 per decade of stiffness (the smoothing's own
    # form, so it is followed exactly): the edges are where it passes 100, 81.3, ... 25.1
    falling = Response("stretching", s.tolist(), (100.0 * 10.0 ** (-0.3 * (s - 2.0))).tolist(), 0.0)
    levels = np.linspace(100.0, 100.0 * 10.0 ** -0.6, 5)
    assert np.allclose(equal_deformation_edges(falling, 4), 2.0 + np.log10(100.0 / levels) / 0.3, atol=1e-6)
    # the stiffer, the less a step of stiffness shows: the stiff bins are wide
    assert np.all(np.diff(np.diff(equal_deformation_edges(falling, 4))) > 0)
    # a jump in the measured curve (a drape test's folds changing in number) neither crowds
    # the bins into it nor leaves one wide flat bin at the soft end
    jump = Response("bending", s.tolist(), [70, 69, 68, 67, 66, 65, 64, 50, 49], 0.0)
    widths = np.diff(equal_deformation_edges(jump, 4))
    assert widths.min() > 0.3 and widths.max() < 0.7
    with pytest.raises(ValueError, match="deforms the same"):
        equal_deformation_edges(Response("bending", s.tolist(), [5.0] * 9, 0.0), 3)


@pytest.mark.slow
def test_softer_fabric_deforms_more_in_both_tests():
    from tryon.fabric.presets import mean_preset_fabric

    base = mean_preset_fabric()
    for axis in ("stretching", "bending"):
        lo, hi = measured_range(axis)
        soft, stiff = (deformation(axis, scaled_fabric(base, axis, v)) for v in (lo, hi))
        assert soft > 1.1 * stiff > 0, (axis, soft, stiff)
