"""Golden states: short runs of the built-in scenes against stored results, to catch
unintended changes in the physics. Scenes that stay smooth over the compared steps
(hanging, table) must match to 0.1 mm at every kept frame; the contact-rich ones, whose
folds depend on round-off (sphere-drop, pyramid), are compared by robust statistics.

Regenerate after an intended change with TRYON_REGENERATE_GOLDEN=1 (and say why in the
commit)."""

import os
from pathlib import Path

import numpy as np
import pytest

from tryon.sim.runner import simulate
from tryon.sim.scene import example_scene

GOLDEN = Path(__file__).parent / "data" / "golden"
EXACT = {"hanging": (8, 0.5), "table": (8, 0.5)}
ROBUST = {"sphere-drop": (10, 0.6), "pyramid": (10, 0.6)}


def _run(name: str, resolution: int, duration: float) -> np.ndarray:
    return simulate(example_scene(name, resolution, duration=duration), progress=False).positions


def _golden(name: str, positions: np.ndarray) -> np.ndarray:
    path = GOLDEN / f"{name}.npz"
    if os.environ.get("TRYON_REGENERATE_GOLDEN") == "1":
        GOLDEN.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, positions=positions.astype(np.float64))
    return np.load(path)["positions"]


@pytest.mark.parametrize("name", sorted(EXACT))
def test_smooth_scenes_match_their_golden_frames(name):
    positions = _run(name, *EXACT[name])
    golden = _golden(name, positions)
    assert positions.shape == golden.shape
    assert np.abs(positions - golden).max() < 1e-4


def _statistics(x: np.ndarray) -> np.ndarray:
    """Centroid, spread and extent of the final cloth (m)."""
    return np.concatenate([x.mean(0), x.std(0), x.max(0) - x.min(0)])


@pytest.mark.parametrize("name", sorted(ROBUST))
def test_contact_scenes_keep_their_golden_statistics(name):
    positions = _run(name, *ROBUST[name])
    golden = _golden(name, positions)
    assert positions.shape == golden.shape
    assert np.abs(_statistics(positions[-1]) - _statistics(golden[-1])).max() < 0.01  # 1 cm
    mean_motion = np.linalg.norm(positions[-1] - positions[0], axis=1).mean()
    golden_motion = np.linalg.norm(golden[-1] - golden[0], axis=1).mean()
    assert abs(mean_motion - golden_motion) < 0.01
