"""The garment's pixels in a picture of a person, found from colours seeded by keypoints:
on a drawn figure whose shirt and trousers are known, each is found and not the other."""

import numpy as np
import pytest

from tryon.errors import TryonError
from tryon.perceive.garment_mask import SEEDS, garment_mask, seed_labels
from tryon.perceive.person import K


def _figure(rng):
    """A 240 x 160 picture of a standing figure: head (skin), a shirt over the torso and
    upper arms, skin forearms, trousers on the legs; its mask, keypoints and true parts."""
    cv2 = pytest.importorskip("cv2")
    h, w = 240, 160
    parts = {name: np.zeros((h, w), np.uint8) for name in ("head", "shirt", "skin", "trousers", "shoes")}
    cv2.circle(parts["head"], (80, 30), 14, 1, -1)
    cv2.rectangle(parts["shirt"], (58, 48), (102, 120), 1, -1)        # torso
    cv2.line(parts["shirt"], (60, 52), (44, 85), 1, 12)               # upper arms
    cv2.line(parts["shirt"], (100, 52), (116, 85), 1, 12)
    cv2.line(parts["skin"], (44, 85), (36, 125), 1, 9)                # forearms
    cv2.line(parts["skin"], (116, 85), (124, 125), 1, 9)
    cv2.line(parts["trousers"], (70, 120), (68, 212), 1, 18)          # legs
    cv2.line(parts["trousers"], (90, 120), (92, 212), 1, 18)
    cv2.rectangle(parts["shoes"], (56, 216), (76, 230), 1, -1)
    cv2.rectangle(parts["shoes"], (84, 216), (104, 230), 1, -1)
    colours = {"head": (200, 160, 130), "skin": (200, 160, 130), "shirt": (40, 90, 200), "trousers": (60, 60, 60), "shoes": (150, 40, 40)}
    image = np.zeros((h, w, 3), np.float64) + (180, 200, 170)
    mask = np.zeros((h, w), bool)
    for name in ("trousers", "shoes", "shirt", "skin", "head"):
        on = parts[name] > 0
        image[on] = colours[name]
        mask |= on
    image = np.clip(image + rng.normal(0, 6, image.shape), 0, 255).astype(np.uint8)
    kp = np.zeros((33, 2))
    at = {"nose": (80, 32), "left_eye": (75, 27), "right_eye": (85, 27), "left_ear": (68, 30), "right_ear": (92, 30),
          "left_shoulder": (62, 52), "right_shoulder": (98, 52), "left_elbow": (44, 85), "right_elbow": (116, 85),
          "left_wrist": (36, 125), "right_wrist": (124, 125), "left_hip": (70, 118), "right_hip": (90, 118),
          "left_knee": (69, 170), "right_knee": (91, 170), "left_ankle": (68, 214), "right_ankle": (92, 214),
          "left_foot_index": (60, 226), "right_foot_index": (100, 226)}
    for name, p in at.items():
        kp[K[name]] = p
    shirt = (parts["shirt"] > 0) & (parts["skin"] == 0) & (parts["head"] == 0)
    trousers = (parts["trousers"] > 0) & ~shirt & (parts["skin"] == 0) & (parts["shoes"] == 0)
    return image, mask.astype(np.float32), kp, shirt, trousers


def _iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def test_the_shirt_and_the_trousers_are_each_found_and_not_the_other():
    image, mask, kp, shirt, trousers = _figure(np.random.default_rng(0))
    top = garment_mask(image, mask, kp, "tshirt")
    bottom = garment_mask(image, mask, kp, "trousers")
    assert _iou(top, shirt) > 0.85 and _iou(bottom, trousers) > 0.85
    assert (top & trousers).sum() < 0.05 * trousers.sum() and (bottom & shirt).sum() < 0.05 * shirt.sum()
    assert not (top & (mask < 0.5)).any()  # never outside the person


def test_seeds_mark_the_core_as_garment_and_the_head_as_not():
    cv2 = pytest.importorskip("cv2")
    _, mask, kp, shirt, _ = _figure(np.random.default_rng(1))
    for garment in SEEDS:
        labels = seed_labels(mask.shape, mask > 0.5, kp, garment)
        assert (labels == cv2.GC_FGD).any(), garment
        assert labels[30, 80] == cv2.GC_BGD, garment   # the head
        assert (labels[mask < 0.5] == cv2.GC_BGD).all(), garment
    labels = seed_labels(mask.shape, mask > 0.5, kp, "tshirt")
    assert labels[85, 80] == cv2.GC_FGD  # the middle of the torso


def test_no_person_means_no_garment_and_unknown_garments_are_named():
    image, mask, kp, _, _ = _figure(np.random.default_rng(2))
    assert not garment_mask(image, np.zeros_like(mask), kp, "tshirt").any()
    with pytest.raises(TryonError, match="hat"):
        garment_mask(image, mask, kp, "hat")


def test_a_frame_is_read_as_the_clip_datasets_store_it():
    from tryon.perceive.frame_features import GARMENT_CROP, frame_features
    from tryon.perceive.person import CROP, PersonInPhoto

    image, mask, kp, shirt, _ = _figure(np.random.default_rng(3))
    person = PersonInPhoto("frame", image, 1.0, mask, kp, np.ones(33), np.zeros((33, 3)))
    seen, crop = frame_features(image, person, "tshirt")
    assert seen["found"] and seen["mask_bits"].shape == (CROP * CROP // 8,)
    assert seen["found_garment_bits"].shape == (GARMENT_CROP * GARMENT_CROP // 8,)
    person_px = np.unpackbits(seen["mask_bits"]).sum() / CROP ** 2
    garment_px = np.unpackbits(seen["found_garment_bits"]).sum() / GARMENT_CROP ** 2
    assert 0.15 < garment_px / person_px < 0.6  # the shirt is part of the person
    inside = seen["keypoints"][seen["visibility"] > 0].astype(float)
    assert ((inside > 0) & (inside < 1)).all() and crop[2] > 200  # the crop holds the 240 px figure
    empty, _ = frame_features(image, None, "tshirt", box=(0, 0, 100, 200))
    assert not empty["found"] and not empty["mask_bits"].any() and not empty["keypoints"].any()
    with pytest.raises(ValueError, match="box"):
        frame_features(image, None, "tshirt")
