"""Posing by forward kinematics and linear blend skinning, for the body and for any mesh
that borrows its skinning weights (a garment).

A pose is one rotation per bone, `rotations [J,3,3]`, each about the bone's head and
expressed in the world frame of the rest pose, applied parent first:
    G_j = G_parent(j) · T(h_j) · R_j · T(-h_j),   G_root = T(root_translation) · T(h_0) · R_0 · T(-h_0)
and a skinned point is x' = Σ_k w_k G_{b_k} x (Kavan et al. call this LBS). The identity
pose is Anny's rest pose. `a_pose` / `t_pose` straighten the elbows and raise the arms to
45 / 90 degrees from the body in the frontal plane; both stand the legs just far enough apart
that full thighs do not pass through each other (`clear_thighs`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch

from tryon.body.anny_model import BodyShape
from tryon.errors import TryonError

log = logging.getLogger(__name__)

ARM_SIDES = ("L", "R")
ARM_WORDS = ("upperarm", "lowerarm", "wrist", "finger", "metacarpal")
LEG_WORDS = ("upperleg", "lowerleg", "foot", "toe")  # Anny's .L bones lie at +x
POSES = {"a": 45.0, "t": 90.0, "rest": None}
# widest leg spread (degrees per leg, frontal plane) tried to part thighs that cross at rest:
# Anny's legs hang close, and a body fitted to real thigh girths from BMI about 30 has
# inner thighs through each other (2-6 degrees part those of BMI 35-45)
MAX_STANCE_DEG = 12.0
STANCE_STEP_DEG = 1.0


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation [3,3] taking direction a to direction b."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1 + 1e-12:
        axis = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        return axis_angle(axis / np.linalg.norm(axis) * np.pi)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def axis_angle(r: np.ndarray) -> np.ndarray:
    """Rotation matrices [...,3,3] from axis-angle vectors [...,3] (Rodrigues)."""
    r = np.asarray(r, dtype=np.float64)
    theta = np.linalg.norm(r, axis=-1, keepdims=True)
    k = r / np.maximum(theta, 1e-12)
    kx = np.zeros(r.shape[:-1] + (3, 3))
    kx[..., 0, 1], kx[..., 0, 2] = -k[..., 2], k[..., 1]
    kx[..., 1, 0], kx[..., 1, 2] = k[..., 2], -k[..., 0]
    kx[..., 2, 0], kx[..., 2, 1] = -k[..., 1], k[..., 0]
    s, c = np.sin(theta)[..., None], np.cos(theta)[..., None]
    return np.eye(3) + s * kx + (1 - c) * (kx @ kx)


def matrix_to_axis_angle(R: np.ndarray) -> np.ndarray:
    """Axis-angle vectors [...,3] of rotation matrices [...,3,3] (angles below pi)."""
    R = np.asarray(R, dtype=np.float64)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    theta = np.arccos(cos)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.sin(theta)
    scale = np.where(s > 1e-9, theta / np.maximum(2 * s, 1e-12), 0.5)
    return w * scale[..., None]


def identity_pose(shape: BodyShape) -> np.ndarray:
    return np.tile(np.eye(3), (len(shape.bone_labels), 1, 1))


def children_order(parents: list[int]) -> list[int]:
    """Bones sorted so that every parent comes before its children."""
    order, seen = [], set()

    def visit(j: int) -> None:
        if j in seen:
            return
        if parents[j] >= 0:
            visit(parents[j])
        seen.add(j)
        order.append(j)

    for j in range(len(parents)):
        visit(j)
    return order


def bone_transforms(shape: BodyShape, rotations, root_translation=None) -> torch.Tensor:
    """World transforms G [J,4,4] (torch, float64) of a pose (see the module docstring)."""
    R = torch.as_tensor(np.asarray(rotations) if not torch.is_tensor(rotations) else rotations, dtype=torch.float64)
    heads = shape.bone_heads.detach()
    J = len(shape.bone_labels)
    if R.shape != (J, 3, 3):
        raise TryonError(f"a pose needs one 3x3 rotation per bone ({J}), got shape {tuple(R.shape)}")
    local = torch.zeros((J, 4, 4), dtype=torch.float64)
    local[:, :3, :3] = R
    local[:, :3, 3] = heads - torch.einsum("jab,jb->ja", R, heads)
    local[:, 3, 3] = 1.0
    G = [None] * J
    for j in children_order(shape.bone_parents):
        p = shape.bone_parents[j]
        G[j] = local[j] if p < 0 else G[p] @ local[j]
    G = torch.stack(G)
    if root_translation is not None:
        G[:, :3, 3] += torch.as_tensor(np.asarray(root_translation), dtype=torch.float64)
    return G


def skin(points: torch.Tensor, weight_index: np.ndarray, weight: np.ndarray, G: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning of rest points [N,3] with per-point weights [N,K]."""
    idx = torch.from_numpy(np.asarray(weight_index, dtype=np.int64))
    w = torch.as_tensor(weight, dtype=torch.float64)
    M = (w[..., None, None] * G[idx]).sum(1)  # [N,4,4]
    return torch.einsum("nab,nb->na", M[:, :3, :3], points) + M[:, :3, 3]


