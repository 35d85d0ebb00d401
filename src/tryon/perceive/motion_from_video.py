"""The body's motion in a clip: the bone rotations of a body (`BodyShape`) that put its
limbs where the person finder's 3D landmarks put the person's, frame by frame.

BlazePose gives per frame 33 metric landmarks centred between the hips, in the camera's
axes (x right, y down, z away). They become body axes (x right, y away, z up) and the fit
matches directions, not positions, so the body's own proportions stand: each limb segment
(shoulder-elbow, elbow-wrist, hip-knee, knee-ankle), the shoulder line, the hip line and
the spine (hips' centre to shoulders' centre), weighted by how visible BlazePose says the
landmarks are. The rotated bones are those of the built-in motions (root, spine03, upper
and lower arms and legs), fitted over all frames at once by L-BFGS with a smoothness term
between frames and a small pull towards the rest pose; each frame's root starts turned
about the vertical to the landmarks' hip line, so the fit does not begin facing away.
Frames whose landmarks are misread (a bone far from its length over the clip) are left to
their neighbours.
The result is a `BodyMotion` the simulator plays like any other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from tryon.errors import TryonError
from tryon.perceive.person import K
from tryon.perceive.video import Frames, follow_person, read_frames

FITTED_BONES = ("root", "spine03", "upperarm01.L", "lowerarm01.L", "upperarm01.R", "lowerarm01.R",
                "upperleg01.L", "lowerleg01.L", "upperleg01.R", "lowerleg01.R")
# landmark -> the body joint at the same place (the bone whose head it is)
JOINTS = {"left_shoulder": "upperarm01.L", "right_shoulder": "upperarm01.R", "left_elbow": "lowerarm01.L",
          "right_elbow": "lowerarm01.R", "left_wrist": "wrist.L", "right_wrist": "wrist.R",
          "left_hip": "upperleg01.L", "right_hip": "upperleg01.R", "left_knee": "lowerleg01.L",
          "right_knee": "lowerleg01.R", "left_ankle": "foot.L", "right_ankle": "foot.R"}
SEGMENTS = (("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"), ("right_shoulder", "right_elbow"),
            ("right_elbow", "right_wrist"), ("left_hip", "left_knee"), ("left_knee", "left_ankle"),
            ("right_hip", "right_knee"), ("right_knee", "right_ankle"), ("right_shoulder", "left_shoulder"),
            ("right_hip", "left_hip"), ("mid_hip", "mid_shoulder"))
SMOOTH = 0.2     # weight of frame-to-frame rotation change (rad^2, per frame) against the misfit (per frame)
REST = 0.002     # weight of the rotations' size (rad^2): the rest pose where the landmarks say nothing
MIN_VISIBILITY = 0.3
LENGTH_RATIO = 1.35  # a bone this many times longer or shorter than its median: the frame is misread
CAMERA_TO_BODY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y down, z away) -> (x, y away, z up)


def _rodrigues(r: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [...,3,3] of axis-angle vectors [...,3] (differentiable at 0)."""
    theta2 = (r * r).sum(-1, keepdim=True)
    theta = torch.sqrt(theta2 + 1e-12)
    k = r / theta
    zero = torch.zeros_like(r[..., 0])
    kx = torch.stack([zero, -k[..., 2], k[..., 1], k[..., 2], zero, -k[..., 0], -k[..., 1], k[..., 0], zero], -1)
    kx = kx.reshape(*r.shape[:-1], 3, 3)
    s, c = torch.sin(theta)[..., None], torch.cos(theta)[..., None]
    eye = torch.eye(3, dtype=r.dtype).expand_as(kx)
    return eye + s * kx + (1 - c) * (kx @ kx)


