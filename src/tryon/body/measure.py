"""Body measurements on a rest-pose `BodyShape`, differentiable in the vertices.

* stature: top of the head above the soles (z = 0).
* volume: of the closed skin mesh (divergence theorem); mass = 980 kg/m^3 x volume, the
  density Anny's own anthropometry uses; BMI = mass / stature^2.
* girths, measured like a tape around the torso in a horizontal plane: the perimeter of
  the convex hull of the torso's cross-section (the arms, found by their skinning weights,
  are left out, so a tape never runs around an arm):
    - chest: at the height of the bust point, the most forward point of the chest at least
      4 cm off the midline between the heads of the spine02 and spine01 bones (the bust in
      women, the chest at the nipples in men);
    - waist: the smallest girth between the heads of spine04 and spine02 (the natural
      waist, between the lowest rib and the iliac crest);
    - hip: the largest girth between the head of upperleg02 (upper thigh) and the pelvis
      (the buttocks at their fullest).
  For waist and hip the search scans 16 levels of the band and measures at the best one.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import ConvexHull

from tryon.body.anny_model import BodyShape
from tryon.body.tape import find_landmarks
from tryon.body.tape import horizontal_section as slice_points

BODY_DENSITY = 980.0  # kg/m^3, as in anny.Anthropometry
ARM_BONE_WORDS = ("upperarm", "lowerarm", "wrist", "finger", "metacarpal")
GIRTH_BANDS = {  # name -> (lower bone, upper bone, "max" | "min")
    "chest": ("spine02", "spine01", "bust"),
    "waist": ("spine04", "spine02", "min"),
    "hip": ("upperleg02.L", "pelvis.L", "max"),
}
BAND_LEVELS = 16


def stature(v: torch.Tensor) -> torch.Tensor:
    return v[:, 2].max() - v[:, 2].min()


def volume(v: torch.Tensor, faces: np.ndarray) -> torch.Tensor:
    f = torch.from_numpy(faces)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return (torch.cross(a, b, dim=1) * c).sum().abs() / 6.0


def mass(v: torch.Tensor, faces: np.ndarray) -> torch.Tensor:
    return BODY_DENSITY * volume(v, faces)


def bmi(v: torch.Tensor, faces: np.ndarray) -> torch.Tensor:
    return mass(v, faces) / stature(v) ** 2


_TORSO_EDGES: dict[tuple[int, int], np.ndarray] = {}


def torso_edges(shape: BodyShape) -> np.ndarray:
    """Mesh edges [E,2] whose two ends belong to the torso, head or legs (not the arms).
    Cached per model (every shape of a model shares its faces and weight arrays)."""
    key = (id(shape.faces), id(shape.weight))
    if key not in _TORSO_EDGES:
        arm_bone = np.array([any(w in lab for w in ARM_BONE_WORDS) for lab in shape.bone_labels])
        arm = (shape.weight * arm_bone[shape.weight_index]).sum(1) > 0.5
        f = shape.faces
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        e = np.unique(np.sort(e, axis=1), axis=0)
        _TORSO_EDGES[key] = e[~arm[e].any(1)]
    return _TORSO_EDGES[key]


def hull_perimeter(points: torch.Tensor) -> torch.Tensor:
    """Perimeter of the convex hull of 2D points (the tape measure), differentiable."""
    if points.shape[0] < 3:
        return points.new_zeros(())
    hull = ConvexHull(points.detach().numpy())
    ring = torch.from_numpy(np.asarray(hull.vertices, dtype=np.int64))  # counter-clockwise
    p = points[ring]
    return torch.linalg.norm(p - torch.roll(p, 1, dims=0), dim=1).sum()


def girth_at(v: torch.Tensor, edges: np.ndarray, z: float) -> torch.Tensor:
    return hull_perimeter(slice_points(v, edges, z))


def girth(shape: BodyShape, name: str, v: torch.Tensor | None = None) -> tuple[torch.Tensor, float]:
    """(girth in m, height of the measuring plane in m) for 'chest', 'waist' or 'hip'."""
    lo_bone, hi_bone, mode = GIRTH_BANDS[name]
    v = shape.vertices if v is None else v
    edges = torso_edges(shape)
    lo, hi = float(shape.head(lo_bone)[2]), float(shape.head(hi_bone)[2])
    if mode == "bust":
        z = bust_height(shape, edges, lo, hi)
        return girth_at(v, edges, z), z
    levels = np.linspace(lo, hi, BAND_LEVELS)
    with torch.no_grad():
        values = np.array([float(girth_at(v.detach(), edges, z)) for z in levels])
    k = int(np.argmax(values) if mode == "max" else np.argmin(values))
    return girth_at(v, edges, float(levels[k])), float(levels[k])


def bust_height(shape: BodyShape, edges: np.ndarray, lo: float, hi: float) -> float:
    """Height of the most forward (-y) torso vertex between lo and hi, off the midline."""
    v = shape.vertices.detach().numpy()
    torso = np.zeros(len(v), dtype=bool)
    torso[edges.ravel()] = True
    sel = torso & (v[:, 2] > lo) & (v[:, 2] < hi) & (np.abs(v[:, 0]) > 0.04)
    if not sel.any():
        return 0.5 * (lo + hi)
    return float(v[np.argmin(np.where(sel, v[:, 1], np.inf)), 2])


def measurements(shape: BodyShape) -> dict[str, float]:
    """Stature, mass, BMI and the three girths (cm, kg) of a rest-pose body."""
    v = shape.vertices.detach()
    out = {
        "height_cm": 100.0 * float(stature(v)),
        "weight_kg": float(mass(v, shape.faces)),
        "bmi": float(bmi(v, shape.faces)),
    }
    for name in GIRTH_BANDS:
        g, _ = girth(shape, name, v)
        out[f"{name}_cm"] = 100.0 * float(g)
    return out


def _limb_girth(v: np.ndarray, mask: np.ndarray, centre: np.ndarray, axis: np.ndarray, band: float = 0.012) -> float:
    """Convex-hull girth of the limb points within `band` of the plane through `centre`
    perpendicular to `axis`."""
    axis = axis / np.linalg.norm(axis)
    d = (v - centre) @ axis
    sel = mask & (np.abs(d) < band) & (np.linalg.norm(v - centre, axis=1) < 0.15)
    if sel.sum() < 3:
        return 0.0
    p = v[sel] - centre
    p = p - np.outer(p @ axis, axis)
    e1 = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    return float(hull_perimeter(torch.from_numpy(np.stack([p @ e1, p @ e2], 1))))


def _bone_mask(shape: BodyShape, words: tuple[str, ...], side: str) -> np.ndarray:
    match = np.array([any(w in lab for w in words) and lab.endswith(side) for lab in shape.bone_labels])
    return (shape.weight * match[shape.weight_index]).sum(1) > 0.5


def drafting_measurements(shape: BodyShape) -> dict[str, float]:
    """The construction measurements the pattern drafts are built on, in metres, on a
    rest-pose body (left side for limbs). Not the tape measurements a person is described
    by (`tryon.body.tape`): these are pinned, every standard-size pattern and the learned
    models' datasets are drafted with them (docs/BODY.md). Girths (chest, waist, hip, neck,
    bicep, wrist, thigh), heights above the floor
    (stature, neck base, shoulder, chest, waist, hip, crotch, knee, ankle), shoulder width
    (between the shoulder joints plus the deltoid), arm length (shoulder to wrist) and
    the body depth at chest level."""
    v = shape.vertices.detach().numpy()
    vt = shape.vertices.detach()
    edges = torso_edges(shape)
    out = {"stature": float(v[:, 2].max())}
    for name in GIRTH_BANDS:
        g, z = girth(shape, name, vt)
        out[f"{name}_girth"], out[f"{name}_height"] = float(g), z
    head = {b: shape.head(b) for b in ("neck01", "upperarm01.L", "lowerarm01.L", "wrist.L", "upperleg02.L", "lowerleg01.L", "foot.L")}
    out["neck_height"] = float(head["neck01"][2])
    out["neck_girth"] = float(girth_at(vt, edges, out["neck_height"] + 0.01))
    sh = head["upperarm01.L"]
    near = np.abs(v[:, 0] - sh[0]) < 0.03
    out["shoulder_height"] = float(v[near & (np.abs(v[:, 1] - sh[1]) < 0.06), 2].max())
    out["shoulder_width"] = float(2.0 * sh[0] + 0.03)
    out["arm_length"] = float(np.linalg.norm(head["lowerarm01.L"] - sh) + np.linalg.norm(head["wrist.L"] - head["lowerarm01.L"]))
    arm = _bone_mask(shape, ("upperarm",), ".L")
    fore = _bone_mask(shape, ("lowerarm", "wrist"), ".L")
    out["bicep_girth"] = _limb_girth(v, arm, 0.5 * (sh + head["lowerarm01.L"]), head["lowerarm01.L"] - sh)
    out["wrist_girth"] = _limb_girth(v, fore, head["wrist.L"] - 0.02 * (head["wrist.L"] - head["lowerarm01.L"]) / np.linalg.norm(head["wrist.L"] - head["lowerarm01.L"]), head["wrist.L"] - head["lowerarm01.L"])
    mid = np.abs(v[:, 0]) < 0.015
    torso = np.zeros(len(v), dtype=bool)
    torso[edges.ravel()] = True
    crotch = mid & torso & (v[:, 2] > head["lowerleg01.L"][2]) & (v[:, 2] < out["hip_height"])
    out["crotch_height"] = float(v[crotch, 2].min()) if crotch.any() else float(head["upperleg02.L"][2] - 0.05)
    leg = _bone_mask(shape, ("upperleg",), ".L")
    out["thigh_girth"] = _limb_girth(v, leg, np.array([head["upperleg02.L"][0], head["upperleg02.L"][1], out["crotch_height"] - 0.03]),
                                     head["lowerleg01.L"] - head["upperleg02.L"])
    out["knee_height"] = float(head["lowerleg01.L"][2])
    out["ankle_height"] = float(head["foot.L"][2])
    chest = slice_points(vt, edges, out["chest_height"]).numpy()
    out["chest_depth"] = float(chest[:, 1].max() - chest[:, 1].min()) if len(chest) else 0.25
    return out


def made_to_measure_measurements(shape: BodyShape) -> dict[str, float]:
    """`drafting_measurements` for a pattern drafted on the wearer's own body (`--size
    made-to-measure`), with the crotch of `tryon.body.tape` (the lowest midline vertex the
    pelvis carries): the lowest midline vertex that `drafting_measurements` takes is, on
    fuller thighs, an inner thigh crossing the midline (6 cm low on a 165 cm, 68 kg woman,
    18 cm on a 158 cm, 92 kg one), which drafted trousers that short in the leg."""
    m = drafting_measurements(shape)
    m["crotch_height"] = float(shape.vertices[find_landmarks(shape).crotch, 2])
    return m


def centre_profiles(shape: BodyShape, lo: float, hi: float, step: float = 0.01) -> tuple[np.ndarray, ...]:
    """Heights (m, from `hi` down to `lo` every `step`) and the body's foremost and
    rearmost depth there (y, m; the body faces -y): the torso's, and below the crotch both
    legs'. A made-to-measure dress is drafted long enough to run down both over the bust,
    belly and buttocks (`tryon.garment.drafts.BodyCover.centre_excess`)."""
    v = shape.vertices.detach().numpy()
    v = v[np.unique(torso_edges(shape))]
    heights = np.arange(hi, lo, -step)
    front, back = np.empty(len(heights)), np.empty(len(heights))
    for k, z in enumerate(heights):
        band = v[np.abs(v[:, 2] - z) < 0.6 * step, 1]
        front[k], back[k] = (band.min(), band.max()) if len(band) else (np.nan, np.nan)
    good = np.isfinite(front)
    return heights[good], front[good], back[good]


def girth_profile(shape: BodyShape, lo: float, hi: float, step: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Heights (m, from `hi` down to `lo` every `step`) and the girths (m) there, on the
    tape of the girths: the convex hull of the torso's cross-section, and below the crotch
    of both legs together (what a skirt passes over). A made-to-measure skirt or dress is
    drafted to pass over all of it (`tryon.garment.drafts.BodyCover`): on a heavy body the
    belly at the navel can be 20 cm more than the waist above it, and both upper thighs
    together 9 cm more than the hip (a 200 cm, 180 kg man)."""
    v = shape.vertices.detach()
    edges = torso_edges(shape)
    heights = np.arange(hi, lo, -step)
    return heights, np.array([float(girth_at(v, edges, float(z))) for z in heights])
