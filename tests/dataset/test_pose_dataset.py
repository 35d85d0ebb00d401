"""Pose datasets: the rest drape made once, sequences of poses with the cloth simulated
through them (recorded exactly at the poses), split by sequence, resumable."""

import numpy as np
import pytest

import tryon.dataset.poses as poses_module
from tryon.body.pose import arm_pose, matrix_to_axis_angle
from tryon.dataset.poses import (PoseDatasetSpec, body_keyframes, load_pose_dataset, make_pose_dataset, pose_unit,
                                 sequence_poses, settle_time, step_size)
from tryon.cli import main
from tryon.dataset.pack import pack_dataset
from tryon.errors import TryonError

pytestmark = [pytest.mark.anny, pytest.mark.slow]


def test_a_small_pose_dataset_is_made_and_resumed(tmp_path):
    out = tmp_path / "poses"
    spec = PoseDatasetSpec(count=2, frames=8, edge_length=0.03, shard_size=2)
    store, report = make_pose_dataset(spec, out, progress=False)
    assert report.made == 2 and (out / "rest.npz").exists()
    data = load_pose_dataset(out)
    a = data.arrays
    n = len(data.rest.garment.vertices)
    assert a["x"].shape == (2, 8, n, 3) and a["pose"].shape[:2] == (2, 8)
    assert a["ok"].all(), a["error"]
    assert np.isfinite(a["x"]).all() and np.nanmax(a["penetration_pct"]) == 0.0
    # the cloth moved with the body from the rest drape
    assert np.linalg.norm(a["x"][:, -1] - data.rest.garment.vertices, axis=-1).max() > 0.01
    # the stored poses are the unit's own draw
    shape = data.rest.shape()
    poses, drawn = sequence_poses(data.manifest, shape, 1)
    assert np.allclose(a["pose"][1], matrix_to_axis_angle(poses), atol=1e-6) and str(a["source"][1]) == drawn["motion"]
    # every pose falls on a time step
    sp = data.manifest.spec
    assert (sp["slow"] / sp["fps"] / step_size(sp)) == pytest.approx(round(sp["slow"] / sp["fps"] / step_size(sp)))
    # a larger count adds sequences; the first ones are not made again
    spec.count = 3
    _, report = make_pose_dataset(spec, out, progress=False)
    assert report.made == 1 and report.skipped == 2
    assert load_pose_dataset(out).summary()["sequences"] == 3
    # a packed copy (to keep in version control) loads with its rest drape, in half precision
    assert main(["dataset", "pack", str(out), "--out", str(tmp_path / "packed")]) == 0
    packed = load_pose_dataset(tmp_path / "packed")
    full = load_pose_dataset(out)
    assert packed.arrays["x"].dtype == np.float16 and packed.manifest.spec == full.manifest.spec
    assert np.abs(packed.arrays["x"].astype(np.float32) - full.arrays["x"]).max() < 0.001
    assert np.array_equal(packed.rest.garment.vertices, full.rest.garment.vertices)
    assert packed.rest.params.to_dict() == full.rest.params.to_dict()
    # packing again after the dataset grew rewrites the short last shard only
    first, last = (tmp_path / "packed" / "shards" / f"shard-0000{k}.npz" for k in (0, 1))
    before = (first.read_bytes(), first.stat().st_mtime_ns)
    assert np.load(last)["unit"].tolist() == [2]
    spec.count = 4
    make_pose_dataset(spec, out, progress=False)
    pack_dataset(out, tmp_path / "packed")
    assert (first.read_bytes(), first.stat().st_mtime_ns) == before
    assert np.load(last)["unit"].tolist() == [2, 3]
    grown = load_pose_dataset(tmp_path / "packed")
    assert grown.arrays["unit"].tolist() == [0, 1, 2, 3] and grown.manifest.count == 4
    assert np.abs(grown.arrays["x"].astype(np.float32) - load_pose_dataset(out).arrays["x"]).max() < 0.001