def posed_vertices(shape: BodyShape, rotations, root_translation=None) -> torch.Tensor:
    return skin(shape.vertices, shape.weight_index, shape.weight, bone_transforms(shape, rotations, root_translation))


def arm_pose(shape: BodyShape, angle_deg: float) -> np.ndarray:
    """Rotations that straighten the elbows and put each arm (shoulder to wrist) at
    `angle_deg` from the body's downward axis, in the frontal (x-z) plane."""
    R = identity_pose(shape)
    heads = shape.bone_heads.detach().numpy()
    a = np.radians(angle_deg)
    for side, sign in zip(ARM_SIDES, (1.0, -1.0)):
        sh, el, wr = (shape.bone(f"{b}.{side}") for b in ("upperarm01", "lowerarm01", "wrist"))
        upper = heads[el] - heads[sh]
        lower = heads[wr] - heads[el]
        R_elbow = rotation_between(lower, upper)
        target = np.array([sign * np.sin(a), 0.0, -np.cos(a)])
        R_shoulder = rotation_between(upper, target)
        R[sh] = R_shoulder  # children compose as G_parent · local: the elbow straightens
        R[el] = R_elbow  # in the rest frame, then the whole arm turns at the shoulder
    return R


def leg_spread(shape: BodyShape, rotations: np.ndarray, deg: float) -> np.ndarray:
    """`rotations` with each leg turned `deg` outward at the hip, in the frontal plane."""
    R = np.array(rotations, copy=True)
    a = np.radians(deg)
    for side, sign in (("L", 1.0), ("R", -1.0)):  # about world y: -a takes -z towards +x
        hip = shape.bone(f"upperleg01.{side}")
        R[hip] = axis_angle(np.array([0.0, -sign * a, 0.0])) @ R[hip]
    return R


def thigh_crossings(vertices: np.ndarray, faces: np.ndarray, part: np.ndarray) -> int:
    """Edge-triangle intersections between the left and the right leg."""
    from tryon.sim.geometry import edge_face_intersections

    legs = [faces[(part[faces] == p).all(1)] for p in (3, 4)]
    edges = [np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])), axis=0) for f in legs]
    return (len(edge_face_intersections(vertices, edges[0], vertices, legs[1], False))
            + len(edge_face_intersections(vertices, edges[1], vertices, legs[0], False)))


def gap_between_thighs(vertices: np.ndarray, part: np.ndarray) -> float:
    """The smallest distance (m) between a left-leg and a right-leg vertex more than 2 cm
    below the crotch (the torso's lowest vertex): how much room the thighs leave for a
    trouser's inner legs. Higher up, both legs meet the torso at the perineum."""
    from scipy.spatial import cKDTree

    below = vertices[part == 0, 2].min() - 0.02
    left, right = (vertices[(part == p) & (vertices[:, 2] < below)] for p in (3, 4))
    if not len(left) or not len(right):
        return float("inf")
    return float(cKDTree(right).query(left)[0].min())


def clear_thighs(shape: BodyShape, rotations: np.ndarray, gap: float = 0.0) -> tuple[np.ndarray, float]:
    """The narrowest leg spread (whole degrees, up to MAX_STANCE_DEG) at which the thighs
    of `rotations` no longer pass through each other and, when `gap` > 0, stand at least
    `gap` metres apart (`gap_between_thighs`): (rotations, degrees per leg). Thighs
    already clear are left as they are."""
    part = body_parts(shape.bone_labels, shape.weight_index, shape.weight)
    rest = shape.vertices.detach()
    deg = 0.0
    while True:
        R = leg_spread(shape, rotations, deg) if deg else np.asarray(rotations)
        v = skin(rest, shape.weight_index, shape.weight, bone_transforms(shape, R)).numpy()
        clear = thigh_crossings(v, shape.faces, part) == 0 and (gap <= 0 or gap_between_thighs(v, part) >= gap)
        if clear or deg >= MAX_STANCE_DEG:
            if not clear:
                log.warning("the thighs are not %s at the widest stance, %.0f degrees per leg",
                            f"{1000 * gap:.0f} mm apart" if gap > 0 else "clear of each other", deg)
            return R, deg
        deg += STANCE_STEP_DEG


