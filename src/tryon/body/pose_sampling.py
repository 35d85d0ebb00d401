"""Pose sequences drawn at random, for datasets of pose-dependent cloth.

Two sources, both returning per-bone rotations [F,J,3,3] at a frame rate (the convention
of `tryon.body.pose`: rotations about each bone's head in the world frame of Anny's rest
pose, parents first):

- `varied_motion`: a built-in motion (walk, arm-raise, turn) played faster or slower and
  with its swing scaled about its first frame, from a random start. Root translation is
  dropped: the body moves in place.
- `keyframed_poses`: a few whole-body key poses drawn within joint limits (`LIMITS`:
  arm direction and elbow, hip direction and knee, spine bend and twist) and joined by
  smoothstep spherical interpolation.

Angles are degrees in `LIMITS`. Arm elevation is measured from straight down, in the
plane turned `arm_azimuth` towards the front (0: the side; 90: straight ahead).
"""

from __future__ import annotations

import numpy as np

from tryon.body.anny_model import BodyShape
from tryon.body.motion import load_motion, slerp_poses, smoothstep
from tryon.body.pose import axis_angle, identity_pose, rotation_between

LIMITS = {
    "arm_elevation": (25.0, 150.0),
    "arm_azimuth": (-30.0, 80.0),
    "elbow_flexion": (0.0, 110.0),
    "hip_flexion": (-20.0, 60.0),
    "hip_abduction": (0.0, 20.0),
    "knee_flexion": (0.0, 90.0),
    "spine_bend": (-15.0, 25.0),
    "spine_side": (-15.0, 15.0),
    "spine_twist": (-25.0, 25.0),
}
FORWARD = np.array([0.0, -1.0, 0.0])   # Anny faces -Y
SIDES = (("L", 1.0), ("R", -1.0))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _limb(R: np.ndarray, shape: BodyShape, upper: str, lower: str, end: str, target: np.ndarray, bend: float,
          bend_towards: np.ndarray) -> None:
    """Point the limb's upper bone along `target` with its joint bent `bend` degrees towards
    `bend_towards` (in the straight limb's frame), in place in R."""
    heads = shape.bone_heads.detach().numpy()
    a, b, c = (shape.bone(x) for x in (upper, lower, end))
    up, lo = heads[b] - heads[a], heads[c] - heads[b]
    straight = rotation_between(lo, up)
    axis = _unit(np.cross(_unit(up), bend_towards))
    R[b] = axis_angle(np.radians(bend) * axis) @ straight
    R[a] = rotation_between(up, target)


def random_pose(shape: BodyShape, rng: np.random.Generator, tries: int = 50) -> np.ndarray:
    """One whole-body pose [J,3,3] within `LIMITS` whose arms stay out of the torso
    (drawn again until they do)."""
    for _ in range(tries):
        R = _draw_pose(shape, rng)
        if not arms_in_torso(shape, R):
            return R
    return R


def arms_in_torso(shape: BodyShape, R: np.ndarray, margin: float = 0.01) -> bool:
    """Whether a point of either arm (from a third of the way down the upper arm to the
    wrist) lies inside the torso: inside the convex hull of the torso's cross-section at
    its height, `margin` in from its outline."""
    from scipy.spatial import ConvexHull

    from tryon.body.pose import posed_body

    body = posed_body(shape, R)
    torso = body.vertices[(body.part == 0) & (body.vertices[:, 2] < body.heads["neck01"][2])]
    for side, _ in SIDES:
        a, b, c = (body.heads[f"{x}.{side}"] for x in ("upperarm01", "lowerarm01", "wrist"))
        points = np.concatenate([a + np.linspace(0.33, 1.0, 5)[:, None] * (b - a),
                                 b + np.linspace(0.0, 1.0, 6)[:, None] * (c - b)])
        for p in points:
            ring = torso[np.abs(torso[:, 2] - p[2]) < 0.02, :2]
            if len(ring) < 8:
                continue
            hull = ConvexHull(ring)
            if (hull.equations[:, :2] @ p[:2] + hull.equations[:, 2] < -margin).all():
                return True
    return False


ARM_KEYS = ("arm_elevation", "arm_azimuth", "elbow_flexion")
LEG_KEYS = ("hip_flexion", "hip_abduction", "knee_flexion")
SPINE_KEYS = ("spine_bend", "spine_side", "spine_twist")


def angle_names() -> list[str]:
    """The angles of a whole-body pose (`pose_from_angles`): each limb's per side
    (`arm_elevation.L`, ...), then the spine's."""
    return [f"{k}.{side}" for side, _ in SIDES for k in ARM_KEYS + LEG_KEYS] + list(SPINE_KEYS)


def default_angle(name: str) -> float:
    """An angle of `angle_names` left unset: its range's value nearest 0 (the arms as low
    as the limits allow, the rest straight)."""
    lo, hi = LIMITS[name.split(".")[0]]
    return min(max(0.0, lo), hi)


def _draw_pose(shape: BodyShape, rng: np.random.Generator) -> np.ndarray:
    return pose_from_angles(shape, _draw_angles(rng))


