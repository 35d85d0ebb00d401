"""The KDSM models that ship in the package (T-shirt M on the female fit model): they load
on a fresh install, their cards hold the data and per-split errors, they predict a pose
fast, and `tryon animate --method kdsm` uses the hybrid one by default."""

import json

import numpy as np
import pytest

from tryon.kdsm.model import MODELS_DIR, KdsmModel, shipped_model_path

pytestmark = [pytest.mark.anny]


def test_the_shipped_models_load_and_carry_their_cards():
    paths = sorted(MODELS_DIR.glob("*.npz"))
    assert shipped_model_path("kdsm-hybrid") in paths and shipped_model_path("jin-uvn") in paths
    for p in paths:
        assert p.stat().st_size < 10e6
        model = KdsmModel.load(p)
        card = model.card
        assert card["manifest"]["kind"] == "poses" and card["manifest"]["spec"]["size"] == "M"
        for split in ("train", "val", "test"):
            assert card["metrics"][split]["frames"] >= 100 and np.isfinite(card["metrics"][split]["mean_error_cm"])
        x = model.predict(np.zeros((len(model.rig.shape.bone_labels), 3)))
        assert x.shape == model.rig.x0.shape and np.isfinite(x).all()


@pytest.mark.slow
def test_animate_kdsm_defaults_to_the_shipped_hybrid(tmp_path):
    from tryon.cli import main

    drape = tmp_path / "d"
    assert main(["drape", "--height-cm", "168", "--weight-kg", "64", "--gender", "female", "--size", "M", "--edge-length",
                 "0.015", "--out", str(drape), "--quiet"]) == 0
    assert main(["animate", str(drape), "--motion", "walk", "--duration", "0.4", "--method", "kdsm", "--quiet"]) == 0
    rep = json.loads((drape / "animation-walk" / "report.json").read_text())
    assert rep["method"] == "kdsm (kdsm-hybrid)" and rep["frames"] == 13 and rep["max_penetration_pct"] < 5.0
