"""The photo dataset for the body from photos: people drawn from the ANSUR II prior,
photographed from several sides, with what BlazePose sees in each picture."""

import numpy as np
import pytest

from tryon.dataset.bodies import BodyRanges


def test_drawn_people_vary_at_a_given_stature_and_weight_as_the_prior_says():
    from tryon.dataset.photos import DRAWN, draw_person

    ranges = BodyRanges(genders=("female",), bmi=(24.0, 24.0 + 1e-6), height_cm={"female": (165.0, 165.0 + 1e-6)})
    people = [draw_person(0, i, ranges) for i in range(300)]
    assert {p.gender for p in people} == {"female"}
    hips = np.array([p.asked["hip_cm"] for p in people])
    assert 0.02 < hips.std() / hips.mean() < 0.06  # real people: 2-4 %, not Anny's phenotypes' < 1 %
    again = draw_person(0, 7, ranges)
    assert again.asked == people[7].asked and set(again.asked) == set(DRAWN)


@pytest.mark.slow
@pytest.mark.anny
def test_a_sample_holds_masks_keypoints_and_the_true_body(tmp_path):
    from tryon.dataset.photos import CROP, PhotoDatasetSpec, make_photo_dataset
    from tryon.dataset.store import Manifest, ShardStore
    from tryon.perceive.person import K

    spec = PhotoDatasetSpec(count=1, seed=3, views=("front", "left"), shard_size=1)
    store, report = make_photo_dataset(spec, tmp_path / "photos", progress=False)
    assert report.made == 1 and report.failed == 0
    s = ShardStore(store.folder, Manifest.read(store.folder)).load()
    assert s["view_found"].shape == (1, 2) and s["view_found"].all()
    mask = np.unpackbits(s["view_mask_bits"][0, 0]).reshape(CROP, CROP).astype(bool)
    true = np.unpackbits(s["view_true_mask_bits"][0, 0]).reshape(64, 64).astype(bool)
    coarse = mask.reshape(64, 2, 64, 2).mean((1, 3)) > 0.5
    assert (coarse & true).sum() / (coarse | true).sum() > 0.75  # BlazePose's mask against the render's
    # BlazePose's shoulders and hips where the body's joints project (crop units, front view)
    kp, joints = s["view_keypoints"][0, 0].astype(float), s["view_joints_2d"][0, 0]
    names = list(store.manifest.spec["joints"])
    for bp, joint in (("left_shoulder", "upperarm01.L"), ("right_hip", "upperleg01.R"), ("left_knee", "lowerleg01.L")):
        assert np.linalg.norm(kp[K[bp]] - joints[names.index(joint)]) < 0.06, bp
    tapes = dict(zip(store.manifest.spec["tapes"], s["tapes_cm"][0]))
    assert abs(tapes["height"] - s["height_cm"][0]) < 1.5