class Skeleton:
    """The chain from the root to the landmarks' joints of one body, posed for many frames."""

    def __init__(self, shape):
        labels, parents = list(shape.bone_labels), list(shape.bone_parents)
        missing = [b for b in FITTED_BONES + tuple(JOINTS.values()) if b not in labels]
        if missing:
            raise TryonError(f"the body's skeleton lacks the bones {missing}")
        chain: set[int] = set()
        for name in JOINTS.values():
            j = labels.index(name)
            while j >= 0:
                chain.add(j)
                j = parents[j]
        self.order = sorted(chain, key=lambda j: self._depth(j, parents))
        self.parents = parents
        self.heads = shape.bone_heads.detach().to(torch.float64)
        self.fitted = [labels.index(b) for b in FITTED_BONES]
        self.joint = {lm: labels.index(b) for lm, b in JOINTS.items()}

    @staticmethod
    def _depth(j: int, parents: list[int]) -> int:
        d = 0
        while parents[j] >= 0:
            j, d = parents[j], d + 1
        return d

    def joints(self, rotations: torch.Tensor) -> dict[str, torch.Tensor]:
        """Landmark name -> its joint's position [T,3] for fitted-bone axis-angles [T,B,3]."""
        T = rotations.shape[0]
        R = _rodrigues(rotations)
        local_R = {j: R[:, i] for i, j in enumerate(self.fitted)}
        G: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
        eye = torch.eye(3, dtype=torch.float64).expand(T, 3, 3)
        for j in self.order:
            Rj = local_R.get(j, eye)
            h = self.heads[j]
            tj = h - torch.einsum("tab,b->ta", Rj, h)
            p = self.parents[j]
            if p < 0:
                G[j] = (Rj, tj)
            else:
                Rp, tp = G[p]
                G[j] = (Rp @ Rj, torch.einsum("tab,tb->ta", Rp, tj) + tp)
        return {lm: torch.einsum("tab,b->ta", G[j][0], self.heads[j]) + G[j][1] for lm, j in self.joint.items()}


