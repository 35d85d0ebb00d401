"""What each fabric preset looks like in a render: its colour and, where the fabric has
one, a print (dots, stripes) evaluated on the garment's material coordinates (metres),
so a print follows the cloth as it drapes. Prints are coloured per vertex: features
smaller than about two edge lengths blur."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT = (0.27, 0.45, 0.72)


@dataclass(frozen=True)
class Appearance:
    color: tuple[float, float, float]
    print_color: tuple[float, float, float] | None = None
    print_kind: str = ""          # "dots" or "stripes"
    period_m: float = 0.04
    size: float = 0.3             # share of the period covered (dot radius or stripe width)


# the measured fabrics' look, from their names and descriptions (Wang et al. 2011)
APPEARANCES = {
    "ivory-rib-knit": Appearance((0.93, 0.89, 0.80)),
    "pink-ribbon-brown": Appearance((0.40, 0.26, 0.18), (0.93, 0.62, 0.70), "stripes", 0.06, 0.3),
    "white-dots-on-blk": Appearance((0.06, 0.06, 0.07), (0.95, 0.95, 0.95), "dots", 0.06, 0.25),
    "navy-sparkle-sweat": Appearance((0.12, 0.15, 0.33)),
    "camel-ponte-roma": Appearance((0.74, 0.58, 0.40)),
    "gray-interlock": Appearance((0.56, 0.57, 0.60)),
    "11oz-black-denim": Appearance((0.11, 0.12, 0.15)),
    "white-swim-solid": Appearance((0.93, 0.93, 0.92)),
    "tango-red-jet-set": Appearance((0.80, 0.16, 0.12)),
    "royal-target": Appearance((0.16, 0.27, 0.66)),
    "paper": Appearance((0.95, 0.94, 0.90)),
    "aluminium": Appearance((0.76, 0.77, 0.79)),
}


def appearance(fabric: str) -> Appearance:
    """The preset's look; a fabric file of the user's own is drawn in the default blue."""
    return APPEARANCES.get(fabric, Appearance(DEFAULT))


def fabric_colors(fabric: str, uv: np.ndarray) -> np.ndarray:
    """Per-vertex colours [N,3] of a garment in `fabric` with material coordinates `uv` [N,2] (m)."""
    look = appearance(fabric)
    colors = np.tile(np.asarray(look.color, float), (len(uv), 1))
    if look.print_color is None:
        return colors
    phase = np.mod(np.asarray(uv, float) / look.period_m, 1.0) - 0.5
    if look.print_kind == "dots":
        on = np.hypot(phase[:, 0], phase[:, 1]) < look.size
    else:  # stripes across the grain (v)
        on = np.abs(phase[:, 1]) < 0.5 * look.size
    colors[on] = look.print_color
    return colors


def subdivide_faces(faces: np.ndarray, face_ids: np.ndarray, num_vertices: int,
                    n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split the faces `face_ids` of a mesh into n x n triangles each, for pictures finer
    than the mesh (an image printed on cloth). Returns, for the P new points, the face each
    lies in [P] and its barycentric coordinates there [P,3] (interpolate positions,
    material coordinates, normals with them), the mesh's faces with the split ones
    replaced [F',3] (indices: the `num_vertices` old vertices, then the new points) and
    which of those faces are new [F'] (bool). Points on an edge two split faces share are
    made once, so smooth shading stays smooth; an edge shared with an unsplit face gets
    T-junctions (its points lie on the straight edge, nothing opens)."""
    face_ids = np.asarray(face_ids, np.int64)
    n = int(n)
    if n < 1:
        raise ValueError(f"subdivide_faces: n must be >= 1, got {n}")
    ii, jj = [a.ravel() for a in np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")]
    keep = ii + jj <= n
    ii, jj = ii[keep], jj[keep]
    w = np.stack([n - ii - jj, ii, jj], 1)                      # [p,3] integer weights of corners a, b, c
    local = -np.ones((n + 1, n + 1), np.int64)
    local[ii, jj] = np.arange(len(ii))
    tris = []
    for i in range(n):
        for j in range(n - i):
            tris.append((local[i, j], local[i + 1, j], local[i, j + 1]))
            if i + j < n - 1:
                tris.append((local[i + 1, j], local[i + 1, j + 1], local[i, j + 1]))
    tris = np.asarray(tris, np.int64)
    corners = faces[face_ids]                                    # [k,3]
    ids = np.broadcast_to(corners[:, None, :], (len(face_ids), len(w), 3)).copy()
    ws = np.broadcast_to(w[None], ids.shape).copy()
    ids[ws == 0] = -1
    order = np.argsort(ids, axis=2)
    key = np.concatenate([np.take_along_axis(ids, order, 2), np.take_along_axis(ws, order, 2)], 2).reshape(-1, 6)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    vertex_of = uniq[:, 3:].max(1) == n                          # a point that is an old vertex
    new = ~vertex_of
    index = np.empty(len(uniq), np.int64)
    index[vertex_of] = uniq[vertex_of, :3].max(1)
    index[new] = num_vertices + np.arange(int(new.sum()))
    _, first = np.unique(inverse, return_index=True)               # one (face, point) per unique point
    f_of, p_of = np.divmod(first[new], len(w))
    sub = index[inverse.reshape(len(face_ids), len(w))]          # [k, p] mesh index of each face's points
    rest = np.setdiff1d(np.arange(len(faces)), face_ids)
    new_faces = sub[:, tris].reshape(-1, 3)
    out_faces = np.concatenate([faces[rest], new_faces])
    is_new = np.concatenate([np.zeros(len(rest), bool), np.ones(len(new_faces), bool)])
    return face_ids[f_of], w[p_of] / n, out_faces, is_new
