"""The simulator refines a fabric's two stiffness scales from an observed motion: on a
function whose answer is known, and on a hanging cloth simulated in a fabric the test
chose, from a start a class away."""

import numpy as np
import pytest

from tryon.errors import FabricError, TryonError
from tryon.fabric.blend import fabric_features, scaled_stiffness
from tryon.fabric.presets import mean_preset_fabric
from tryon.perceive.refine_fabric import refine_scales


def scaled_fabric(base, s, b):
    return scaled_stiffness(base, 10.0 ** s, 10.0 ** b)


def test_scaling_moves_the_stiffness_features_by_the_logs_of_the_factors():
    base = mean_preset_fabric()
    f0, f1 = fabric_features(base), fabric_features(scaled_fabric(base, 0.3, -0.5))
    assert f1[0] - f0[0] == pytest.approx(0.3, abs=1e-6) and f1[2] - f0[2] == pytest.approx(-0.5, abs=1e-6)
    assert f1[3] == pytest.approx(f0[3])  # density kept
    with pytest.raises(FabricError, match="positive"):
        scaled_stiffness(base, -1.0, 1.0)


def test_levenberg_marquardt_finds_the_scales_of_a_smooth_response():
    # "frames" whose points move with both scales, one more strongly than the other
    grid = np.linspace(0, 1, 20)

    def simulate(s, b):
        return np.stack([np.stack([grid, np.exp(-0.5 * s) * grid * k / 3, 0.2 * np.tanh(b) * grid ** 2 * k], -1)
                         for k in range(4)])

    observed = simulate(0.25, -0.4)
    theta, error, history = refine_scales(simulate, observed, start=(-0.2, 0.1), bounds=((-1, 1), (-1, 1)),
                                          iterations=8)
    assert theta == pytest.approx([0.25, -0.4], abs=0.01)
    assert error < 0.01 * history[0]["error"] and error == pytest.approx(min(h["error"] for h in history))
    # bounds hold: the answer outside them stops at the edge
    theta, _, _ = refine_scales(simulate, observed, start=(-0.2, 0.1), bounds=((-1, 0.1), (-1, 1)), iterations=8)
    assert theta[0] == pytest.approx(0.1)


def test_a_failing_start_is_named():
    from tryon.errors import SimulationError

    def broken(s, b):
        raise SimulationError("flung")

    with pytest.raises(TryonError, match="fails at the start"):
        refine_scales(broken, np.ones((3, 4, 3)) * np.arange(4)[:, None], (0.0, 0.0), ((-1, 1), (-1, 1)))
    with pytest.raises(TryonError, match="no extent"):
        refine_scales(broken, np.zeros((3, 4, 3)), (0.0, 0.0), ((-1, 1), (-1, 1)))
    with pytest.raises(TryonError, match="at least 2 frames"):
        refine_scales(broken, np.ones((1, 4, 3)), (0.0, 0.0), ((-1, 1), (-1, 1)))


@pytest.mark.slow
def test_the_stretching_of_a_hanging_cloth_is_recovered_from_its_motion():
    from tryon.sim.runner import simulate
    from tryon.sim.scene import example_scene

    base = mean_preset_fabric()

    def run(s, b):
        scene = example_scene("hanging", 8, fabric=scaled_fabric(base, s, b).to_arcsim_dict(), duration=0.6,
                              frame_time=0.1, wind={"velocity": [0.0, 0.0, 0.0], "density": 1.0, "drag": 0.0})
        return simulate(scene, progress=False).positions

    truth = (-1.2, 0.0)  # a soft fabric: it stretches visibly as it falls
    observed = run(*truth)
    theta, error, history = refine_scales(run, observed, start=(-0.9, 0.0), bounds=((-2.0, 0.5), (-0.5, 0.5)),
                                          iterations=4)
    assert abs(theta[0] - truth[0]) < 0.05, theta  # within 12 % of the stiffness
    assert error < 0.2 * history[0]["error"]