def named_pose(shape: BodyShape, name: str, thigh_gap: float = 0.0) -> np.ndarray:
    """'a' (arms 45 degrees), 't' (arms 90 degrees) or 'rest' (Anny's rest pose); 'a' and
    't' stand with the thighs clear of each other (at least `thigh_gap` apart)."""
    key = name.lower().replace("-pose", "").replace("pose", "") or name
    if key not in POSES:
        raise TryonError(f"unknown pose {name!r}; use one of a-pose, t-pose, rest")
    if POSES[key] is None:
        return identity_pose(shape)
    return clear_thighs(shape, arm_pose(shape, POSES[key]), thigh_gap)[0]


def transfer_weights(points: np.ndarray, shape: BodyShape, vertices: np.ndarray | None = None, k: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Skinning weights for other points (a garment) from the body: inverse-distance blend
    of the weights of the k nearest body vertices. Returns (index [N,K'], weight [N,K'])."""
    from scipy.spatial import cKDTree

    body = shape.vertices.detach().numpy() if vertices is None else vertices
    dist, near = cKDTree(body).query(np.asarray(points), k=k)
    inv = 1.0 / np.maximum(dist, 1e-4) ** 2
    inv /= inv.sum(1, keepdims=True)
    J = len(shape.bone_labels)
    dense = np.zeros((len(points), J))
    for c in range(k):
        rows = np.repeat(np.arange(len(points))[:, None], shape.weight.shape[1], 1)
        np.add.at(dense, (rows, shape.weight_index[near[:, c]]), inv[:, c, None] * shape.weight[near[:, c]])
    K = shape.weight.shape[1]
    top = np.argsort(-dense, axis=1)[:, :K]
    w = np.take_along_axis(dense, top, 1)
    return top, w / np.maximum(w.sum(1, keepdims=True), 1e-12)


def posed_heads(shape: BodyShape, G: torch.Tensor) -> np.ndarray:
    """Bone heads [J,3] after the bone transforms G (each head moves with its own bone)."""
    h = shape.bone_heads.detach()
    return (torch.einsum("jab,jb->ja", G[:, :3, :3], h) + G[:, :3, 3]).numpy()


@dataclass
class BodyPose:
    """A posed body for dressing: vertices [V,3], faces, per-vertex part labels, skeleton."""

    vertices: np.ndarray
    faces: np.ndarray
    part: np.ndarray            # 0 torso/head, 1 left arm, 2 right arm, 3 left leg, 4 right leg
    heads: dict[str, np.ndarray]


def body_parts(bone_labels: list[str], weight_index: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Per-vertex body part by dominant skinning weight group (0 torso, 1/2 arm L/R, 3/4 leg L/R)."""
    groups = np.zeros(len(bone_labels), dtype=np.int64)
    for j, lab in enumerate(bone_labels):
        side = 0 if lab.endswith(".L") else 1
        if any(w in lab for w in ARM_WORDS):
            groups[j] = 1 + side
        elif any(w in lab for w in LEG_WORDS):
            groups[j] = 3 + side
    score = np.zeros((len(weight), 5))
    rows = np.repeat(np.arange(len(weight))[:, None], weight.shape[1], 1)
    np.add.at(score, (rows, groups[weight_index]), weight)
    return score.argmax(1)


def posed_body(shape: BodyShape, pose: str | np.ndarray = "a", crotch_height: float | None = None) -> BodyPose:
    """The body in a named pose ('a', 't', 'rest') or given rotations, with bone heads (plus
    a 'crotch' landmark when its height is given) moved along."""
    R = named_pose(shape, pose) if isinstance(pose, str) else pose
    G = bone_transforms(shape, R)
    v = skin(shape.vertices.detach(), shape.weight_index, shape.weight, G).numpy()
    heads = dict(zip(shape.bone_labels, posed_heads(shape, G)))
    if crotch_height is not None:
        heads["crotch"] = np.array([0.0, 0.0, crotch_height])
    return BodyPose(v, shape.faces, body_parts(shape.bone_labels, shape.weight_index, shape.weight), heads)
