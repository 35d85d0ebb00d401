"""`tryon bench perceive` on tiny held-out clips of measured fabrics: the clips wear the
fabrics exactly as measured, and each record's errors are those of its class's centre and
of the refined fabric against that fabric."""

import json

import numpy as np
import pytest

from tryon.bench.perceive import mean_record, relative_error_pct, run_perceive_bench
from tryon.dataset import BodyRanges
from tryon.dataset.clips import ClipDatasetSpec, clip_fabric, make_clip_dataset
from tryon.errors import TryonError
from tryon.fabric.wang2011 import WangFabric
from tryon.perceive.fabric_classes import default_classes

PRESETS = ("gray-interlock", "11oz-black-denim")


def test_clips_on_measured_fabrics_take_them_in_turn_as_measured():
    spec = ClipDatasetSpec(count=4, presets=PRESETS)
    manifest = spec.manifest("v")
    classes = default_classes()
    for unit in range(4):
        c, fabric = clip_fabric(manifest, unit)
        preset = WangFabric.from_preset(PRESETS[unit % 2])
        assert np.allclose(fabric.parameters().numpy(), preset.parameters().numpy())
        assert c == classes.class_of(preset)
    assert "presets" not in ClipDatasetSpec(count=4).manifest("v").spec  # class-drawn datasets unchanged
    with pytest.raises(TryonError, match="measured fabrics"):
        ClipDatasetSpec(presets=("no-such-cloth",)).validate()


@pytest.mark.anny
@pytest.mark.slow
def test_the_bench_judges_the_class_and_the_refinement_on_each_clip(tmp_path):
    spec = ClipDatasetSpec(garment="tshirt", sizes=("M",), count=2, edge_length=0.04, frames=4, fps=5.0, shard_size=2,
                           presets=PRESETS, seed=1, ranges=BodyRanges(genders=("female",), bmi=(20.0, 26.0)))
    make_clip_dataset(spec, tmp_path / "clips", progress=False)
    out = tmp_path / "perceive.json"
    records = run_perceive_bench(str(out), clips=str(tmp_path / "clips"), frames=3, bases=PRESETS, grid=3, golden=1)
    assert json.loads(out.read_text()) == json.loads(json.dumps(records))
    clips, mean = records[:-1], records[-1]
    classes = default_classes()
    assert [r["fabric"] for r in clips] == list(PRESETS) and mean["clip"] == "mean" and mean["clips"] == 2
    for r in clips:
        truth = WangFabric.from_preset(r["fabric"])
        c = classes.class_of(truth)
        assert r["method"] == "true-class" and r["class"] == r["true_class"] == classes.name(c)
        (s_true, b_true), (s_c, b_c) = classes.position(truth), classes.centre(c)
        assert r["stiffness_error_pct"] == pytest.approx(relative_error_pct(s_c, s_true))
        assert r["bending_error_pct"] == pytest.approx(relative_error_pct(b_c, b_true))
        # the refined stretching stays in the class: its error is at most the class's width away
        (s0, s1), _ = classes.box(c)
        assert r["refined_stiffness_error_pct"] <= relative_error_pct(s1, s0) + 1e-6
        assert r["refined_base"] in PRESETS and r["misfit_refined"] <= r["misfit_at_class_centre"]
        assert r["simulations"] == 2 + 2 + 1  # two bases at the centre, two more grid points, one golden
        assert r["top1"] is None and r["chamfer_cm"] is None and r["seconds"] > 0
    assert mean["stiffness_error_pct"] == pytest.approx(np.mean([r["stiffness_error_pct"] for r in clips]))
    better = sum(r["refined_stiffness_error_pct"] < r["stiffness_error_pct"] for r in clips)
    assert mean["refined_better"] == better and mean_record("m", clips[:1])["clips"] == 1
    with pytest.raises(TryonError, match="no finished clips"):
        run_perceive_bench(str(out), clips=str(tmp_path / "clips"), limit=0)
    # with an image-only classifier the class is its top guess, judged against the truth
    model = _tiny_classifier(tmp_path / "classifier")
    [guessed, _] = run_perceive_bench(str(out), clips=str(tmp_path / "clips"), model_path=str(model), frames=3,
                                      bases=PRESETS[:1], grid=2, golden=1, limit=1)
    assert guessed["method"] == "image-only-temporal" and guessed["top1"] in (0.0, 1.0)
    assert guessed["top3"] >= guessed["top1"] and guessed["true_class"] == clips[0]["true_class"]
    assert (guessed["class"] == guessed["true_class"]) == (guessed["top1"] == 1.0)


def _tiny_classifier(folder):
    from tryon.learn.fabric_video import ClipTensors
    from tryon.learn.train_fabric_video import ClassifierTrainConfig, train_classifier

    rng = np.random.default_rng(0)
    n, T = 6, 4
    clips = ClipTensors((rng.random((n, T, 2, 64, 64)) > 0.5).astype(np.uint8), rng.random((n, T, 99)).astype(np.float32),
                        rng.normal(size=(n, T, 16)).astype(np.float32), np.arange(n) * 9, np.array(["train"] * n),
                        np.array(["tshirt"] * n))
    train_classifier(clips, folder, "image-only-temporal", ClassifierTrainConfig(epochs=1, batch=3), classes=54,
                     progress=False)
    return folder / "fabric-video.npz"
