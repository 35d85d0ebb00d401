"""`tryon perceive` on a rendered clip (the `arm_raise_frames` fixture): the motion, the
garment in each frame, and with a classifier (a tiny one trained here) the fabric class and
a fabric file that `tryon drape --fabric` reads; classifiers that need garment codes are
refused before any work."""

import json

import numpy as np
import pytest

from tryon.cli import main
from tryon.fabric.presets import load_fabric
from tryon.learn.fabric_video import ClipTensors
from tryon.learn.train_fabric_video import ClassifierTrainConfig, train_classifier
from tryon.perceive.fabric_classes import default_classes

pytestmark = [pytest.mark.anny, pytest.mark.slow]


def _tiny_classifier(folder, method):
    rng = np.random.default_rng(0)
    n, T = 6, 8
    clips = ClipTensors((rng.random((n, T, 2, 64, 64)) > 0.5).astype(np.uint8), rng.random((n, T, 99)).astype(np.float32),
                        rng.normal(size=(n, T, 16)).astype(np.float32), np.arange(n) * 9, np.array(["train"] * n),
                        np.array(["tshirt"] * n))
    train_classifier(clips, folder, method, ClassifierTrainConfig(epochs=1, batch=3), classes=54, progress=False)
    return folder / "fabric-video.npz"


@pytest.mark.parametrize("rate", [12.5, 15.0, 25.0, 30.0])
def test_the_classifier_reads_frames_5_a_second_from_where_the_person_is_found(rate):
    from tryon.learn.fabric_from_video import clip_frames

    times = np.arange(int(8 * rate)) / rate
    found = times >= 0.3
    picked = clip_frames(times, found)
    first = int(np.argmax(found))
    assert len(picked) == 25 and picked[0] == first
    assert np.abs(times[picked] - (times[first] + np.arange(25) / 5.0)).max() <= 0.5 / rate + 1e-9
    # a gap in the source ends the clip there
    gap = np.concatenate([times[times < 2.0], times[times > 3.0]])
    assert len(clip_frames(gap, gap >= 0.0)) == 11  # 0.0, 0.2, ..., 2.0 s


def test_a_clip_is_perceived_with_and_without_a_classifier(arm_raise_frames, tmp_path, capsys):
    args = ["perceive", str(arm_raise_frames), "--height-cm", "170", "--gender", "female", "--garment", "tshirt",
            "--frames-fps", "5"]
    # without a classifier: the motion and the garment, the class left unnamed
    assert main(args + ["--out", str(tmp_path / "plain")]) == 0
    report = json.loads((tmp_path / "plain" / "report.json").read_text())
    assert report["fabric"] is None and any("no fabric classifier" in n for n in report["notes"])
    assert report["classifier_frames"] == 8 and report["motion"]["followed_frames"] == 8
    assert report["garment_found_frames"] >= 6
    assert (tmp_path / "plain" / "motion.npz").exists() and (tmp_path / "plain" / "frames.png").exists()
    # re-simulated in a fabric asked: the garment draped on the body and moved through the
    # motion read, beside the frames; what --resimulate needs is asked before any work
    # (the clip given does not exist: each refusal comes before it is read)
    missing = ["perceive", str(tmp_path / "no-such-clip.mp4")] + args[2:]
    for extra, why in ((["--fabric", "gray-interlock"], "add --resimulate"),
                       (["--edge-length", "0.02"], "add --resimulate"),
                       (["--resimulate"], "needs a fabric"),
                       (["--resimulate", "--fabric", "gray-interlock", "--size", "Q"], "--size Q"),
                       (["--resimulate", "--fabric", "gray-interlock", "--edge-length", "0.2"], "outside 0.004-0.05"),
                       (["--resimulate", "--fabric", "no-such-cloth"], "unknown fabric")):
        capsys.readouterr()
        assert main(missing + extra + ["--out", str(tmp_path / "bad")]) != 0
        assert why in capsys.readouterr().err and not (tmp_path / "bad").exists()
    assert main(args + ["--resimulate", "--fabric", "gray-interlock", "--size", "M", "--edge-length", "0.04",
                        "--out", str(tmp_path / "resim")]) == 0
    resim = json.loads((tmp_path / "resim" / "report.json").read_text())["resimulation"]
    assert resim["size"] == "M" and resim["fabric"] == "gray-interlock" and resim["frames"] >= 40
    assert 0 < resim["max_strain"] < 2.0 and resim["summary"]["drape"]["penetration_pct"] < 5
    from tryon.io.frames import load_frames_npz

    frames = load_frames_npz(tmp_path / "resim" / "resimulated.npz")
    assert frames["times"][0] >= 0 and frames["times"][-1] == pytest.approx(1.4, abs=0.05)
    assert frames["max_strain"].shape == frames["times"].shape
    assert frames["max_strain"].max() == pytest.approx(resim["max_strain"], rel=1e-5)
    # the sleeves follow the arms as they rise
    assert np.linalg.norm(frames["positions"][-1] - frames["positions"][0], axis=1).max() > 0.05
    from PIL import Image

    picture = np.asarray(Image.open(tmp_path / "resim" / "resimulated.png"))
    assert picture.shape[:2] == (2 * 280, 6 * 200)  # six of the eight frames, each above its simulation
    # with an image-only classifier: a class, its probabilities, a fabric of that class
    model = _tiny_classifier(tmp_path / "image", "image-only-temporal")
    capsys.readouterr()
    assert main(args + ["--classifier", str(model), "--out", str(tmp_path / "classed")]) == 0
    fabric = json.loads((tmp_path / "classed" / "report.json").read_text())["fabric"]
    assert f"fabric class {fabric['class']} (" in capsys.readouterr().out
    top = [t["probability"] for t in fabric["top"]]
    assert 0 < top[0] <= 1 and top == sorted(top, reverse=True) and fabric["class"] == fabric["top"][0]["class"]
    classes = default_classes()
    made = load_fabric(str(tmp_path / "classed" / "fabric.json"))
    assert classes.name(classes.class_of(made)) == fabric["class"]
    assert len(fabric["nearest_presets"]) == 3
    # a classifier that reads garment codes is refused, naming why, before the clip is read
    # (the clip given does not exist: the refusal comes first)
    coded = _tiny_classifier(tmp_path / "coded", "image+garment-temporal")
    refused = ["perceive", str(tmp_path / "no-such-clip.mp4")] + args[2:]
    assert main(refused + ["--classifier", str(coded), "--out", str(tmp_path / "refused")]) != 0
    assert "reads garment codes" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()
