"""The simulator refines a fabric's stretching from an observed motion: the bracketing
search on functions whose answer is known, and on a hanging cloth simulated in a fabric the
test chose."""

import math

import numpy as np
import pytest

from tryon.errors import FabricError, TryonError
from tryon.fabric.blend import fabric_features, scaled_stiffness
from tryon.fabric.presets import mean_preset_fabric
from tryon.fabric.wang2011 import MEASURED_FABRICS
from tryon.perceive.fabric_classes import default_classes
from tryon.perceive.refine_fabric import (GOLDEN_STEPS, GRID_POINTS, INVERSE_PHI, RESOLUTION_LOG10, golden_steps, misfit,
                                         refine_clip_fabric, search_scale)


def scaled_fabric(base, s, b):
    return scaled_stiffness(base, 10.0 ** s, 10.0 ** b)


def test_scaling_moves_the_stiffness_features_by_the_logs_of_the_factors():
    base = mean_preset_fabric()
    f0, f1 = fabric_features(base), fabric_features(scaled_fabric(base, 0.3, -0.5))
    assert f1[0] - f0[0] == pytest.approx(0.3, abs=1e-6) and f1[2] - f0[2] == pytest.approx(-0.5, abs=1e-6)
    assert f1[3] == pytest.approx(f0[3])  # density kept
    with pytest.raises(FabricError, match="positive"):
        scaled_stiffness(base, -1.0, 1.0)


def test_the_search_finds_the_bottom_of_a_rough_v_and_keeps_the_best_seen():
    rng = np.random.default_rng(3)
    bumps = rng.uniform(0, 0.02, 64)

    def misfit(x):  # a V at 0.37 with bumps up to a tenth of its rise over a grid step (0.25)
        return abs(x - 0.37) + bumps[int(abs(x) * 1000) % 64] * 1.25

    x, error, seen = search_scale(misfit, (0.0, 1.0))
    assert len(seen) == GRID_POINTS + GOLDEN_STEPS and x == pytest.approx(0.37, abs=0.06)
    assert error == min(e for _, e in seen) and (x, error) in seen
    assert [s for s, _ in seen[:GRID_POINTS]] == pytest.approx(np.linspace(0, 1, GRID_POINTS).tolist())
    # more golden steps narrow it further; the answer at a range's end is found there
    x, _, _ = search_scale(lambda x: abs(x - 0.37), (0.0, 1.0), golden=10)
    assert x == pytest.approx(0.37, abs=0.005)
    x, _, _ = search_scale(lambda x: abs(x - 2.0), (0.0, 1.0))
    assert x == 1.0


def test_failed_simulations_are_never_best_and_all_failing_is_named():
    x, error, seen = search_scale(lambda x: math.inf if x < 0.5 else x, (0.0, 1.0))
    assert x == pytest.approx(0.5, abs=0.01) and math.isfinite(error)
    with pytest.raises(TryonError, match="every simulation"):
        search_scale(lambda x: math.inf, (0.0, 1.0))
    with pytest.raises(TryonError, match="rises"):
        search_scale(lambda x: x, (1.0, 0.0))
    assert misfit(None, np.zeros((2, 3, 3)), 1.0) == math.inf
    assert misfit(np.full((2, 3, 3), np.nan), np.zeros((2, 3, 3)), 1.0) == math.inf
    observed = np.zeros((3, 2, 3))
    moved = observed.copy()
    moved[1:, :, 0] = 0.2  # frame 0 is where both start: only later frames count
    assert misfit(moved, observed, 2.0) == pytest.approx(0.1)


class FakeClip:
    """A clip whose misfit is known: a V in the stretching at `target`, lowest for one base."""

    def __init__(self, target, base, fail_below=None):
        self.target, self.base, self.fail_below, self.calls = target, base, fail_below, 0

    def misfit(self, fabric):
        self.calls += 1
        s = default_classes().position(fabric)[0]
        if self.fail_below is not None and s < self.fail_below:
            return math.inf
        return abs(s - self.target) + (0.0 if fabric.name.startswith(self.base + "-") else 0.05)


