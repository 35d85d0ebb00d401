"""Cheaper collision obstacles for the coarse level of a time-parallel run.

On a garment animation both levels collide against the same body mesh (~14k vertices),
so the body's collision work is the same at both resolutions and the fine-to-coarse cost
ratio K stays small. By default the coarse level collides with the body's triangles near
the garment, unchanged (`crop_obstacle`). Opt-in, it collides against a proxy: the body
decimated by vertex clustering (every vertex
replaced by the mean of its grid cell, degenerate and repeated triangles dropped) and
inflated along its vertex normals until it encloses the original body (the part within
reach of the garment) at the keyframes, so a coarse cloth outside the proxy is outside
the real body.

The clustering is a fixed sparse averaging matrix C [m, n], so a keyframed (deforming)
body is decimated frame by frame as C @ frames with one topology.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from tryon.errors import SceneError
from tryon.sim.geometry import area_vertex_normals, nearest_surface_points
from tryon.sim.obstacles import Motion, Obstacle

MIN_FACES = 2000  # obstacles with fewer triangles are kept as they are
CROP_REACH = 0.15  # m: the body near a garment, kept for the coarse level (a walk's thighs and arms included)


def cluster_decimate(vertices: np.ndarray, faces: np.ndarray, cell: float) -> tuple[sp.csr_matrix, np.ndarray]:
    """Vertex clustering on a grid of `cell` metres: the averaging matrix C [m, n] (row k
    the mean of cluster k's vertices) and the faces [F', 3] on the clusters, with
    triangles that collapse or repeat dropped."""
    if not cell > 0:
        raise SceneError(f"the decimation cell size must be positive, got {cell}")
    v = np.asarray(vertices, np.float64)
    key = np.floor((v - v.min(0)) / cell).astype(np.int64)
    _, cluster = np.unique(key, axis=0, return_inverse=True)
    cluster = cluster.reshape(-1)
    m = int(cluster.max()) + 1
    counts = np.bincount(cluster, minlength=m).astype(np.float64)
    C = sp.csr_matrix((1.0 / counts[cluster], (cluster, np.arange(len(v)))), shape=(m, len(v)))
    f = cluster[np.asarray(faces, np.int64)]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
    # one triangle per vertex triple (either orientation: the first one kept)
    _, first = np.unique(np.sort(f, 1), axis=0, return_index=True)
    f = f[np.sort(first)]
    used = np.unique(f)
    remap = np.full(m, -1, np.int64)
    remap[used] = np.arange(len(used))
    return C[used].tocsr(), remap[f]


def _frames(ob: Obstacle) -> tuple[np.ndarray, np.ndarray | None]:
    if ob.motion.keyframes is not None:
        return np.asarray(ob.motion.keyframes, np.float64), np.asarray(ob.motion.keyframe_times, np.float64)
    return np.asarray(ob.rest_vertices, np.float64)[None], None


ENCLOSED = 0.995  # fraction of the body vertices near the cloth the proxy must enclose


def excess_outside(proxy_frames: np.ndarray, faces: np.ndarray, body_frames: np.ndarray) -> np.ndarray:
    """Signed distance (m, positive outside) of every body vertex to the proxy, all frames."""
    out = []
    for p, b in zip(proxy_frames, body_frames):
        d, _, _ = nearest_surface_points(np.ascontiguousarray(b), np.ascontiguousarray(p), faces)
        out.append(d)
    return np.concatenate(out)


def proxy_obstacle(ob: Obstacle, cell: float, near: np.ndarray | None = None, reach: float = 0.1,
                   margin: float = 0.002, rounds: int = 6) -> tuple[Obstacle, dict]:
    """The decimated, inflated stand-in of a mesh obstacle (see the module doc).

    With `near` (cloth positions at the start) only the part of the obstacle within
    `reach` of the cloth is kept (the same vertices at every keyframe: a garment does not
    reach the feet), and enclosure is required of the vertices within reach/2 (the cut
    border of an open surface has no inside). The offset along the vertex normals grows by
    the measured excess until `ENCLOSED` of those vertices lie inside the proxy at every
    sampled keyframe (vertex clustering folds thin parts such as fingers into sheets
    whose inside is ambiguous), then `margin` is added."""
    frames, times = _frames(ob)
    faces_in = np.asarray(ob.faces, np.int64)
    check = np.ones(len(frames[0]), bool)
    if near is not None:
        dist, _ = cKDTree(np.asarray(near, np.float64)).query(frames[0])
        faces_in = faces_in[(dist < reach)[faces_in].all(1)]
        check = dist < 0.5 * reach
        if len(faces_in) == 0:
            raise SceneError(f"obstacle {ob.name}: no part of it lies within {reach} m of the cloth")
    C, faces = cluster_decimate(frames[0], faces_in, cell)
    base = np.stack([C @ f for f in frames])
    normals = np.stack([area_vertex_normals(b, faces) for b in base])
    sample = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), 12)).round().astype(int))
    offset = 0.0
    for _ in range(rounds):
        d = excess_outside(base[sample] + offset * normals[sample], faces, frames[sample][:, check])
        excess = float(np.quantile(d, ENCLOSED))
        if excess <= 0.0:
            break
        offset += excess + 2e-4  # the quantile approaches 0 from above: step past it
    else:
        raise SceneError(f"obstacle {ob.name}: its decimation at {cell} m does not enclose it; use a smaller cell")
    offset += margin
    proxy = base + offset * normals
    motion = Motion(keyframes=proxy, keyframe_times=times) if times is not None else ob.motion
    info = {"name": ob.name, "vertices": int(proxy.shape[1]), "faces": int(len(faces)),
            "original_vertices": int(len(frames[0])), "original_faces": int(len(ob.faces)), "offset_m": float(offset),
            "cell_m": float(cell), "reach_m": float(reach) if near is not None else None}
    return Obstacle(f"{ob.name}-proxy", proxy[0], faces, motion), info


def crop_obstacle(ob: Obstacle, near: np.ndarray, reach: float = CROP_REACH) -> tuple[Obstacle, dict]:
    """The part of a mesh obstacle within `reach` of the cloth at the start, unchanged:
    its triangles whose three vertices lie that close (the same ones at every keyframe), on
    the vertices they use. Collisions of cloth that stays within reach are those against
    the whole obstacle; the work per step that grows with the obstacle's size shrinks."""
    frames, times = _frames(ob)
    dist, _ = cKDTree(np.asarray(near, np.float64)).query(frames[0])
    faces = np.asarray(ob.faces, np.int64)
    faces = faces[(dist < reach)[faces].all(1)]
    if len(faces) == 0:
        raise SceneError(f"obstacle {ob.name}: no part of it lies within {reach} m of the cloth")
    used = np.unique(faces)
    remap = np.full(len(frames[0]), -1, np.int64)
    remap[used] = np.arange(len(used))
    cropped = frames[:, used]
    motion = Motion(keyframes=cropped, keyframe_times=times) if times is not None else ob.motion
    info = {"name": ob.name, "vertices": int(len(used)), "faces": int(len(faces)),
            "original_vertices": int(len(frames[0])), "original_faces": int(len(ob.faces)), "reach_m": float(reach),
            "cropped": True}
    return Obstacle(f"{ob.name}-near", cropped[0], remap[faces], motion), info



def coarse_obstacles(obstacles: list[Obstacle], cell: float | str | None, near: np.ndarray | None = None,
                     reach: float = 0.1) -> tuple[list[Obstacle], list[dict]]:
    """Every mesh obstacle with at least `MIN_FACES` triangles replaced by its proxy of
    `cell` metres, or with `cell` "crop" by its part near the cloth (`crop_obstacle`;
    needs `near`); `cell` None keeps them all."""
    if cell is None:
        return list(obstacles), []
    out, infos = [], []
    for ob in obstacles:
        if len(ob.faces) >= MIN_FACES:
            proxy, info = crop_obstacle(ob, near) if cell == "crop" else proxy_obstacle(ob, cell, near, reach)
            out.append(proxy)
            infos.append(info)
        else:
            out.append(ob)
    return out, infos
