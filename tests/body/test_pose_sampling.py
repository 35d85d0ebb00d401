"""Random pose sequences for pose datasets: within the joint limits, arms out of the torso,
key poses joined smoothly, built-in motions varied in speed and swing."""

import numpy as np
import pytest

from tryon.body.anny_model import ShapeParams, body_model
from tryon.body.motion import load_motion
from tryon.body.pose import identity_pose, matrix_to_axis_angle, posed_body
from tryon.body.pose_sampling import (FORWARD, LIMITS, _limb, angle_names, arms_in_torso, keyframed_poses,
                                     pose_from_angles, random_pose, varied_motion)

pytestmark = [pytest.mark.anny]


@pytest.fixture(scope="module")
def shape():
    return body_model().rest_shape(ShapeParams()).detached()


def _angle(a, b):
    return np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


def test_random_poses_respect_the_joint_limits(shape):
    rng = np.random.default_rng(0)
    for _ in range(8):
        R = random_pose(shape, rng)
        assert not arms_in_torso(shape, R)
        for bone in ("spine03", "spine01"):   # limbs are limited relative to the trunk
            assert np.degrees(np.linalg.norm(matrix_to_axis_angle(R[shape.bone(bone)]))) < 25.0
            R[shape.bone(bone)] = np.eye(3)
        body = posed_body(shape, R)
        for side in ("L", "R"):
            sh, el, wr = (body.heads[f"{b}.{side}"] for b in ("upperarm01", "lowerarm01", "wrist"))
            elevation = _angle(el - sh, np.array([0.0, 0.0, -1.0]))
            assert LIMITS["arm_elevation"][0] - 1 <= elevation <= LIMITS["arm_elevation"][1] + 1
            assert _angle(wr - el, el - sh) <= LIMITS["elbow_flexion"][1] + 1
            hip, knee, foot = (body.heads[f"{b}.{side}"] for b in ("upperleg01", "lowerleg01", "foot"))
            assert _angle(foot - knee, knee - hip) <= LIMITS["knee_flexion"][1] + 1


def test_the_random_angles_are_drawn_as_every_dataset_was_made():
    """The pose datasets regenerate from their seeds only while the draws keep their order."""
    from tryon.body.pose_sampling import _draw_angles

    a = _draw_angles(np.random.default_rng(0))
    assert list(a) == angle_names()
    assert [round(a[k], 6) for k in ("arm_elevation.L", "arm_azimuth.L", "elbow_flexion.L", "spine_twist")] == [
        104.620211, -0.323461, 4.507088, 11.482772]


def test_a_pose_from_joint_angles_points_the_limbs_as_named(shape):
    """What `tryon view --live`'s sliders set: each arm's elevation from straight down and
    azimuth towards the front, the elbow's and knee's bend."""
    assert len(angle_names()) == 15 and {n.split(".")[0] for n in angle_names()} == set(LIMITS)
    body = posed_body(shape, pose_from_angles(shape, {"arm_elevation.L": 90.0, "arm_azimuth.R": 90.0,
                                                       "arm_elevation.R": 90.0, "elbow_flexion.L": 90.0,
                                                       "hip_flexion.R": 45.0, "knee_flexion.R": 60.0}))
    sh, el, wr = (body.heads[f"{b}.L"] for b in ("upperarm01", "lowerarm01", "wrist"))
    assert _angle(el - sh, np.array([1.0, 0.0, 0.0])) < 2.0            # left arm out to its side, level
    assert _angle(wr - el, el - sh) == pytest.approx(90.0, abs=2.0)
    sh, el = body.heads["upperarm01.R"], body.heads["lowerarm01.R"]
    assert _angle(el - sh, FORWARD) < 2.0                                # right arm straight ahead
    hip, knee, foot = (body.heads[f"{b}.R"] for b in ("upperleg01", "lowerleg01", "foot"))
    assert _angle(knee - hip, np.array([0.0, 0.0, -1.0])) == pytest.approx(45.0, abs=2.0)
    assert _angle(foot - knee, knee - hip) == pytest.approx(60.0, abs=2.0)
    with pytest.raises(ValueError, match="arm_elevaton.L"):   # a misspelt angle is not silently the default
        pose_from_angles(shape, {"arm_elevaton.L": 120.0})


def test_an_arm_through_the_chest_is_caught(shape):
    R = identity_pose(shape)
    target = np.array([-0.6, -0.2, -0.77])
    _limb(R, shape, "upperarm01.L", "lowerarm01.L", "wrist.L", target / np.linalg.norm(target), 0.0, FORWARD)
    assert arms_in_torso(shape, R)


def test_key_poses_are_joined_smoothly(shape):
    rng = np.random.default_rng(1)
    start = random_pose(shape, rng)
    P = keyframed_poses(shape, rng, 21, keys=3, start=start)
    assert P.shape == (21, len(shape.bone_labels), 3, 3) and np.allclose(P[0], start)
    step = np.abs(matrix_to_axis_angle(np.einsum("fjba,fjbc->fjac", P[:-1], P[1:]))).max(axis=(1, 2))
    assert step.max() < 0.35   # no jump: at most 20 degrees per frame for any bone
    assert step[0] < 0.05 and step[-1] < 0.05   # smoothstep: at rest at the ends


def test_varied_motion_at_unit_speed_and_swing_is_the_motion(shape):
    motion = load_motion("walk")
    poses = motion.pose_matrices(shape)
    P, drawn = varied_motion(shape, "walk", np.random.default_rng(2), 10, speed=(1.0, 1.0), amplitude=(1.0, 1.0))
    k0 = drawn["start_s"] * motion.fps
    if abs(k0 - round(k0)) < 1e-9:
        assert np.allclose(P[0], poses[int(round(k0))], atol=1e-9)
    P2, _ = varied_motion(shape, "walk", np.random.default_rng(2), 10, speed=(1.0, 1.0), amplitude=(1.5, 1.5))
    swing = lambda Q: np.abs(matrix_to_axis_angle(np.einsum("jba,fjbc->fjac", poses[0], Q))).max()  # noqa: E731
    assert swing(P2) == pytest.approx(1.5 * swing(P), rel=0.02)
