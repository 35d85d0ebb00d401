"""The KDSM models that ship in the package (T-shirt M on the female fit model): they load
on a fresh install, their cards hold the data and per-split errors, they predict a pose
in their own rig."""

import numpy as np
import pytest

from tryon.kdsm.model import MODELS_DIR, KdsmModel, shipped_model_path
from tryon.kdsm.train import card_markdown

pytestmark = [pytest.mark.anny]


def test_the_shipped_models_load_and_carry_their_cards():
    paths = sorted(MODELS_DIR.glob("*.npz"))
    assert shipped_model_path("kdsm-hybrid") in paths and shipped_model_path("jin-uvn") in paths
    assert shipped_model_path("kdsm-hybrid", from_rest=True) in paths
    for p in paths:
        assert p.stat().st_size < 10e6
        model = KdsmModel.load(p)
        card = model.card
        assert card["manifest"]["kind"] == "poses" and card["manifest"]["spec"]["size"] == "M"
        for split in ("train", "val", "test"):
            assert card["metrics"][split]["frames"] >= 100 and np.isfinite(card["metrics"][split]["mean_error_cm"])
        x = model.predict(np.zeros((len(model.rig.shape.bone_labels), 3)))
        assert x.shape == model.rig.x0.shape and np.isfinite(x).all()
        # the readable card beside it says what the model's own card holds (settings it predates read as they were then)
        assert p.with_suffix(".md").read_text() == card_markdown(card)
        from_rest = card["manifest"]["spec"].get("from_rest", False)
        assert p.stem.endswith("-from-rest") == from_rest   # each pose simulated from the rest drape, or carried
        if model.method == "kdsm-hybrid" and not from_rest:
            assert model.smoothing == 1.0 and "smoothed with strength 1," in card_markdown(card)
