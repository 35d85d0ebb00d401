"""Clip datasets for fabric from video, tiny: a garment of a drawn fabric class follows a
moving body; the clip holds the frames after the blend, the class and the motion drawn."""

import numpy as np
import pytest

from tryon.body.motion import load_motion
from tryon.cli import main
from tryon.dataset import BodyRanges
from tryon.dataset.clips import (
    ClipDatasetSpec, clip_fabric, clip_motion, frame_step, make_clip_dataset, varied_motion,
)
from tryon.dataset.store import Manifest
from tryon.perceive.fabric_classes import FabricClasses

pytestmark = [pytest.mark.anny, pytest.mark.slow]


def _spec(count=2):
    return ClipDatasetSpec(garment="tshirt", sizes=("S", "M", "L"), count=count, edge_length=0.04, frames=4, fps=5.0,
                           shard_size=2, ranges=BodyRanges(genders=("female",), bmi=(20.0, 28.0)))


def test_units_draw_every_class_in_turn_and_the_same_fabric_and_motion_each_run():
    manifest = _spec(count=120).manifest("v")
    classes = FabricClasses.from_dict(manifest.spec["fabric_classes"])
    drawn = [clip_fabric(manifest, u) for u in range(classes.count)]
    assert [c for c, _ in drawn] == list(range(classes.count))
    assert all(classes.class_of(f) == c for c, f in drawn)
    again_c, again = clip_fabric(manifest, 7)
    assert again_c == 7 and np.allclose(again.parameters().numpy(), drawn[7][1].parameters().numpy())
    m1, r1 = clip_motion(manifest, 3)
    m2, r2 = clip_motion(manifest, 3)
    assert r1 == r2 and m1.duration >= (manifest.spec["frames"] - 1) / manifest.spec["fps"]
    speeds = {round(float(clip_motion(manifest, u)[1]["motion_speed"]), 3) for u in range(10)}
    assert len(speeds) == 10


def test_a_varied_motion_is_faster_and_wider():
    walk = load_motion("walk")
    fast = varied_motion(walk, 1.25, 0.8)
    assert fast.duration == pytest.approx(walk.duration / 1.25)
    assert np.allclose(fast.rotations, 0.8 * walk.rotations)


def test_frames_are_recorded_on_a_step_every_clip_frame_falls_on():
    # blend 0.5 s, frames every 0.2 s: every 0.1 s holds them all
    assert frame_step(0.01, 5.0) == 10 and frame_step(0.02, 5.0) == 5
    assert frame_step(0.01, 4.0) == 25  # 0.5 s and 0.25 s: every 0.25 s
    assert frame_step(0.03, 5.0) == 1   # 0.5 s is not a whole number of 0.03 s steps


def test_a_clip_is_the_garment_following_the_body_after_the_blend(tmp_path):
    store, report = make_clip_dataset(_spec(), tmp_path / "clips", progress=False)
    assert (report.made, report.failed) == (2, 0)
    shard = np.load(next((tmp_path / "clips" / "shards").glob("*.npz")))
    x, rest, t = shard["x"], shard["x_rest"], shard["times"]
    assert x.shape[:2] == (2, 4) and x.shape[2:] == rest.shape[1:] and np.isfinite(x).all()
    assert np.allclose(t, 0.5 + np.arange(4) / 5.0, atol=1e-6)
    assert list(shard["fabric_class"]) == [0, 1]
    # the garment moves with the body between frames, a few cm, not flung
    step = np.linalg.norm(np.diff(x, axis=1), axis=3).max(axis=2)
    assert (step > 0.002).all() and (step < 0.3).all()
    assert (shard["max_strain"] < 0.6).all()
    # filmed: the person finder sees the person in (nearly) every frame; the garment covers
    # part of the person's mask, and its mask moves between frames
    assert shard["frame_found"].mean() >= 0.75
    person = np.unpackbits(shard["frame_mask_bits"], axis=-1).reshape(2, 4, 128, 128).astype(bool)
    garment = np.unpackbits(shard["frame_garment_mask_bits"], axis=-1).reshape(2, 4, 64, 64).astype(bool)
    share = garment.mean(axis=(2, 3)) / person[:, :, ::2, ::2].mean(axis=(2, 3))
    assert ((share > 0.1) & (share < 0.8)).all(), share
    assert (garment[:, 1:] != garment[:, :-1]).any(axis=(2, 3)).all()
    # the garment found in the pictures (as on real frames) lies mostly on the true one
    found = np.unpackbits(shard["frame_found_garment_bits"], axis=-1).reshape(2, 4, 64, 64).astype(bool)
    iou = (found & garment).sum(axis=(2, 3)) / np.maximum((found | garment).sum(axis=(2, 3)), 1)
    assert np.median(iou[shard["frame_found"]]) > 0.6, iou
    # what the fabric classifier reads of it: masks, keypoints and each frame's garment code
    from tryon.learn.fabric_video import clip_tensors
    from tryon.learn.garment_codes import CodeConfig, GarmentCodes

    codes = GarmentCodes(CodeConfig(cloud=128, reps=8, patch=8, code=12, width=16))
    clips = clip_tensors([tmp_path / "clips"], codes)
    assert clips.masks.shape == (2, 4, 2, 64, 64) and clips.keypoints.shape == (2, 4, 99)
    assert clips.codes.shape == (2, 4, 12) and list(clips.label) == [0, 1] and set(clips.garment) == {"tshirt"}
    # the clip as the fabric refinement sees it: its true fabric, simulated from the first
    # frame with the body moving as it moved, follows it; a fabric 30x softer does not
    from tryon.dataset.clips import clip_for_refinement
    from tryon.fabric.blend import scaled_stiffness

    sample = {k: shard[k][0] for k in shard.files}
    clip, truth = clip_for_refinement(Manifest.read(tmp_path / "clips"), tmp_path / "clips", sample)
    size = np.linalg.norm(clip.observed[0].max(0) - clip.observed[0].min(0))
    err = {name: np.linalg.norm(clip.simulate(f)[1:] - clip.observed[1:], axis=-1).mean() / size
           for name, f in (("truth", truth), ("soft", scaled_stiffness(truth, 1 / 30, 1 / 30)))}
    assert err["truth"] < 0.01 and err["soft"] > 2 * err["truth"], err
    # a size that could not be dressed: its clips fail, naming why, with the arrays of any clip
    from tryon.dataset.clips import clip_unit, prepare_clips

    manifest = Manifest.read(tmp_path / "clips")
    refs = prepare_clips(manifest, tmp_path / "clips")
    undressed = {k: (r if k == ("female", "XS") else "seams still open") for k, r in refs.items()}
    failed = clip_unit(manifest, {**undressed, ("female", "XS"): refs[("female", "S")]}, 0)
    assert not failed["ok"] and "could not be dressed: seams still open" in str(failed["error"])
    assert {k: np.shape(v) for k, v in failed.items() if k != "unit"} == \
        {k: shard[k].shape[1:] for k in shard.files if k != "unit"}


def test_clip_command_checks_arguments_before_any_work(tmp_path, capsys):
    assert main(["dataset", "clips", "--frames", "1", "--out", str(tmp_path / "c")]) == 2
    assert "1 frames at 5.0 fps" in capsys.readouterr().err
    assert main(["dataset", "clips", "--motions", "dance", "--out", str(tmp_path / "c")]) == 2
    assert "motions ['dance']" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()
