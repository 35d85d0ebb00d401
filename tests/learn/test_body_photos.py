"""The body-from-photos regression: any number of views through one network, and a tiny
training run on a photo dataset that resumes and writes a model and its card."""

import json

import numpy as np
import torch

from tryon.learn.body_photos import PROFILE, BodyFromViews, RegressorConfig, load_model, silhouette_profile


def test_any_number_of_views_goes_through_the_same_network():
    torch.manual_seed(0)
    net = BodyFromViews(RegressorConfig(crop=32, measurements=4, shape=3, joints=5)).eval()
    mask, kp, cond = torch.rand(2, 3, 1, 32, 32), torch.rand(2, 3, 33, 3), torch.rand(2, 4)
    prof = torch.rand(2, 3, PROFILE)
    with torch.no_grad():
        one = net(mask[:, :1], kp[:, :1], prof[:, :1], torch.ones(2, 1), cond)["residual"]
        padded = net(mask, kp, prof, torch.tensor([[1.0, 0, 0], [1.0, 0, 0]]), cond)["residual"]
        three = net(mask, kp, prof, torch.ones(2, 3), cond)["residual"]
    assert torch.allclose(one, padded, atol=1e-6)  # absent views change nothing
    assert not torch.allclose(one, three)           # present ones add their corrections
    assert one.shape == (2, 4)


def _fake_photo_dataset(folder, people=24, views=("front", "left"), crop=32):
    """A photo dataset whose hip shows in the mask: a box whose width is the hip residual."""
    from tryon.dataset.photos import KIND
    from tryon.dataset.store import Manifest, ShardStore

    spec = {"views": list(views), "crop_px": crop, "tapes": ["chest", "waist_navel", "hip", "thigh", "neck"],
            "joints": ["a", "b"]}
    manifest = Manifest(KIND, 1, "test", 0, people, people, spec, {"rule": "test"}, created="now")
    folder.mkdir(parents=True)
    store = ShardStore(folder, manifest)
    store.write_manifest()
    rng = np.random.default_rng(0)
    for u in range(people):
        h, w, g = rng.uniform(155, 195), rng.uniform(50, 110), float(u % 2)
        wide = rng.uniform(-1, 1)
        tapes = np.array([100 * w / 75, 90 * w / 75, (100 + 8 * wide) * (w / 75) ** 0.5, 55 * (w / 75) ** 0.5,
                          38 * (w / 75) ** 0.3]) * np.exp(rng.normal(0.0, [0.03, 0.03, 0.003, 0.03, 0.03]))
        masks = np.zeros((len(views), crop, crop), bool)
        half = int(crop / 4 + wide * crop / 8)
        masks[:, 4:-4, crop // 2 - half:crop // 2 + half] = True
        store.put(u, {"ok": np.asarray(True), "gender": np.asarray(int(g)), "age": np.float32(30.0), "height_cm": np.float32(h),
                      "weight_kg": np.float32(w), "tapes_cm": tapes.astype(np.float32),
                      "shape_params": rng.normal(size=4).astype(np.float64),
                      "joints_3d": rng.normal(size=(2, 3)).astype(np.float32) * 0.1,
                      "split": np.asarray("train" if u < people - 4 else "test"),
                      "view_found": np.ones(len(views), bool),
                      "view_mask_bits": np.packbits(masks.reshape(len(views), -1), axis=-1),
                      "view_keypoints": np.stack([np.full((len(views), 33), 0.5), rng.uniform(0.2, 0.8, (len(views), 33))],
                                                 -1).astype(np.float16),
                      "view_visibility": np.ones((len(views), 33), np.float16),
                      "view_joints_2d": rng.uniform(0, 1, (len(views), 2, 2)).astype(np.float32)})
    return folder


def test_the_silhouette_profile_reads_widths_over_height():
    C = 64
    masks = np.zeros((2, C, C), bool)
    masks[0, 8:56, 22:42] = True   # a 20 px wide, 48 px tall box
    masks[1, 8:56, 12:52] = True   # twice as wide
    masks[1, 30:40, 20:44] = False  # a hole the torso line falls in: no run there
    kp = np.zeros((2, 33, 2))
    kp[..., 0] = 32.0 / C
    kp[:, [11, 12], 1], kp[:, [23, 24], 1], kp[:, [25, 26], 1] = 16 / C, 36 / C, 50 / C
    prof = silhouette_profile(masks, kp)
    assert prof.shape == (2, PROFILE)
    assert np.allclose(prof[0], 20 / 48)
    assert np.allclose(prof[1, :4], 40 / 48) and (prof[1] == 0).any()
    assert np.all(silhouette_profile(np.zeros((1, C, C)), kp[:1]) == 0)  # an empty view reads nothing


def test_a_tiny_training_run_learns_resumes_and_writes_its_card(tmp_path):
    from tryon.learn.train_body_photos import BodyTrainConfig, train_body_photos

    data = _fake_photo_dataset(tmp_path / "photos")
    cfg = BodyTrainConfig(epochs=40, batch=8, lr=1e-3, no_weight_fraction=0.0)  # the fake weights say nothing
    train_body_photos(data, tmp_path / "model", cfg, progress=False, max_epochs_this_run=2)
    state = torch.load(tmp_path / "model" / "checkpoint.pt", weights_only=True)
    assert json.loads(state["state"])["epoch"] == 2
    path = train_body_photos(data, tmp_path / "model", cfg, progress=False)   # resumes to 40
    card = load_model(path).card
    assert len(card["history"]) == 40 and card["split"]["test"] == 4
    first, last = card["history"][0]["mse"], card["history"][-1]["mse"]
    assert last < 0.7 * first   # it learns the hip from the mask...
    hip = {k: v["per_measurement_pct"]["hip"] for k, v in card["test"].items() if k != "people"}
    assert hip["views-2"] < 0.85 * hip["height-weight"]  # ...better than stature and weight tell it
    assert (tmp_path / "model" / "MODEL_CARD.md").read_text().startswith("# Body from photos")
