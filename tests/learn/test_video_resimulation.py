"""Where the re-simulation's camera stands and when the video's first frame is reached:
the two facts that put the simulation beside the video (`tryon perceive --resimulate`)."""

import numpy as np
import pytest

from tryon.body.motion import BLEND_TIME, motion_start
from tryon.body.motion_data import BodyMotion
from tryon.learn.video_resimulation import camera_direction
from tryon.perceive.motion_from_video import camera_heading, facing_forward


@pytest.mark.parametrize("yaw", [-1.3, -0.4, 0.0, 0.7, 2.5])
def test_the_camera_stands_where_the_motion_turned_to_rest_heading_puts_it(yaw):
    rotations = np.zeros((2, 2, 3))
    rotations[:, 0, 2] = yaw  # the root turned about the vertical, as read from a video
    # a point toward the camera (at -y in the motion as read), carried as the root's travel
    moved = BodyMotion(rotations, ["root", "spine"], 30.0, np.array([[0.0, -1.0, 0.0], [0.0, -1.0, 0.0]]), "m")
    turned = facing_forward(moved)
    assert camera_direction(camera_heading(moved)) == pytest.approx(turned.root_translation[0], abs=1e-6)


def test_the_first_frame_comes_after_whole_frames_of_blend():
    def motion(fps):
        return BodyMotion(np.zeros((3, 1, 3)), ["root"], fps, np.zeros((3, 3)), "m")

    assert motion_start(motion(30.0)) == pytest.approx(BLEND_TIME)
    assert motion_start(motion(5.0)) == pytest.approx(0.4)      # 2.5 frames of blend round to 2
    assert motion_start(motion(15.0)) == pytest.approx(8 / 15)  # 7.5 round to 8
    assert motion_start(motion(15.0), fps=30.0) == pytest.approx(BLEND_TIME)
    assert motion_start(motion(1.0)) == pytest.approx(1.0)      # at least one frame
