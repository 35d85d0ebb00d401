"""BVH motion capture files (Biovision hierarchy) and their retargeting onto Anny.

`load_bvh` parses the skeleton (joint offsets, channels) and the per-frame channel
values; `retarget` turns it into a `BodyMotion` for an Anny body:

1. Each BVH joint's world rotation W_j(t) (parent chain of its Euler rotations, in the
   order of its channels) is taken to Anny's frame: BVH files are Y-up with the
   character facing +Z and its left on +X; Anny is Z-up facing -Y with its left on +X,
   so C maps (x, y, z) to (x, -z, y) and the world change is D_j(t) = C W_j(t) C^T.
2. The BVH rest pose (all channels zero) need not match Anny's rest pose (mocap rests
   in a T-pose, Anny's arms hang 45 degrees down): each mapped Anny bone first turns so
   that it points like its BVH bone at rest (A_b, the smallest rotation between the two
   bone directions), then follows the BVH joint: world rotation D_j(t) A_b.
3. Bones the BVH does not drive keep their parent's rotation; local rotations in the
   pose convention of `tryon.body.pose` are R_b = W_parent(b)^T W_b.
4. The root translation follows the BVH root's displacement from frame 0, scaled by the
   ratio of Anny's to the BVH skeleton's hip height (`in_place` drops its horizontal part).

`BONE_MAP` names the Anny bone for common joint names (Mixamo / CMU / Motionbuilder).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tryon.body.anny_model import BodyShape
from tryon.body.motion_data import BodyMotion
from tryon.body.pose import bone_transforms, children_order, matrix_to_axis_angle, rotation_between
from tryon.errors import InputFileError, TryonError
from tryon.limits import LIMITS, check_file_size, check_limit

# BVH joint name (lower case, without "mixamorig:" prefixes) -> Anny bone
BONE_MAP = {
    "hips": "root", "hip": "root", "pelvis": "root",
    "spine": "spine04", "abdomen": "spine04", "spine1": "spine03", "chest": "spine02", "spine2": "spine02", "spine3": "spine01",
    "neck": "neck01", "neck1": "neck01", "head": "head",
    "leftshoulder": "clavicle.L", "lcollar": "clavicle.L", "leftcollar": "clavicle.L",
    "leftarm": "upperarm01.L", "lshldr": "upperarm01.L", "leftupperarm": "upperarm01.L", "leftuparm": "upperarm01.L",
    "leftforearm": "lowerarm01.L", "lforearm": "lowerarm01.L", "leftlowerarm": "lowerarm01.L",
    "lefthand": "wrist.L", "lhand": "wrist.L",
    "rightshoulder": "clavicle.R", "rcollar": "clavicle.R", "rightcollar": "clavicle.R",
    "rightarm": "upperarm01.R", "rshldr": "upperarm01.R", "rightupperarm": "upperarm01.R", "rightuparm": "upperarm01.R",
    "rightforearm": "lowerarm01.R", "rforearm": "lowerarm01.R", "rightlowerarm": "lowerarm01.R",
    "righthand": "wrist.R", "rhand": "wrist.R",
    "leftupleg": "upperleg01.L", "lthigh": "upperleg01.L", "leftupperleg": "upperleg01.L", "lefthip": "upperleg01.L",
    "leftleg": "lowerleg01.L", "lshin": "lowerleg01.L", "leftlowerleg": "lowerleg01.L", "leftknee": "lowerleg01.L",
    "leftfoot": "foot.L", "lfoot": "foot.L", "leftankle": "foot.L",
    "rightupleg": "upperleg01.R", "rthigh": "upperleg01.R", "rightupperleg": "upperleg01.R", "righthip": "upperleg01.R",
    "rightleg": "lowerleg01.R", "rshin": "lowerleg01.R", "rightlowerleg": "lowerleg01.R", "rightknee": "lowerleg01.R",
    "rightfoot": "foot.R", "rfoot": "foot.R", "rightankle": "foot.R",
}
# The child whose head gives an Anny bone's direction (for the rest alignment)
ANNY_CHILD = {
    "root": "spine04", "spine04": "spine03", "spine03": "spine02", "spine02": "spine01", "spine01": "neck01",
    "neck01": "head", "clavicle.L": "upperarm01.L", "upperarm01.L": "lowerarm01.L", "lowerarm01.L": "wrist.L",
    "clavicle.R": "upperarm01.R", "upperarm01.R": "lowerarm01.R", "lowerarm01.R": "wrist.R",
    "upperleg01.L": "lowerleg01.L", "lowerleg01.L": "foot.L", "upperleg01.R": "lowerleg01.R", "lowerleg01.R": "foot.R",
}
BVH_TO_ANNY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass
class BvhJoint:
    name: str
    parent: int
    offset: np.ndarray
    channels: list[str]
    end_offset: np.ndarray | None = None


@dataclass
class Bvh:
    joints: list[BvhJoint]
    frame_time: float
    values: np.ndarray  # [T, total channels]
    source: str = "bvh"


MIN_FRAME_TIME = 1e-3  # s (1000 frames per second)
MAX_FRAME_TIME = 1.0  # s
CHANNEL_NAMES = {f"{axis}{kind}" for axis in "xyz" for kind in ("position", "rotation")}


def load_bvh(path: str | Path, allow_large: bool | None = None) -> Bvh:
    path = Path(path)
    check_file_size(path, "BVH file", allow_large)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"BVH file {path}: cannot be read ({exc})") from exc
    return parse_bvh(text, str(path), allow_large)


class _Tokens:
    """The BVH text as tokens, with errors that name the file and what was expected."""

    def __init__(self, text: str, source: str) -> None:
        self.items = re.findall(r"[^\s{}]+|[{}]", text)
        self.source = source
        self.i = 0

    def more(self) -> bool:
        return self.i < len(self.items)

    def peek(self) -> str:
        return self.items[self.i].upper() if self.more() else ""

    def take(self, what: str) -> str:
        if not self.more():
            raise InputFileError(f"{self.source}: the file ends early (expected {what}); the BVH file is truncated")
        self.i += 1
        return self.items[self.i - 1]

    def number(self, what: str) -> float:
        token = self.take(what)
        try:
            value = float(token)
        except ValueError:
            raise InputFileError(f"{self.source}: expected {what}, got {token!r}") from None
        if not np.isfinite(value):
            raise InputFileError(f"{self.source}: {what} must be finite, got {token!r}")
        return value

    def integer(self, what: str) -> int:
        token = self.take(what)
        if not re.fullmatch(r"[+-]?\d{1,12}", token):
            raise InputFileError(f"{self.source}: expected {what} (a whole number), got {token!r}")
        return int(token)

    def keyword(self, word: str) -> None:
        token = self.take(f"'{word}'")
        if token.upper() != word.upper():
            raise InputFileError(f"{self.source}: expected '{word}', got {token!r}")


def parse_bvh(text: str, source: str = "bvh", allow_large: bool | None = None) -> Bvh:
    """Skeleton and frames of a BVH text; every malformed, truncated or absurd file raises
    `InputFileError` (or `LimitError` for sizes beyond `tryon.limits`)."""
    tok = _Tokens(text, source)
    if tok.peek() != "HIERARCHY":
        raise InputFileError(f"{source}: not a BVH file (it must start with HIERARCHY)")
    tok.take("HIERARCHY")
    joints = _parse_hierarchy(tok, allow_large)
    tok.keyword("MOTION")
    tok.keyword("Frames:")
    frames = tok.integer("the frame count after 'Frames:'")
    tok.keyword("Frame")
    tok.keyword("Time:")
    frame_time = tok.number("the frame time (s) after 'Frame Time:'")
    if not MIN_FRAME_TIME <= frame_time <= MAX_FRAME_TIME:
        raise InputFileError(f"{source}: Frame Time must lie in [{MIN_FRAME_TIME}, {MAX_FRAME_TIME}] s "
                             f"(1 to 1000 frames per second), got {frame_time:g}")
    if frames < 1:
        raise InputFileError(f"{source}: Frames must be at least 1, got {frames}")
    check_limit(f"{source}: frames", frames, LIMITS.max_frames, "max_frames", allow_large)
    check_limit(f"{source}: estimated memory of retargeting (bytes)", 300 * frames * len(joints),
                LIMITS.max_memory_bytes, "max_memory_bytes", allow_large)
    width = sum(len(j.channels) for j in joints)
    rest = tok.items[tok.i:]
    if len(rest) != frames * width:
        raise InputFileError(f"{source}: expected {frames} frames of {width} channel values, found {len(rest)} numbers"
                             " (truncated file, or a wrong Frames: count)")
    try:
        numbers = np.array(rest, dtype=np.float64)
    except ValueError:
        raise InputFileError(f"{source}: the MOTION section holds something that is not a number") from None
    if not np.isfinite(numbers).all():
        raise InputFileError(f"{source}: the MOTION section holds NaN or infinite values")
    return Bvh(joints, frame_time, numbers.reshape(frames, width), source)


def _parse_hierarchy(tok: _Tokens, allow_large: bool | None) -> list[BvhJoint]:
    source = tok.source
    joints: list[BvhJoint] = []
    stack: list[int] = []  # open blocks: a joint index, or -1 for an End Site
    pending: int | None = None  # the block the next '{' opens
    while tok.more() and tok.peek() != "MOTION":
        word = tok.take("a HIERARCHY keyword").upper()
        if word in ("ROOT", "JOINT"):
            if (word == "ROOT") == bool(stack) or (stack and stack[-1] < 0):
                raise InputFileError(f"{source}: {word} in the wrong place (ROOT opens the skeleton, JOINT lies inside a joint)")
            joints.append(BvhJoint(tok.take("a joint name"), stack[-1] if stack else -1, np.zeros(3), []))
            check_limit(f"{source}: joints", len(joints), LIMITS.max_joints, "max_joints", allow_large)
            pending = len(joints) - 1
        elif word == "END":
            tok.keyword("Site")
            if not stack or stack[-1] < 0:
                raise InputFileError(f"{source}: 'End Site' outside a joint")
            pending = -1
        elif word == "{":
            if pending is None:
                raise InputFileError(f"{source}: '{{' without a ROOT, JOINT or End Site before it")
            stack.append(pending)
            pending = None
        elif word == "}":
            if not stack:
                raise InputFileError(f"{source}: unbalanced '}}' in HIERARCHY")
            stack.pop()
        elif word == "OFFSET":
            if not stack:
                raise InputFileError(f"{source}: OFFSET outside a joint block")
            off = np.array([tok.number("an OFFSET coordinate") for _ in range(3)])
            if stack[-1] >= 0:
                joints[stack[-1]].offset = off
            else:
                joints[stack[-2]].end_offset = off
        elif word == "CHANNELS":
            _parse_channels(tok, joints, stack)
        else:
            raise InputFileError(f"{source}: unexpected token {tok.items[tok.i - 1]!r} in HIERARCHY")
    if not tok.more():
        raise InputFileError(f"{source}: no MOTION section (the file is truncated)")
    if stack or not joints:
        raise InputFileError(f"{source}: the HIERARCHY is incomplete ({len(stack)} unclosed blocks, {len(joints)} joints)")
    return joints


def _parse_channels(tok: _Tokens, joints: list[BvhJoint], stack: list[int]) -> None:
    source = tok.source
    if not stack or stack[-1] < 0:
        raise InputFileError(f"{source}: CHANNELS outside a joint block")
    n = tok.integer("the channel count after CHANNELS")
    if not 0 <= n <= 6:
        raise InputFileError(f"{source}: a joint has 0 to 6 CHANNELS, got {n}")
    names = [tok.take("a channel name") for _ in range(n)]
    bad = [c for c in names if c.lower() not in CHANNEL_NAMES]
    if bad:
        raise InputFileError(f"{source}: unknown channel {bad[0]!r}; use Xposition .. Zrotation")
    joints[stack[-1]].channels = names


def _axis_rotation(axis: str, deg: np.ndarray) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    k = "XYZ".index(axis)
    i, j = [(1, 2), (2, 0), (0, 1)][k]
    R[..., k, k] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


def joint_world(bvh: Bvh) -> tuple[np.ndarray, np.ndarray]:
    """World rotations [T,J,3,3] of every BVH joint and the root positions [T,3]."""
    T, J = len(bvh.values), len(bvh.joints)
    local = np.tile(np.eye(3), (T, J, 1, 1))
    root_pos = np.zeros((T, 3))
    col = 0
    for j, joint in enumerate(bvh.joints):
        for ch in joint.channels:
            v = bvh.values[:, col]
            col += 1
            kind = ch.lower()
            if kind.endswith("rotation"):
                local[:, j] = local[:, j] @ _axis_rotation(kind[0].upper(), v)
            elif kind.endswith("position") and joint.parent < 0:
                root_pos[:, "xyz".index(kind[0])] = v
    world = np.empty_like(local)
    for j in children_order([jt.parent for jt in bvh.joints]):
        p = bvh.joints[j].parent
        world[:, j] = local[:, j] if p < 0 else world[:, p] @ local[:, j]
    return world, root_pos


def _bvh_rest_heads(bvh: Bvh) -> np.ndarray:
    heads = np.zeros((len(bvh.joints), 3))
    for j in children_order([jt.parent for jt in bvh.joints]):
        p = bvh.joints[j].parent
        heads[j] = bvh.joints[j].offset + (heads[p] if p >= 0 else 0.0)
    return heads


def bone_mapping(bvh: Bvh, shape: BodyShape) -> dict[str, int]:
    """Anny bone -> BVH joint index for the joints `BONE_MAP` recognises."""
    out: dict[str, int] = {}
    for j, joint in enumerate(bvh.joints):
        key = joint.name.lower().split(":")[-1].replace("_", "").replace(" ", "")
        bone = BONE_MAP.get(key)
        if bone is not None and bone in shape.bone_labels and bone not in out:
            out[bone] = j
    if "root" not in out:
        raise TryonError(f"{bvh.source}: no hips/root joint recognised; joint names: {[j.name for j in bvh.joints][:8]}")
    return out


def retarget(bvh: Bvh, shape: BodyShape, in_place: bool = False) -> BodyMotion:
    """The BVH motion as a `BodyMotion` on `shape` (see the module docstring)."""
    mapping = bone_mapping(bvh, shape)
    world, root_pos = joint_world(bvh)
    C = BVH_TO_ANNY
    delta = np.einsum("ab,tjbc,dc->tjad", C, world, C)  # C W C^T
    heads = _bvh_rest_heads(bvh) @ C.T
    child_of = {}
    for j, joint in enumerate(bvh.joints):
        if joint.parent >= 0:
            child_of.setdefault(joint.parent, j)
    T, labels = len(world), shape.bone_labels
    W = np.tile(np.eye(3), (T, len(labels), 1, 1))
    align = {}
    for bone, j in mapping.items():
        child = ANNY_CHILD.get(bone)
        if child is None or j not in child_of or child not in labels:
            align[bone] = np.eye(3)
            continue
        d_bvh = heads[child_of[j]] - heads[j]
        d_anny = shape.head(child) - shape.head(bone)
        align[bone] = rotation_between(d_anny, d_bvh) if np.linalg.norm(d_bvh) > 1e-9 else np.eye(3)
    parents = shape.bone_parents
    for b in children_order(parents):
        lab = labels[b]
        if lab in mapping:
            W[:, b] = delta[:, mapping[lab]] @ align[lab]
        elif parents[b] >= 0:
            W[:, b] = W[:, parents[b]]
    local = np.empty_like(W)
    for b in range(len(labels)):
        p = parents[b]
        local[:, b] = W[:, b] if p < 0 else np.einsum("tba,tbc->tac", W[:, p], W[:, b])
    hip_bvh = max(float(heads[mapping["root"]][2] - heads[:, 2].min()), 1e-9)
    scale = float(shape.head("root")[2]) / hip_bvh
    trans = (root_pos - root_pos[0]) @ C.T * scale
    if in_place:
        trans[:, :2] = 0.0
    moved = np.abs(local - np.eye(3)).max(axis=(0, 2, 3)) > 1e-12
    moved[0] = True
    return BodyMotion(matrix_to_axis_angle(local[:, moved]), [labels[b] for b in np.flatnonzero(moved)],
                      1.0 / bvh.frame_time, trans, Path(bvh.source).stem)


def motion_to_bvh(motion: BodyMotion, shape: BodyShape) -> str:
    """A BVH text of `motion` on a skeleton of `shape`'s main bones (the ones in
    `ANNY_CHILD`, joint names from `BONE_MAP`), for other tools and round trips."""
    names = {"root": "Hips", "spine04": "Spine", "spine03": "Spine1", "spine02": "Spine2", "spine01": "Spine3", "neck01": "Neck",
             "head": "Head", "clavicle.L": "LeftShoulder", "upperarm01.L": "LeftArm", "lowerarm01.L": "LeftForeArm",
             "wrist.L": "LeftHand", "clavicle.R": "RightShoulder", "upperarm01.R": "RightArm", "lowerarm01.R": "RightForeArm",
             "wrist.R": "RightHand", "upperleg01.L": "LeftUpLeg", "lowerleg01.L": "LeftLeg", "foot.L": "LeftFoot",
             "upperleg01.R": "RightUpLeg", "lowerleg01.R": "RightLeg", "foot.R": "RightFoot"}
    parent = {"spine04": "root", "spine03": "spine04", "spine02": "spine03", "spine01": "spine02", "neck01": "spine01",
              "head": "neck01", "clavicle.L": "spine01", "upperarm01.L": "clavicle.L", "lowerarm01.L": "upperarm01.L",
              "wrist.L": "lowerarm01.L", "clavicle.R": "spine01", "upperarm01.R": "clavicle.R", "lowerarm01.R": "upperarm01.R",
              "wrist.R": "lowerarm01.R", "upperleg01.L": "root", "lowerleg01.L": "upperleg01.L", "foot.L": "lowerleg01.L",
              "upperleg01.R": "root", "lowerleg01.R": "upperleg01.R", "foot.R": "lowerleg01.R"}
    order = list(names)
    R = motion.pose_matrices(shape)
    Cinv = BVH_TO_ANNY.T
    lines = ["HIERARCHY"]

    def emit(bone: str, depth: int) -> None:
        pad = "  " * depth
        off = (shape.head(bone) - (shape.head(parent[bone]) if bone in parent else 0.0)) @ Cinv.T * 100.0
        kind = "ROOT" if bone == "root" else "JOINT"
        lines.append(f"{pad}{kind} {names[bone]}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {off[0]:.5f} {off[1]:.5f} {off[2]:.5f}")
        chans = "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if bone == "root" else "3 Zrotation Xrotation Yrotation"
        lines.append(f"{pad}  CHANNELS {chans}")
        kids = [b for b in order if parent.get(b) == bone]
        for k in kids:
            emit(k, depth + 1)
        if not kids:
            lines.append(f"{pad}  End Site")
            lines.append(pad + "  {")
            lines.append(f"{pad}    OFFSET 0 0 0")
            lines.append(pad + "  }")
        lines.append(pad + "}")

    emit("root", 0)
    rows = []
    emitted = []

    def collect(bone: str) -> None:
        emitted.append(bone)
        for k in [b for b in order if parent.get(b) == bone]:
            collect(k)

    collect("root")
    for t in range(motion.num_frames):
        G = bone_transforms(shape, R[t]).numpy()[:, :3, :3]
        vals = list((motion.root_translation[t] @ Cinv.T) * 100.0)
        for bone in emitted:
            Wb = G[shape.bone(bone)]
            Wp = G[shape.bone(parent[bone])] if bone in parent else np.eye(3)
            local = Cinv @ (Wp.T @ Wb) @ Cinv.T
            vals += list(_euler_zxy(local))
        rows.append(" ".join(f"{v:.6f}" for v in vals))
    lines += ["MOTION", f"Frames: {motion.num_frames}", f"Frame Time: {1.0 / motion.fps:.6f}"] + rows
    return "\n".join(lines) + "\n"


def _euler_zxy(R: np.ndarray) -> tuple[float, float, float]:
    """Angles (deg) z, x, y with R = Rz(z) Rx(x) Ry(y)."""
    x = np.arcsin(np.clip(R[2, 1], -1.0, 1.0))
    z = np.arctan2(-R[0, 1], R[1, 1])
    y = np.arctan2(-R[2, 0], R[2, 2])
    return float(np.degrees(z)), float(np.degrees(x)), float(np.degrees(y))
