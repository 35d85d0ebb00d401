"""`tryon motion from-video` on a rendered clip of a body raising its arms (the
`arm_raise_frames` fixture): the motion it writes raises the arms too, and `tryon animate`
can read it."""

import json

import numpy as np
import pytest
from PIL import Image

from tryon.cli import main

pytestmark = [pytest.mark.anny, pytest.mark.slow]


def test_the_motion_of_a_clip_is_written_for_animate(arm_raise_frames, tmp_path, capsys):
    from tryon.body.anny_model import ShapeParams, body_model
    from tryon.body.motion import load_motion
    from tryon.body.pose import bone_transforms, posed_heads

    out = tmp_path / "motion"
    # asked for 15 fps from frames taken at 5 fps: the motion has the frames' rate
    assert main(["motion", "from-video", str(arm_raise_frames), "--height-cm", "170", "--gender", "female",
                 "--fps", "15", "--frames-fps", "5", "--out", str(out)]) == 0
    assert "followed in" in capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    assert report["frames"] == 8 and report["followed_frames"] >= 7 and report["mean_angle_deg"] < 12
    assert (out / "motion.png").exists() and (out / "body.obj").exists()
    motion = load_motion(str(out / "motion.npz"))
    assert motion.num_frames == 8 and motion.fps == 5.0
    # the wrists rise against the shoulders from the first frame to the last, as in the clip
    shape = body_model().rest_shape(ShapeParams())
    labels = list(shape.bone_labels)
    poses = motion.pose_matrices(shape)

    def lift(P):
        h = posed_heads(shape, bone_transforms(shape, P))
        return np.mean([h[labels.index(f"wrist.{s}")][2] - h[labels.index(f"upperarm01.{s}")][2] for s in "LR"])

    assert lift(poses[-1]) - lift(poses[0]) > 0.15
    # a folder with no person in it is refused by name
    (tmp_path / "empty").mkdir()
    for i in range(6):
        Image.fromarray(np.full((640, 480, 3), 128, np.uint8)).save(tmp_path / "empty" / f"f{i}.png")
    assert main(["motion", "from-video", str(tmp_path / "empty"), "--height-cm", "170", "--gender", "female",
                 "--fps", "5", "--frames-fps", "5", "--out", str(tmp_path / "none")]) != 0
    assert "no person found" in capsys.readouterr().err
    assert not (tmp_path / "none").exists()