def _draw_angles(rng: np.random.Generator) -> dict[str, float]:
    angles = {}
    for side, _ in SIDES:   # this order of draws is what every dataset's seed has made: keep it
        for k in ARM_KEYS + LEG_KEYS:
            angles[f"{k}.{side}"] = rng.uniform(*LIMITS[k])
    angles.update({k: rng.uniform(*LIMITS[k]) for k in SPINE_KEYS})
    return angles


def pose_from_angles(shape: BodyShape, angles: dict[str, float]) -> np.ndarray:
    """The whole-body pose [J,3,3] of joint angles in degrees (`angle_names`, as `LIMITS`
    measures them; a missing one takes its range's value nearest 0, i.e. the arms as
    low as the limits allow and the rest straight)."""
    unknown = sorted(set(angles) - set(angle_names()))
    if unknown:
        raise ValueError(f"unknown joint angle(s) {', '.join(unknown)}; the angles are {', '.join(angle_names())}")

    def a(name: str) -> float:
        return float(angles.get(name, default_angle(name)))

    R = identity_pose(shape)
    for side, sign in SIDES:
        e, az = np.radians(a(f"arm_elevation.{side}")), np.radians(a(f"arm_azimuth.{side}"))
        arm = np.array([sign * np.sin(e) * np.cos(az), -np.sin(e) * np.sin(az), -np.cos(e)])
        _limb(R, shape, f"upperarm01.{side}", f"lowerarm01.{side}", f"wrist.{side}", arm,
              a(f"elbow_flexion.{side}"), FORWARD)
        h, ab = np.radians(a(f"hip_flexion.{side}")), np.radians(a(f"hip_abduction.{side}"))
        leg = _unit(np.array([sign * np.sin(ab), -np.sin(h) * np.cos(ab), -np.cos(h) * np.cos(ab)]))
        _limb(R, shape, f"upperleg01.{side}", f"lowerleg01.{side}", f"foot.{side}", leg,
              a(f"knee_flexion.{side}"), -FORWARD)
    spine = np.radians([a(k) for k in SPINE_KEYS])
    bend = axis_angle(np.array([-spine[0], 0.0, 0.0])) @ axis_angle(np.array([0.0, spine[1], 0.0])) \
        @ axis_angle(np.array([0.0, 0.0, spine[2]]))
    half = axis_angle(0.5 * _rotvec(bend))
    R[shape.bone("spine03")] = half
    R[shape.bone("spine01")] = half
    return R


def _rotvec(R: np.ndarray) -> np.ndarray:
    from tryon.body.pose import matrix_to_axis_angle

    return matrix_to_axis_angle(R[None])[0]


def keyframed_poses(shape: BodyShape, rng: np.random.Generator, frames: int, fps: float = 30.0, keys: int = 3,
                    start: np.ndarray | None = None) -> np.ndarray:
    """`frames` poses [F,J,3,3]: `keys` random key poses spread over the sequence (the first
    is `start` if given), joined by smoothstep slerp."""
    key_poses = [start if start is not None else random_pose(shape, rng)] + [random_pose(shape, rng) for _ in range(keys - 1)]
    t = np.linspace(0.0, keys - 1.0, frames)
    out = []
    for s in t:
        k = min(int(np.floor(s)), keys - 2)
        out.append(slerp_poses(key_poses[k], key_poses[k + 1], float(smoothstep(s - k))))
    return np.stack(out)


def varied_motion(shape: BodyShape, name: str, rng: np.random.Generator, frames: int, fps: float = 30.0,
                  speed: tuple[float, float] = (0.7, 1.4), amplitude: tuple[float, float] = (0.7, 1.3)) -> tuple[np.ndarray, dict]:
    """`frames` poses [F,J,3,3] of a built-in motion at a random speed and swing, from a
    random start; and what was drawn."""
    motion = load_motion(name)
    poses = motion.pose_matrices(shape)
    s, a = rng.uniform(*speed), rng.uniform(*amplitude)
    span = (frames - 1) / fps * s
    t0 = rng.uniform(0.0, max(motion.duration - span, 0.0))
    out = []
    for k in range(frames):
        u = min((t0 + k * s / fps) * motion.fps, motion.num_frames - 1.0)
        i = min(int(np.floor(u)), motion.num_frames - 2)
        R = slerp_poses(poses[i], poses[i + 1], u - i)
        out.append(slerp_poses(poses[0], R, a))
    return np.stack(out), {"motion": name, "speed": s, "amplitude": a, "start_s": t0}


def random_motion(shape: BodyShape, seed: int, seconds: float = 2.0, fps: float = 30.0, keys_per_second: float = 2.0,
                  name: str | None = None):
    """A motion of random key poses (a `BodyMotion`, every bone named) drawn from `seed`:
    for poses no dataset drawn from other seeds holds."""
    from tryon.body.motion_data import BodyMotion
    from tryon.body.pose import matrix_to_axis_angle

    rng = np.random.default_rng([seed, 12345])
    frames = max(2, int(round(seconds * fps)) + 1)
    keys = 1 + max(1, int(round(seconds * keys_per_second)))
    poses = keyframed_poses(shape, rng, frames, fps, keys=keys)
    return BodyMotion(matrix_to_axis_angle(poses), list(shape.bone_labels), fps, name=name or f"random-{seed}")
