"""The fabric class from clips on tiny synthetic clips: what tells the classes apart is how
fast the garment swings, which a single frame cannot show and the frames together can."""

import numpy as np
import pytest
import torch

from tryon.errors import TryonError
from tryon.learn.fabric_video import METHODS, ClipTensors, FabricFromClip, frame_masks, method_parts
from tryon.learn.train_fabric_video import ClassifierTrainConfig, load_classifier, train_classifier

T, CODE = 8, 16


def _clips(n: int = 72, seed: int = 0) -> ClipTensors:
    """Class k swings at (k + 1) cycles per clip, from a random phase: a bar across the mask
    and the code's first numbers follow the swing."""
    rng = np.random.default_rng(seed)
    label = np.arange(n) % 3
    t = np.arange(T) / T
    masks = np.zeros((n, T, 2, 64, 64), np.uint8)
    codes = rng.normal(0, 0.05, (n, T, CODE)).astype(np.float32)
    for i, k in enumerate(label):
        swing = np.sin(2 * np.pi * (k + 1) * t + rng.uniform(0, 2 * np.pi))
        for f, s in enumerate(swing):
            x = int(32 + 20 * s)
            masks[i, f, 0, 20:50, x - 3:x + 3] = 1  # the person
            masks[i, f, 1, 30:50, x - 3:x + 3] = 1  # the garment on them
        codes[i, :, 0] += swing
    keypoints = rng.random((n, T, 99)).astype(np.float32)
    split = np.where(np.arange(n) < n - 18, "train", np.where(np.arange(n) < n - 9, "val", "test"))
    return ClipTensors(masks, keypoints, codes, label, split, np.array(["skirt"] * n))


def test_methods_name_what_the_network_sees():
    assert len(METHODS) == 6
    assert method_parts("image-only-frame") == (True, False, False)
    assert method_parts("garment-only-temporal") == (False, True, True)
    with pytest.raises(TryonError, match="unknown method"):
        method_parts("audio-temporal")
    model = FabricFromClip("image+garment-temporal", classes=54, code=CODE)
    clips = _clips(4)
    out = model(torch.from_numpy(clips.masks), torch.from_numpy(clips.keypoints), torch.from_numpy(clips.codes))
    assert out.shape == (4, 54)


def test_a_clips_packed_masks_become_the_person_halved_and_the_garment():
    person = np.zeros((3, 128, 128), bool)
    person[:, 10:100, 40:60] = True
    person[1, 0, 0] = True  # one pixel survives halving by maxima
    garment = np.zeros((3, 64, 64), bool)
    garment[:, 20:40, 22:28] = True
    m = frame_masks(np.packbits(person.reshape(3, -1), axis=-1), np.packbits(garment.reshape(3, -1), axis=-1))
    assert m.shape == (3, 2, 64, 64) and m.dtype == np.uint8
    assert m[0, 0].sum() == 45 * 10 and m[1, 0, 0, 0] == 1 and m[0, 0, 0, 0] == 0
    assert (m[:, 1] == garment).all()


@pytest.mark.slow
def test_the_temporal_classifier_learns_how_fast_the_garment_swings_and_resumes(tmp_path):
    clips = _clips()
    cfg = ClassifierTrainConfig(epochs=40, batch=8, lr=3e-3)
    card = train_classifier(clips, tmp_path / "g", "garment-only-temporal", cfg, classes=3, progress=False)
    assert card["test"]["top1"] >= 0.75 and card["test"]["top3"] == 1.0
    assert card["chance_top1"] == pytest.approx(1 / 3)
    model, saved = load_classifier(tmp_path / "g" / "fabric-video.npz")
    assert saved["test"] == card["test"] and model.method == "garment-only-temporal"
    # the image path learns from the masks alone (54 clips are too few for its network to
    # generalise: it fits them)
    image = train_classifier(clips, tmp_path / "i", "image-only-temporal", ClassifierTrainConfig(epochs=30, batch=8,
                             lr=1e-3), classes=3, progress=False)
    assert image["history"][-1]["train_loss"] < 0.3 * image["history"][0]["train_loss"]
    # stopped and resumed: the run straight through, epoch by epoch
    train_classifier(clips, tmp_path / "r", "garment-only-temporal", ClassifierTrainConfig(epochs=25, batch=8, lr=3e-3),
                     classes=3, progress=False)
    resumed = train_classifier(clips, tmp_path / "r", "garment-only-temporal", cfg, classes=3, progress=False)
    assert np.allclose([h["train_loss"] for h in resumed["history"]], [h["train_loss"] for h in card["history"]],
                       rtol=1e-4)


def test_train_command_names_a_bad_method_before_any_work(tmp_path, capsys):
    from tryon.cli import main

    assert main(["train", "fabric-video", "--data", str(tmp_path), "--method", "audio", "--out", str(tmp_path / "m")]) == 2
    assert "unknown method 'audio'" in capsys.readouterr().err
    assert not (tmp_path / "m").exists()
