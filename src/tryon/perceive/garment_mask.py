"""The garment in a picture of a person: which of the person's pixels are the garment.

OpenCV's GrabCut (colour models of garment and not-garment refined by a graph cut) seeded
from what the person finder gives: outside the person's mask is never the garment; a core
that the garment always covers (drawn from the keypoints: the middle of the torso for a
top, the thighs for trousers...) always is; the parts it never covers (the head, and the
forearms, shins or upper torso depending on the garment) never are; the rest is left for
the colours to decide. The same function runs on the clips' renders and on real frames,
so a model trained on its masks sees the same kind of errors on both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tryon.errors import TryonError
from tryon.perceive.person import K

WORK_HEIGHT = 200  # px: the person's box is scaled to about this height for the cut


@dataclass(frozen=True)
class Seeds:
    """Keypoint segments (name, name, where along it the segment starts and ends, width
    as a fraction of the torso length) that are surely garment (`garment`) or surely not
    (`not_garment`); `torso_core` also marks the torso quad shrunk to this fraction."""

    garment: tuple[tuple[str, str, float, float, float], ...]
    not_garment: tuple[tuple[str, str, float, float, float], ...]
    torso_core: float = 0.0


_FOREARMS = (("left_elbow", "left_wrist", 0.35, 1.0, 0.06), ("right_elbow", "right_wrist", 0.35, 1.0, 0.06))
_SHINS = (("left_knee", "left_ankle", 0.3, 1.0, 0.07), ("right_knee", "right_ankle", 0.3, 1.0, 0.07))
_THIGHS = (("left_hip", "left_knee", 0.45, 1.0, 0.08), ("right_hip", "right_knee", 0.45, 1.0, 0.08))
_FEET = (("left_ankle", "left_foot_index", 0.0, 1.0, 0.06), ("right_ankle", "right_foot_index", 0.0, 1.0, 0.06))
_UPPER_TORSO = (("mid_shoulder", "mid_hip", 0.0, 0.45, 0.25),)

SEEDS = {
    "tshirt": Seeds(garment=(("mid_shoulder", "mid_hip", 0.15, 0.8, 0.3),), not_garment=_FOREARMS + _THIGHS + _SHINS + _FEET,
                    torso_core=0.55),
    "longsleeve": Seeds(garment=(("mid_shoulder", "mid_hip", 0.15, 0.8, 0.3),
                                 ("left_shoulder", "left_elbow", 0.2, 0.8, 0.05),
                                 ("right_shoulder", "right_elbow", 0.2, 0.8, 0.05)),
                        not_garment=_THIGHS + _SHINS + _FEET, torso_core=0.55),
    "dress": Seeds(garment=(("mid_shoulder", "mid_hip", 0.2, 1.0, 0.3), ("mid_hip", "mid_knee", 0.0, 0.35, 0.35)),
                   not_garment=_FOREARMS + _FEET, torso_core=0.5),
    "skirt": Seeds(garment=(("mid_hip", "mid_knee", 0.05, 0.35, 0.4),),
                   not_garment=_UPPER_TORSO + _FOREARMS + _FEET),
    "trousers": Seeds(garment=(("left_hip", "left_knee", 0.15, 0.85, 0.1), ("right_hip", "right_knee", 0.15, 0.85, 0.1)),
                      not_garment=_UPPER_TORSO + _FOREARMS + _FEET),
}


def _points(keypoints: np.ndarray) -> dict[str, np.ndarray]:
    pts = {name: keypoints[i] for name, i in K.items()}
    for part in ("shoulder", "hip", "knee"):
        pts[f"mid_{part}"] = (keypoints[K[f"left_{part}"]] + keypoints[K[f"right_{part}"]]) / 2
    return pts


def _draw_segments(canvas: np.ndarray, segments, pts: dict[str, np.ndarray], torso: float, value: int) -> None:
    import cv2

    for a, b, s0, s1, width in segments:
        p, q = pts[a], pts[b]
        u, v = p + s0 * (q - p), p + s1 * (q - p)
        cv2.line(canvas, tuple(int(round(c)) for c in u), tuple(int(round(c)) for c in v), value,
                 thickness=max(1, int(round(width * torso))))


def seed_labels(shape_hw: tuple[int, int], person: np.ndarray, keypoints: np.ndarray, garment: str) -> np.ndarray:
    """GrabCut's starting labels [H,W] (cv2.GC_*) for `garment` on a person whose mask
    (bool) and keypoints (px, x right, y down) are given."""
    import cv2

    if garment not in SEEDS:
        raise TryonError(f"no garment mask for {garment!r}; garments: {', '.join(SEEDS)}")
    seeds = SEEDS[garment]
    pts = _points(keypoints)
    torso = float(np.linalg.norm(pts["mid_shoulder"] - pts["mid_hip"]))
    labels = np.full(shape_hw, cv2.GC_BGD, np.uint8)
    labels[person] = cv2.GC_PR_BGD
    near = np.zeros(shape_hw, np.uint8)  # around the core: probably garment
    _draw_segments(near, [(a, b, s0, s1, 2.5 * w) for a, b, s0, s1, w in seeds.garment], pts, torso, 1)
    labels[(near > 0) & person] = cv2.GC_PR_FGD
    sure_not = np.zeros(shape_hw, np.uint8)
    _draw_segments(sure_not, seeds.not_garment, pts, torso, 1)
    head = pts["nose"]
    cv2.circle(sure_not, tuple(int(round(c)) for c in head), max(1, int(round(0.22 * torso))), 1, -1)
    labels[sure_not > 0] = cv2.GC_BGD
    sure = np.zeros(shape_hw, np.uint8)
    _draw_segments(sure, seeds.garment, pts, torso, 1)
    if seeds.torso_core:
        quad = np.array([pts["left_shoulder"], pts["right_shoulder"], pts["right_hip"], pts["left_hip"]])
        core = quad.mean(0) + seeds.torso_core * (quad - quad.mean(0))
        cv2.fillConvexPoly(sure, np.round(core).astype(np.int32), 1)
    labels[(sure > 0) & person] = cv2.GC_FGD
    return labels


def garment_mask(image: np.ndarray, person_mask: np.ndarray, keypoints: np.ndarray, garment: str,
                 iterations: int = 4) -> np.ndarray:
    """Bool [H,W]: the garment's pixels in `image` (RGB uint8 [H,W,3]) of a person whose
    mask (0-1 [H,W]) and 33 keypoints (px) the person finder gave. Empty when the person's
    mask is empty or the colours leave nothing for the garment."""
    import cv2

    person = person_mask > 0.5
    out = np.zeros(person.shape, bool)
    ys, xs = np.nonzero(person)
    if len(ys) < 16:
        return out
    pad = int(0.05 * (ys.max() - ys.min() + 1)) + 2
    y0, y1 = max(0, ys.min() - pad), min(person.shape[0], ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(person.shape[1], xs.max() + pad + 1)
    scale = min(1.0, WORK_HEIGHT / (y1 - y0))
    size = (max(8, int(round((x1 - x0) * scale))), max(8, int(round((y1 - y0) * scale))))
    img = cv2.resize(np.ascontiguousarray(image[y0:y1, x0:x1, :3]), size, interpolation=cv2.INTER_AREA)
    small = cv2.resize(person[y0:y1, x0:x1].astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    kp = (np.asarray(keypoints, float) - [x0, y0]) * [size[0] / (x1 - x0), size[1] / (y1 - y0)]
    labels = seed_labels((size[1], size[0]), small, kp, garment)
    if not (labels == cv2.GC_FGD).any() or not np.isin(labels, (cv2.GC_BGD, cv2.GC_PR_BGD)).any():
        return out
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)
    cv2.grabCut(img[..., ::-1].copy(), labels, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    cut = np.isin(labels, (cv2.GC_FGD, cv2.GC_PR_FGD)) & small
    full = cv2.resize(cut.astype(np.uint8), (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST) > 0
    out[y0:y1, x0:x1] = full & person[y0:y1, x0:x1]
    return out
