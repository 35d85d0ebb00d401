"""`tryon motion from-video` on a rendered clip of a body raising its arms: the motion it
writes raises the arms too, and `tryon animate` can read it."""

import json

import numpy as np
import pytest
from PIL import Image

from tryon.cli import main

pytestmark = [pytest.mark.anny, pytest.mark.slow]


def _render_clip(folder, frames=8):
    """A front view of the average body doing the built-in arm raise, `frames` pictures."""
    from tryon.body.anny_model import ShapeParams, body_model
    from tryon.body.motion import load_motion
    from tryon.body.pose import posed_vertices
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes

    shape = body_model().rest_shape(ShapeParams())
    motion = load_motion("arm-raise")
    poses = motion.pose_matrices(shape)
    picked = np.linspace(0, len(poses) // 2, frames).astype(int)  # arms going up
    verts = [posed_vertices(shape, poses[k]).detach().numpy() for k in picked]
    cam = Camera.fit(verts, "front", aspect=480 / 640, margin=1.25)
    folder.mkdir()
    for i, v in enumerate(verts):
        img = render_meshes([RenderMesh(v, np.asarray(shape.faces), color=(0.85, 0.68, 0.58))], 480, 640, cam,
                            background=(0.55, 0.6, 0.65), backend="numpy")
        Image.fromarray(img).save(folder / f"frame{i:02d}.png")


def test_the_motion_of_a_clip_is_written_for_animate(tmp_path, capsys):
    from tryon.body.anny_model import ShapeParams, body_model
    from tryon.body.motion import load_motion
    from tryon.body.pose import bone_transforms, posed_heads

    _render_clip(tmp_path / "frames")
    out = tmp_path / "motion"
    # asked for 15 fps from frames taken at 5 fps: the motion has the frames' rate
    assert main(["motion", "from-video", str(tmp_path / "frames"), "--height-cm", "170", "--gender", "female",
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
                 "--fps", "5", "--out", str(tmp_path / "none")]) != 0
    assert "no person found" in capsys.readouterr().err
    assert not (tmp_path / "none").exists()