def _with_mids(points: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    out = dict(points)
    out["mid_hip"] = (points["left_hip"] + points["right_hip"]) / 2
    out["mid_shoulder"] = (points["left_shoulder"] + points["right_shoulder"]) / 2
    return out


def landmark_directions(world: np.ndarray, visibility: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions [T,S,3] of the SEGMENTS in body axes and their weights [T,S]."""
    w = np.asarray(world, dtype=np.float64) @ CAMERA_TO_BODY.T
    pts = {name: w[:, K[name]] for name in JOINTS}
    pts["mid_hip"] = (pts["left_hip"] + pts["right_hip"]) / 2
    pts["mid_shoulder"] = (pts["left_shoulder"] + pts["right_shoulder"]) / 2
    vis = {name: np.asarray(visibility)[:, K[name]] for name in JOINTS}
    vis["mid_hip"] = np.minimum(vis["left_hip"], vis["right_hip"])
    vis["mid_shoulder"] = np.minimum(vis["left_shoulder"], vis["right_shoulder"])
    d = np.stack([pts[b] - pts[a] for a, b in SEGMENTS], 1)
    d /= np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    weight = np.stack([np.minimum(vis[a], vis[b]) for a, b in SEGMENTS], 1)
    weight = np.where(weight >= MIN_VISIBILITY, weight, 0.0)
    return d, weight * ~misread_frames(pts)[:, None]


def misread_frames(pts: dict[str, np.ndarray]) -> np.ndarray:
    """Bool [T]: frames whose landmarks the finder misread, told by a bone or a side of
    the torso whose length is off the clip's median by more than LENGTH_RATIO either way
    (a person's bones keep their length; a misread frame folds the torso or a leg).
    Clips shorter than 5 frames keep every frame."""
    pairs = [(a, b) for a, b in SEGMENTS if "mid" not in a] + [("left_shoulder", "left_hip"),
                                                              ("right_shoulder", "right_hip")]
    lengths = np.stack([np.linalg.norm(pts[b] - pts[a], axis=-1) for a, b in pairs], 1)
    found = (lengths > 1e-9).any(axis=1)  # frames without the person hold no landmarks: not misread, not counted
    if found.sum() < 5:
        return np.zeros(len(lengths), bool)
    ratio = lengths / np.maximum(np.median(lengths[found], axis=0), 1e-9)
    return found & ((ratio < 1 / LENGTH_RATIO) | (ratio > LENGTH_RATIO)).any(axis=1)


def _initial_yaw(skeleton: Skeleton, directions: np.ndarray) -> np.ndarray:
    """Per frame the turn about the vertical that lays the rest body's hip line (or, where
    the hips are seen edge-on, its shoulder line) on the landmarks'."""
    rest = _with_mids(skeleton.joints(torch.zeros(1, len(FITTED_BONES), 3, dtype=torch.float64)))
    hip = (rest["left_hip"] - rest["right_hip"])[0].numpy()
    a0 = np.arctan2(hip[1], hip[0])
    hips = directions[:, SEGMENTS.index(("right_hip", "left_hip"))]
    shoulders = directions[:, SEGMENTS.index(("right_shoulder", "left_shoulder"))]
    edge_on = np.linalg.norm(hips[:, :2], axis=-1) < 0.3  # the hip line points at the camera (or is unseen)
    seen = np.where(edge_on[:, None], shoulders, hips)
    yaw = np.arctan2(seen[:, 1], seen[:, 0]) - a0
    ok = np.linalg.norm(seen[:, :2], axis=-1) > 0.3
    if not ok.any():
        return np.zeros(len(seen))
    frames = np.arange(len(seen))
    return np.interp(frames, frames[ok], np.unwrap(yaw[ok]))  # frames without hips: their neighbours' turn


def fit_motion(shape, world: np.ndarray, visibility: np.ndarray, fps: float, iterations: int = 60,
               name: str = "from video"):
    """The `BodyMotion` of `shape` (bones FITTED_BONES) that follows BlazePose world
    landmarks `world` [T,33,3] with `visibility` [T,33], at `fps`; and the mean angle (deg)
    between the body's segments and the landmarks' over the visible ones."""
    from tryon.body.motion_data import BodyMotion

    world = np.asarray(world, dtype=np.float64)
    if world.ndim != 3 or world.shape[1:] != (33, 3) or len(world) < 1:
        raise TryonError(f"landmarks must be [frames, 33, 3], got {world.shape}")
    skeleton = Skeleton(shape)
    target, weight = landmark_directions(world, visibility)
    if not (weight > 0).any():
        raise TryonError("no limb of the person is visible enough to follow")
    T = len(world)
    rot = torch.zeros(T, len(FITTED_BONES), 3, dtype=torch.float64)
    rot[:, 0, 2] = torch.from_numpy(_initial_yaw(skeleton, target * (weight[..., None] > 0)))
    rot.requires_grad_(True)
    tgt, wgt = torch.from_numpy(target), torch.from_numpy(weight)
    opt = torch.optim.LBFGS([rot], lr=1.0, max_iter=iterations, line_search_fn="strong_wolfe")

    def misfit(r: torch.Tensor) -> torch.Tensor:
        pts = _with_mids(skeleton.joints(r))
        d = torch.stack([pts[b] - pts[a] for a, b in SEGMENTS], 1)
        d = d / torch.sqrt((d * d).sum(-1, keepdim=True) + 1e-12)
        return (wgt * ((d - tgt) ** 2).sum(-1)).sum() / T

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = misfit(rot) + SMOOTH * ((rot[1:] - rot[:-1]) ** 2).sum() / max(T - 1, 1) \
            + REST * (rot[:, 1:] ** 2).sum() / T
        loss.backward()
        return loss

    opt.step(closure)
    r = rot.detach()
    with torch.no_grad():
        pts = _with_mids(skeleton.joints(r))
        d = torch.stack([pts[b] - pts[a] for a, b in SEGMENTS], 1)
        d = d / d.norm(dim=-1, keepdim=True)
        angle = torch.rad2deg(torch.arccos((d * tgt).sum(-1).clamp(-1, 1)))
        mean_deg = float((angle * wgt).sum() / wgt.sum())
    return BodyMotion(r.numpy(), list(FITTED_BONES), fps, None, name), mean_deg


def body_travel(shape, motion, keypoints: np.ndarray, visibility: np.ndarray) -> tuple[np.ndarray, float]:
    """The body's travel [T,3] (m, x right, z up, from the first frame; none in depth) that
    lays the posed joints of `motion` on the person's 2D keypoints [T,33,2] (px, y down)
    seen by a still camera: one scale (px per m) for the clip and an offset per frame,
    by least squares over the visible joints (`visibility` [T,33] >= 0.5). Frames with no
    visible joint take their neighbours' travel. Returns the travel and the scale."""
    skeleton = Skeleton(shape)
    rot = np.zeros((motion.num_frames, len(FITTED_BONES), 3))
    for i, bone in enumerate(FITTED_BONES):
        if bone in motion.bone_labels:
            rot[:, i] = motion.rotations[:, motion.bone_labels.index(bone)]
    with torch.no_grad():
        joints = skeleton.joints(torch.from_numpy(rot))
    names = list(JOINTS)
    P = np.stack([joints[n].numpy() for n in names], 1)                # [T,J,3] body axes
    kp = np.asarray(keypoints, np.float64)[:, [K[n] for n in names]]    # [T,J,2]
    w = (np.asarray(visibility)[:, [K[n] for n in names]] >= 0.5).astype(float)
    seen = w.sum(1) >= 3
    if not seen.any():
        raise TryonError("too few joints are visible to follow the body's travel")
    W = np.where(seen[:, None], w, 0.0)
    n = np.maximum(W.sum(1, keepdims=True), 1e-9)

    def centred(a: np.ndarray) -> np.ndarray:
        return a - (W * a).sum(1, keepdims=True) / n

    dX, dZ, dx, dy = centred(P[..., 0]), centred(P[..., 2]), centred(kp[..., 0]), centred(kp[..., 1])
    scale = float((W * (dx * dX - dy * dZ)).sum() / max((W * (dX ** 2 + dZ ** 2)).sum(), 1e-12))
    if not scale > 0:
        raise TryonError("the body's joints cannot be laid on the person's keypoints (no positive scale fits)")
    ox = ((W * (kp[..., 0] - scale * P[..., 0])).sum(1) / n[:, 0])
    oy = ((W * (kp[..., 1] + scale * P[..., 2])).sum(1) / n[:, 0])
    frames = np.arange(len(kp))
    ox, oy = (np.interp(frames, frames[seen], o[seen]) for o in (ox, oy))
    travel = np.stack([(ox - ox[0]) / scale, np.zeros(len(ox)), -(oy - oy[0]) / scale], 1)
    return smoothed(travel), scale


def smoothed(x: np.ndarray, window: int = 7) -> np.ndarray:
    """`x` [T,...] through a Savitzky-Golay filter (quadratic, `window` frames): keypoint
    jitter of a few pixels is centimetres a frame, metres a second of false speed."""
    from scipy.signal import savgol_filter

    w = min(window, len(x) - (1 - len(x) % 2))  # odd, at most the frames there are
    if w < 5:
        return x
    return savgol_filter(x, w, 2, axis=0, mode="interp")


def motion_of_person(shape, people: list, fps: float, name: str = "from video"):
    """The motion of `shape` following a person through the frames of a clip (`people`:
    per frame a `PersonInPhoto`, or None where the person was not found), travel
    included; and the mean angle (deg) between the body's segments and the landmarks'."""
    from tryon.body.motion_data import BodyMotion

    if not any(p is not None for p in people):
        raise TryonError("the person is not found in any frame")
    world = np.stack([p.world if p is not None else np.zeros((33, 3)) for p in people])
    visibility = np.stack([p.visibility if p is not None else np.zeros(33) for p in people])
    keypoints = np.stack([p.keypoints / p.scale if p is not None else np.zeros((33, 2)) for p in people])
    motion, mean_deg = fit_motion(shape, world, visibility, fps, name=name)
    travel, _ = body_travel(shape, motion, keypoints, visibility)
    return BodyMotion(motion.rotations, motion.bone_labels, fps, travel, name), mean_deg


def camera_heading(motion) -> float:
    """The body's heading (rad, about the vertical) at the first frame of `motion` as read
    from a video: what `facing_forward` takes out."""
    from tryon.body.pose import axis_angle

    R = axis_angle(motion.rotations[:1, motion.bone_labels.index("root")])
    return float(np.arctan2(R[0, 1, 0], R[0, 0, 0]))


def facing_forward(motion):
    """`motion` turned about the vertical so that the body faces at its first frame as it
    does at rest (the camera's view of the person is taken out; the motion then starts
    from the rest orientation, as the built-in motions do)."""
    from tryon.body.motion_data import BodyMotion
    from tryon.body.pose import axis_angle, matrix_to_axis_angle

    root = motion.bone_labels.index("root")
    R = axis_angle(motion.rotations[:, root])
    heading = camera_heading(motion)
    c, s = np.cos(-heading), np.sin(-heading)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    rotations = motion.rotations.copy()
    rotations[:, root] = matrix_to_axis_angle(turn @ R)
    return BodyMotion(rotations, list(motion.bone_labels), motion.fps, motion.root_translation @ turn.T, motion.name)


@dataclass
class VideoMotion:
    """A person's motion read from a video, with what it was read from."""

    motion: object          # BodyMotion, as seen by the camera (`facing_forward` turns it to the rest heading)
    shape: object           # the body it was fitted on
    frames: Frames
    people: list            # per frame the followed PersonInPhoto, or None
    mean_angle_deg: float
    misread: int            # frames whose landmarks were misread (left to their neighbours)
    seconds: float

    def report(self) -> dict:
        seen = [k for k, p in enumerate(self.people) if p is not None]
        travel = self.motion.root_translation[seen[-1]] - self.motion.root_translation[seen[0]]
        span = float(self.frames.times[seen[-1]] - self.frames.times[seen[0]])
        return {"source": self.frames.source, "frames": len(self.people), "fps": self.motion.fps,
                "followed_frames": len(seen), "misread_frames": self.misread,
                "mean_angle_deg": self.mean_angle_deg, "travel_m": travel.tolist(),
                "speed_m_s": float(np.linalg.norm(travel) / span) if span > 0 else 0.0,
                "duration_s": self.motion.duration, "seconds": self.seconds}


def read_video_motion(source, shape, fps: float = 15.0, start_s: float = 0.0, end_s: float | None = None,
                      min_frames: int = 5, folder_fps: float = 5.0) -> VideoMotion:
    """The motion of the person followed through `source` (a video file, or a folder of
    frames taken `folder_fps` apart) between `start_s` and `end_s`, fitted on `shape`."""
    import time

    t0 = time.perf_counter()
    frames = read_frames(source, fps=fps, folder_fps=folder_fps, start_s=start_s, end_s=end_s)
    keep = [k for k, t in enumerate(frames.times) if t >= start_s - 1e-9 and (end_s is None or t <= end_s + 1e-9)]
    if len(keep) < min_frames:
        raise TryonError(f"{source}: {len(keep)} frames between {start_s:g} s and "
                         f"{'the end' if end_s is None else f'{end_s:g} s'} at {fps:g} fps; at least {min_frames} needed")
    frames = Frames([frames.images[k] for k in keep], frames.times[keep] - frames.times[keep[0]], frames.source)
    people = follow_person(frames)
    seen = sum(p is not None for p in people)
    if seen < min_frames:
        raise TryonError(f"{source}: the person is followed in only {seen} of {len(people)} frames; at least "
                         f"{min_frames} needed")
    motion, deg = motion_of_person(shape, people, frames.fps)  # the rate the frames have, not the one asked for
    pts = {n: np.stack([p.world[K[n]] if p is not None else np.zeros(3) for p in people]) for n in JOINTS}
    misread = int((misread_frames(pts) & np.array([p is not None for p in people])).sum())
    return VideoMotion(motion, shape, frames, people, deg, misread, time.perf_counter() - t0)


def motion_picture(vm: VideoMotion, count: int = 6, height: int = 260) -> np.ndarray:
    """`count` followed frames, each with its keypoints beside the fitted body seen from
    the camera's side (RGB uint8, two rows)."""
    from PIL import Image, ImageDraw

    from tryon.body.pose import posed_vertices
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes

    seen = [k for k, p in enumerate(vm.people) if p is not None]
    poses = vm.motion.pose_matrices(vm.shape)
    faces = np.asarray(vm.shape.faces)
    tiles = []
    for k in (seen[int(i)] for i in np.linspace(0, len(seen) - 1, min(count, len(seen)))):
        p = vm.people[k]
        img = Image.fromarray(p.image)
        draw = ImageDraw.Draw(img)
        for x, y in p.keypoints:
            draw.ellipse((x - 2, y - 2, x + 2, y + 2), fill=(0, 255, 0))
        x0, y0, x1, y1 = p.box
        pad = (y1 - y0) // 15
        crop = img.crop((max(0, x0 - pad), max(0, y0 - pad), x1 + pad, y1 + pad))
        crop = np.asarray(crop.resize((max(1, int(crop.width * height / crop.height)), height)))
        v = posed_vertices(vm.shape, poses[k]).detach().numpy()
        c = (v.min(0) + v.max(0)) / 2
        cam = Camera(eye=(c[0], c[1] - 6.0, c[2]), target=tuple(c), fov_deg=20)
        tiles.append(np.hstack([crop, render_meshes([RenderMesh(v, faces, color=(0.75, 0.7, 0.65))], 200, height,
                                                    cam)]))
    width = max(t.shape[1] for t in tiles)
    tiles = [np.pad(t, ((0, 0), (0, width - t.shape[1]), (0, 0)), constant_values=255) for t in tiles]
    half = (len(tiles) + 1) // 2
    rows = [np.hstack(tiles[:half]), np.hstack(tiles[half:])] if len(tiles) > 1 else [tiles[0]]
    wide = max(r.shape[1] for r in rows)
    return np.vstack([np.pad(r, ((0, 0), (0, wide - r.shape[1]), (0, 0)), constant_values=255) for r in rows])