def test_the_refinement_picks_the_base_then_the_stretching_inside_the_class():
    classes = default_classes()
    c = classes.index(3, 4)
    (s0, s1), (b0, b1) = classes.box(c)
    target = s0 + 0.3 * (s1 - s0)
    clip = FakeClip(target, "tango-red-jet-set")
    r = refine_clip_fabric(clip, classes, c)
    assert r.base == "tango-red-jet-set" and set(r.base_errors) == set(MEASURED_FABRICS)
    assert r.stretch_log10 == pytest.approx(target, abs=0.1 * (s1 - s0))
    assert r.bend_log10 == pytest.approx((b0 + b1) / 2) and classes.class_of(r.fabric) == c
    # the centre is simulated once for each base and reused by the grid
    assert r.simulations == clip.calls == len(MEASURED_FABRICS) + GRID_POINTS - 1 + GOLDEN_STEPS
    assert r.error <= r.error_centre and len(r.notes) == 1 and "bending" in r.notes[0]
    # a fabric beyond the class: the search stops at its edge, inside it, and says so
    r = refine_clip_fabric(FakeClip(s1 + 0.5, "gray-interlock"), classes, c, bases=("gray-interlock", "paper"))
    assert r.stretch_log10 == pytest.approx(s1, abs=0.01 * (s1 - s0)) and classes.class_of(r.fabric) == c
    assert "neighbouring class" in r.notes[-1]


def test_wider_classes_get_more_golden_section_steps_until_the_bracket_is_narrow():
    classes = default_classes()
    for c in range(classes.count):
        (s0, s1), _ = classes.box(c)
        n = golden_steps(s1 - s0)
        bracket = 2 * (s1 - s0) / (GRID_POINTS - 1)
        assert n >= GOLDEN_STEPS and bracket * INVERSE_PHI ** (n - 1) <= max(RESOLUTION_LOG10, bracket * INVERSE_PHI ** 3)
        if n > GOLDEN_STEPS:  # no more than needed
            assert bracket * INVERSE_PHI ** (n - 2) > RESOLUTION_LOG10
    # the widest bin (almost a decade) is searched to the resolution too
    c = classes.index(5, 4)
    (s0, s1), _ = classes.box(c)
    target = s0 + 0.62 * (s1 - s0)
    clip = FakeClip(target, "gray-interlock")
    r = refine_clip_fabric(clip, classes, c, bases=("gray-interlock",))
    assert golden_steps(s1 - s0) > GOLDEN_STEPS and r.simulations == GRID_POINTS + golden_steps(s1 - s0)
    assert r.stretch_log10 == pytest.approx(target, abs=RESOLUTION_LOG10 / 2)


def test_the_refinement_keeps_the_centre_when_the_rest_fails_and_names_what_it_cannot_do():
    classes = default_classes()
    c = classes.index(2, 2)
    (s0, s1), _ = classes.box(c)
    centre = (s0 + s1) / 2
    # an even grid does not hold the centre: all its points fail (a step below the centre
    # fails and so does the grid), and the centre, which did not, is kept
    r = refine_clip_fabric(FakeClip(centre, "gray-interlock", fail_below=centre - 1e-6), classes, c,
                           bases=("gray-interlock",), grid=4, golden=0,
                           bounds=(s0, centre - 0.01 * (s1 - s0)))
    assert r.stretch_log10 == pytest.approx(centre) and r.error == r.error_centre
    with pytest.raises(TryonError, match="every simulation at the centre"):
        refine_clip_fabric(FakeClip(centre, "gray-interlock", fail_below=s1 + 1), classes, c, bases=("gray-interlock",))
    with pytest.raises(TryonError, match="at least one measured fabric"):
        refine_clip_fabric(FakeClip(centre, "x"), classes, c, bases=())
    with pytest.raises(TryonError, match="at least 2 grid points"):
        refine_clip_fabric(FakeClip(centre, "x"), classes, c, grid=1)


@pytest.mark.slow
def test_the_stretching_of_a_hanging_cloth_is_recovered_from_its_motion():
    from tryon.sim.runner import simulate
    from tryon.sim.scene import example_scene

    base = mean_preset_fabric()

    def run(s):
        scene = example_scene("hanging", 8, fabric=scaled_fabric(base, s, 0.0).to_arcsim_dict(), duration=0.6,
                              frame_time=0.1, wind={"velocity": [0.0, 0.0, 0.0], "density": 1.0, "drag": 0.0})
        return np.asarray(simulate(scene, progress=False).positions, np.float64)

    truth = -1.2  # a soft fabric: it stretches visibly as it falls
    observed = run(truth)
    size = float(np.linalg.norm(observed[0].max(0) - observed[0].min(0)))
    # the range is two decades: a grid step of half a decade, narrowed by golden section
    s, error, seen = search_scale(lambda s: misfit(run(s), observed, size), (-2.0, 0.0), golden=7)
    assert abs(s - truth) < 0.05, seen  # within 12 % of the stiffness
    assert error < 0.5 * min(e for _, e in seen[:GRID_POINTS])
