"""The body's motion from a person finder's 3D landmarks: landmarks made from a known
motion of the body (turned away from the camera, with centimetre noise) give that motion
back, joint by joint."""

import numpy as np
import pytest

from tryon.body.anny_model import ShapeParams, body_model
from tryon.body.motion import load_motion
from tryon.body.pose import bone_transforms, posed_heads
from tryon.errors import TryonError
from tryon.perceive.motion_from_video import CAMERA_TO_BODY, JOINTS, fit_motion
from tryon.perceive.person import K

pytestmark = [pytest.mark.anny]


@pytest.fixture(scope="module")
def shape():
    return body_model().rest_shape(ShapeParams())


def _joints(shape, poses, yaw_deg=0.0):
    """Hip-centred joints per frame {landmark: [T,3]} of `poses` [T,J,3,3], turned by yaw."""
    labels = list(shape.bone_labels)
    a = np.deg2rad(yaw_deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    out = {lm: [] for lm in JOINTS}
    for P in poses:
        h = posed_heads(shape, bone_transforms(shape, P)) @ Rz.T
        mid = (h[labels.index("upperleg01.L")] + h[labels.index("upperleg01.R")]) / 2
        for lm, bone in JOINTS.items():
            out[lm].append(h[labels.index(bone)] - mid)
    return {lm: np.stack(v) for lm, v in out.items()}


def test_a_walk_seen_as_landmarks_is_followed_to_within_centimetres(shape):
    poses = load_motion("walk").pose_matrices(shape)[::2]
    truth = _joints(shape, poses, yaw_deg=35.0)
    T = len(poses)
    world = np.zeros((T, 33, 3))
    for lm, p in truth.items():
        world[:, K[lm]] = p @ CAMERA_TO_BODY  # body axes -> the finder's camera axes
    world += np.random.default_rng(0).normal(0.0, 0.01, world.shape)
    visibility = np.ones((T, 33))
    motion, mean_deg = fit_motion(shape, world, visibility, fps=15.0)
    assert motion.num_frames == T and motion.fps == 15.0 and mean_deg < 6.0
    fitted = _joints(shape, motion.pose_matrices(shape))
    err = np.stack([np.linalg.norm(fitted[lm] - truth[lm], axis=-1) for lm in JOINTS])
    assert err.mean() < 0.025 and err.max() < 0.08, (err.mean(), err.max())
    # the knees and ankles swing as the walk's do (not a body standing still)
    swing = np.ptp(truth["left_ankle"][:, 1] - truth["left_hip"][:, 1])
    assert swing > 0.2 and np.ptp(fitted["left_ankle"][:, 1] - fitted["left_hip"][:, 1]) > 0.8 * swing


def test_a_person_facing_the_camera_at_rest_is_the_body_at_rest(shape):
    # BlazePose's world landmarks: x to the image's right, y down, z away from the camera,
    # centred between the hips; a person facing the camera has their left side on the
    # image's right. Anny stands facing -y with its left (.L) at +x and z up.
    body = _joints(shape, [np.tile(np.eye(3), (len(shape.bone_labels), 1, 1))])
    world = np.zeros((1, 33, 3))
    for lm, p in body.items():
        x, y, z = p[0]
        world[0, K[lm]] = (x, -z, y)
    assert world[0, K["left_shoulder"], 0] > 0.1 and world[0, K["left_shoulder"], 1] < -0.3
    motion, mean_deg = fit_motion(shape, world, np.ones((1, 33)), fps=5.0)
    assert mean_deg < 2.0
    assert np.degrees(np.linalg.norm(motion.rotations[0], axis=-1)).max() < 8.0  # no turn, no bend


def test_frames_without_the_person_do_not_make_the_others_misread(shape):
    from tryon.perceive.motion_from_video import misread_frames

    truth = _joints(shape, load_motion("walk").pose_matrices(shape)[::2])
    T = len(truth["left_hip"])
    pts = {lm: p.copy() for lm, p in truth.items()}
    for p in pts.values():
        p[: T // 2 + 2] = 0.0  # the person unseen in more than half of the frames
    assert not misread_frames(pts).any()


def test_a_misread_frame_is_left_to_its_neighbours(shape):
    from tryon.perceive.motion_from_video import misread_frames

    poses = load_motion("walk").pose_matrices(shape)[::2]
    truth = _joints(shape, poses)
    T = len(poses)
    world = np.zeros((T, 33, 3))
    for lm, p in truth.items():
        world[:, K[lm]] = p @ CAMERA_TO_BODY
    # frame 6 misread: the finder folds the torso forward (shoulders 25 cm lower, 20 cm ahead)
    for lm in ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist"):
        world[6, K[lm]] += np.array([0.0, 0.25, -0.2])
    pts = {lm: world[:, K[lm]] @ CAMERA_TO_BODY.T for lm in JOINTS}
    assert list(np.nonzero(misread_frames(pts))[0]) == [6]
    motion, _ = fit_motion(shape, world, np.ones((T, 33)), fps=15.0)
    fitted = _joints(shape, motion.pose_matrices(shape))
    err6 = np.mean([np.linalg.norm(fitted[lm][6] - truth[lm][6]) for lm in JOINTS])
    assert err6 < 0.05, err6


def test_the_bodys_travel_across_the_picture_is_found_in_metres(shape):
    from tryon.perceive.motion_from_video import body_travel

    walk = load_motion("walk")
    truth = _joints(shape, walk.pose_matrices(shape))  # hip-centred; the walk stays in place
    T = walk.num_frames
    travel = np.stack([0.03 * np.arange(T), np.zeros(T), 0.02 * np.sin(np.arange(T) / 3)], 1)  # m
    scale, origin = 300.0, np.array([100.0, 250.0])  # px per m; where the hips start in the picture
    keypoints, visibility = np.zeros((T, 33, 2)), np.zeros((T, 33))
    for lm, p in truth.items():
        at = p + travel
        keypoints[:, K[lm]] = origin + scale * np.stack([at[:, 0], -at[:, 2]], 1)
        visibility[:, K[lm]] = 1.0
    visibility[10] = 0.0  # a frame where the person is not seen: its neighbours' travel
    found, found_scale = body_travel(shape, walk, keypoints, visibility)
    assert found_scale == pytest.approx(scale, rel=0.01)
    ok = np.arange(T) != 10
    assert np.abs(found[ok] - (travel[ok] - travel[0])).max() < 0.01
    assert np.abs(found[10] - (travel[10] - travel[0])).max() < 0.03


def test_unseen_limbs_and_bad_landmarks_are_named(shape):
    with pytest.raises(TryonError, match=r"\[frames, 33, 3\]"):
        fit_motion(shape, np.zeros((4, 17, 3)), np.ones((4, 17)), 5.0)
    with pytest.raises(TryonError, match="no limb"):
        fit_motion(shape, np.random.default_rng(1).normal(size=(3, 33, 3)), np.zeros((3, 33)), 5.0)