def test_bad_settings_are_refused():
    with pytest.raises(TryonError, match="tops and dresses"):
        PoseDatasetSpec(garment="trousers").validate()
    with pytest.raises(TryonError, match="out of range"):
        PoseDatasetSpec(frames=1).validate()


def test_settled_poses_hold_the_body_still_until_the_cloth_rests(tmp_path):
    """With --settle the body holds every pose (two keyframes a hold apart, the cloth
    recorded at the second) and the cloth is slower when recorded than in passing."""
    base = dict(count=1, frames=4, edge_length=0.03, shard_size=1, seed=3)
    runs = {}
    for settle in (0.0, 0.3):
        out = tmp_path / f"settle-{settle}"
        make_pose_dataset(PoseDatasetSpec(settle=settle, **base), out, progress=False)
        runs[settle] = load_pose_dataset(out)
    held = runs[0.3]
    assert held.manifest.spec["settle"] == 0.3 and "settle" not in runs[0.0].manifest.spec
    a, b = runs[0.0].arrays, held.arrays
    assert a["ok"].all() and b["ok"].all(), (a["error"], b["error"])
    assert np.allclose(a["pose"], b["pose"])  # the same poses, only held
    assert np.nanmax(b["cloth_speed"]) < np.nanmax(a["cloth_speed"])
    assert np.allclose(a["speed"], b["speed"])  # the drawn playback speed is kept beside it
    sp = held.manifest.spec
    shape = held.rest.shape()
    poses, _ = sequence_poses(held.manifest, shape, 0)
    frames, times, keys = body_keyframes(shape, poses, sp)
    hold = settle_time(sp)
    assert hold == pytest.approx(0.3, abs=step_size(sp))
    assert np.allclose(times[keys] - times[keys - 1], hold) and np.allclose(frames[keys], frames[keys - 1])


def test_from_rest_the_cloth_at_a_pose_does_not_depend_on_the_path_to_it(tmp_path, monkeypatch):
    """--from-rest simulates every pose on its own from the rest drape: the same pose gives
    the same cloth whatever came before it in the sequence; carried through the sequence
    (friction keeps what the path did) it does not."""
    out = tmp_path / "from-rest"
    make_pose_dataset(PoseDatasetSpec(count=1, frames=2, edge_length=0.03, shard_size=1, settle=0.1, from_rest=True),
                      out, progress=False)
    data = load_pose_dataset(out)
    assert data.manifest.spec["from_rest"] is True and data.arrays["ok"].all(), data.arrays["error"]
    assert np.isfinite(data.arrays["x"]).all() and np.isfinite(data.arrays["cloth_speed"]).all()
    shape = data.rest.shape()
    raised, lowered, between = (arm_pose(shape, angle) for angle in (120.0, 20.0, 70.0))
    cloth = {}
    for from_rest in (True, False):
        data.manifest.spec["from_rest"] = from_rest
        for name, first in (("raised", raised), ("lowered", lowered)):
            drawn = (np.stack([first, between]), {"motion": "test", "speed": 1.0, "amplitude": 1.0})
            monkeypatch.setattr(poses_module, "sequence_poses", lambda manifest, shape, unit, drawn=drawn: drawn)
            unit = pose_unit(data.manifest, data.rest, 0)
            assert unit["ok"], unit["error"]
            assert np.allclose(unit["pose"][1], matrix_to_axis_angle(between), atol=1e-6)
            cloth[from_rest, name] = unit["x"][1]
    gap = {r: np.linalg.norm(cloth[r, "raised"] - cloth[r, "lowered"], axis=-1).mean() for r in (True, False)}
    assert gap[True] < 1e-4 and gap[False] > 1e-3, gap  # the same pose from rest; different paths: > 1 mm apart


def test_from_rest_needs_a_hold():
    with pytest.raises(TryonError, match="needs --settle"):
        PoseDatasetSpec(from_rest=True).validate()
