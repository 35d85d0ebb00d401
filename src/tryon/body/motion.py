"""Body motions: per-frame joint rotations, their files, and bodies moving through them.

A `BodyMotion` holds, for T frames at `fps`, one rotation per named bone (axis-angle,
in the pose convention of `tryon.body.pose`: about the bone's head, in the world frame of
Anny's rest pose, applied parent first) and a root translation. Bones a motion does not
name stay at their rest rotation, so one file fits every Anny body.

File format (npz): `rotations` [T,J,3] axis-angle (radians), `bone_labels` [J] (str),
`fps` (scalar), optional `root_translation` [T,3] (m), optional `name`. BVH files load
through `tryon.body.bvh`. Built-in motions (`walk`, `arm-raise`, `turn`) ship in
tryon/body/data/motions, authored by scripts/author_motions.py.

`motion_keyframes` poses a body through a motion (linear blend skinning), starting from a
given pose (the A-pose a garment was draped in) and blending into the motion with
spherical interpolation; `morph_keyframes` changes one body shape into another over time.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from tryon.body.anny_model import BodyShape
from tryon.body.motion_data import MAX_FPS, MIN_FPS, BodyMotion
from tryon.body.pose import axis_angle, bone_transforms, matrix_to_axis_angle, skin
from tryon.errors import InputFileError, TryonError
from tryon.limits import LIMITS, check_limit

__all__ = ["BUILTIN_MOTIONS", "BodyMotion", "load_motion", "motion_keyframes", "motion_poses", "morph_keyframes", "posed_sequence",
           "slerp_poses", "smoothstep"]

BUILTIN_MOTIONS = ("walk", "arm-raise", "turn")
MAX_BLEND_TIME = 60.0  # s
BLEND_TIME = 0.5  # s from the start pose into a motion's first frame, by default


def load_motion(source: str | Path, shape: BodyShape | None = None, allow_large: bool | None = None) -> BodyMotion:
    """A built-in motion by name, or a motion file (.npz, or .bvh retargeted onto `shape`);
    `allow_large` lifts the file size limits of `tryon.limits`."""
    text = str(source)
    if text in BUILTIN_MOTIONS:
        ref = resources.files("tryon.body").joinpath(f"data/motions/{text}.npz")
        with resources.as_file(ref) as p:
            return _load_npz(Path(p))
    path = Path(text)
    if not path.exists():
        raise InputFileError(f"motion {text!r}: no such file, and not a built-in motion ({', '.join(BUILTIN_MOTIONS)})")
    if path.suffix.lower() == ".bvh":
        from tryon.body.bvh import load_bvh, retarget

        if shape is None:
            raise TryonError(f"motion {path}: a BVH file needs the body it is retargeted onto")
        return retarget(load_bvh(path, allow_large), shape)
    if path.suffix.lower() != ".npz":
        raise InputFileError(f"motion {path}: use a .npz (rotations, bone_labels, fps) or a .bvh file")
    return _load_npz(path, allow_large)


def _load_npz(path: Path, allow_large: bool | None = None) -> BodyMotion:
    from tryon.io import npz

    arrays = npz.read_npz(path, "motion file", allow_large)
    source = f"motion file {path}"
    if not {"rotations", "bone_labels", "fps"} <= set(arrays):
        raise InputFileError(f"{source}: needs the arrays rotations / bone_labels / fps, it has {sorted(arrays)}")
    labels = npz.text_list(arrays, "bone_labels", source)
    rot = npz.float_array(arrays, "rotations", source, (None, len(labels), 3))
    fps = npz.scalar(arrays, "fps", source, MIN_FPS, MAX_FPS, "frames per second")
    trans = npz.float_array(arrays, "root_translation", source, (len(rot), 3)) if "root_translation" in arrays else None
    return BodyMotion(rot, labels, fps, trans, npz.text(arrays, "name", source, path.stem, 100))


def slerp_poses(Ra: np.ndarray, Rb: np.ndarray, s: float) -> np.ndarray:
    """Per-bone spherical interpolation between pose rotations [J,3,3] (s in [0, 1])."""
    delta = matrix_to_axis_angle(np.einsum("jba,jbc->jac", Ra, Rb))  # Ra^T Rb
    return np.einsum("jab,jbc->jac", Ra, axis_angle(s * delta))


def smoothstep(s: np.ndarray | float) -> np.ndarray | float:
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3 - 2 * s)


def motion_start(motion: BodyMotion, blend_time: float = BLEND_TIME, fps: float | None = None) -> float:
    """When the motion's first frame is reached after the blend (s): the blend lasts a whole
    number of frames at `fps` (the motion's own by default), so not always `blend_time`."""
    fps = fps or motion.fps
    return max(1, int(round(blend_time * fps))) / fps


def motion_poses(shape: BodyShape, motion: BodyMotion, start_pose: np.ndarray, blend_time: float = BLEND_TIME,
                 fps: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses [K,J,3,3], root translations [K,3] and times [K]: `blend_time` seconds from
    `start_pose` [J,3,3] into the motion's first frame (smoothstep slerp), then the motion."""
    fps = fps or motion.fps
    if not (MIN_FPS <= fps <= MAX_FPS and 0 <= blend_time <= MAX_BLEND_TIME):
        raise TryonError(f"motion {motion.name}: need {MIN_FPS:g} <= fps <= {MAX_FPS:g} and 0 <= blend_time <= "
                         f"{MAX_BLEND_TIME:g} s, got fps {fps} and blend_time {blend_time}")
    n_blend = int(round(motion_start(motion, blend_time, fps) * fps))
    count = n_blend + int(motion.duration * fps + 1e-9) + 1
    check_limit(f"motion {motion.name} at {fps:g} fps: frames", count, LIMITS.max_frames, "max_frames")
    poses = motion.pose_matrices(shape)
    rots, trans, times = [], [], []
    for k in range(n_blend):
        rots.append(slerp_poses(start_pose, poses[0], float(smoothstep(k / n_blend))))
        trans.append(np.zeros(3))
        times.append(k / fps)
    for t in np.arange(0.0, motion.duration + 1e-9, 1.0 / fps):
        R, tr = pose_at(motion, poses, t)
        rots.append(R)
        trans.append(np.asarray(tr, float))
        times.append(n_blend / fps + t)
    return np.stack(rots), np.stack(trans), np.asarray(times)


def motion_keyframes(shape: BodyShape, motion: BodyMotion, start_pose: np.ndarray, blend_time: float = BLEND_TIME,
                     fps: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Skinned body vertices [K,V,3] and their times [K] of `motion_poses`."""
    rots, trans, times = motion_poses(shape, motion, start_pose, blend_time, fps)
    check_limit(f"motion {motion.name}: skinned frames (bytes)", 24 * len(rots) * shape.vertices.shape[0],
                LIMITS.max_memory_bytes, "max_memory_bytes")
    return posed_sequence(shape, rots, trans), times


def pose_at(motion: BodyMotion, poses: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Pose [J,3,3] and root translation at time t (slerp between the nearest frames)."""
    u = min(max(t * motion.fps, 0.0), motion.num_frames - 1.0)
    k = min(int(np.floor(u)), motion.num_frames - 2) if motion.num_frames > 1 else 0
    s = u - k if motion.num_frames > 1 else 0.0
    if motion.num_frames == 1:
        return poses[0], motion.root_translation[0]
    R = slerp_poses(poses[k], poses[k + 1], s)
    trans = (1 - s) * motion.root_translation[k] + s * motion.root_translation[k + 1]
    return R, trans


def morph_keyframes(a: np.ndarray, b: np.ndarray, duration: float, count: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """A body changing shape: vertices [count,V,3] from `a` to `b` (same mesh and pose) with
    smoothstep timing (no jerk at the ends), and their times [count] over `duration`."""
    if a.shape != b.shape:
        raise TryonError(f"morph: both bodies need the same vertices, got {a.shape} and {b.shape}")
    s = np.linspace(0.0, 1.0, count)
    w = smoothstep(s)
    return np.stack([(1 - wi) * a + wi * b for wi in w]), s * duration


def posed_sequence(shape: BodyShape, rotations: np.ndarray, translations: np.ndarray | None = None) -> np.ndarray:
    """Skinned vertices [T,V,3] for poses [T,J,3,3] (and root translations [T,3])."""
    verts = shape.vertices.detach()
    out = []
    for k in range(len(rotations)):
        trans = None if translations is None else translations[k]
        out.append(skin(verts, shape.weight_index, shape.weight, bone_transforms(shape, rotations[k], trans)).numpy())
    return np.stack(out)

