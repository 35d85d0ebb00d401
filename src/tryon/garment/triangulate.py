"""Triangulation of pattern panels at a target edge length, with matching vertices along
seams, and assembly of the panels into one garment mesh.

Each panel edge is sampled at equal arc length; the two edges of a seam get the same
number of segments, so their vertices pair up one to one. The inside is filled with a
triangular lattice kept away from the outline, Delaunay-triangulated (scipy) and relaxed
by a few Laplacian sweeps; triangles outside the outline are dropped. Panel coordinates
become material coordinates in the grain frame (u along the grain line, the fabric's
warp).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from matplotlib.path import Path as PolyPath
from scipy.spatial import Delaunay

from tryon.errors import MeshError
from tryon.garment.pattern import Panel, Pattern
from tryon.sim.collision import stitch_alias
from tryon.sim.origin import PatternMesh


@dataclass
class PanelMesh:
    """A triangulated panel: points [n,2] (panel coordinates, m), faces [f,3] (CCW),
    and for each edge the indices of its vertices from start to end."""

    name: str
    points: np.ndarray
    faces: np.ndarray
    edge_vertices: dict[str, np.ndarray]
    grain: tuple[float, float]

    def material_uv(self) -> np.ndarray:
        """(u, v): u along the grain line, v across it; a rotation, so orientation is kept."""
        g = np.asarray(self.grain)
        return np.stack([self.points @ g, self.points @ np.array([-g[1], g[0]])], 1)


def edge_segments(pattern: Pattern, edge_length: float) -> dict[tuple[str, str], int]:
    """Segments per (panel, edge): ceil(length / edge_length), the larger of the two for a seam."""
    if not edge_length > 0:
        raise MeshError(f"edge length must be positive, got {edge_length}")
    seg = {(p.name, e.name): max(1, int(np.ceil(e.length() / edge_length))) for p in pattern.panels for e in p.edges}
    for s in pattern.seams:
        n = max(seg[s.a], seg[s.b])
        seg[s.a] = seg[s.b] = n
    return seg


def _segment_distance(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance from each point to the closed polyline `poly`."""
    a = poly
    b = np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(((points[:, None, :] - a[None]) * ab[None]).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-18)[None], 0, 1)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=-1).min(1)


def triangulate_panel(panel: Panel, segments: dict[str, int], edge_length: float, smoothing: int = 4) -> PanelMesh:
    boundary, edge_vertices = [], {}
    for e in panel.edges:
        n = segments[e.name]
        pts = e.sample(n)
        start = len(boundary)
        boundary.extend(pts[:-1])
        edge_vertices[e.name] = np.arange(start, start + n + 1)
    nb = len(boundary)
    for name in edge_vertices:  # the last vertex of each edge is the first of the next
        edge_vertices[name] = edge_vertices[name] % nb
    boundary = np.asarray(boundary)
    outline = PolyPath(np.vstack([boundary, boundary[:1]]))
    lo, hi = boundary.min(0), boundary.max(0)
    h = edge_length
    rows = np.arange(lo[1] + 0.5 * h, hi[1], h * np.sqrt(3) / 2)
    lattice = [np.stack([np.arange(lo[0] + (0.5 * h if k % 2 else 0.0), hi[0], h), np.full(len(np.arange(lo[0] + (0.5 * h if k % 2 else 0.0), hi[0], h)), y)], 1)
               for k, y in enumerate(rows)]
    inner = np.concatenate(lattice) if lattice else np.zeros((0, 2))
    if len(inner):
        inner = inner[outline.contains_points(inner)]
        inner = inner[_segment_distance(inner, boundary) > 0.6 * h]
    points = np.vstack([boundary, inner])
    faces = _delaunay_inside(points, outline, nb)
    for _ in range(smoothing):
        points = _relax(points, faces, nb, outline, boundary, h)
        faces = _delaunay_inside(points, outline, nb)
    _check_boundary(faces, nb, panel.name)
    return PanelMesh(panel.name, points, faces, edge_vertices, panel.grain)


def _delaunay_inside(points: np.ndarray, outline: PolyPath, nb: int) -> np.ndarray:
    tri = Delaunay(points).simplices
    centroid = points[tri].mean(1)
    keep = outline.contains_points(centroid)
    tri = tri[keep]
    p = points[tri]
    area = 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    tri = np.where((area < 0)[:, None], tri[:, [0, 2, 1]], tri)
    scale = np.median(np.abs(area)) if len(area) else 1.0
    return tri[np.abs(area) > 1e-6 * scale]


def _relax(points, faces, nb, outline, boundary, h):
    """One Laplacian sweep of the interior points (boundary fixed), kept inside."""
    n = len(points)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.unique(np.sort(e, 1), axis=0)
    acc = np.zeros_like(points)
    cnt = np.zeros(n)
    np.add.at(acc, e[:, 0], points[e[:, 1]])
    np.add.at(acc, e[:, 1], points[e[:, 0]])
    np.add.at(cnt, e[:, 0], 1)
    np.add.at(cnt, e[:, 1], 1)
    new = points.copy()
    movable = np.arange(n) >= nb
    movable &= cnt > 0
    cand = acc[movable] / cnt[movable, None]
    ok = outline.contains_points(cand) & (_segment_distance(cand, boundary) > 0.35 * h)
    idx = np.nonzero(movable)[0]
    new[idx[ok]] = cand[ok]
    return new


def _check_boundary(faces: np.ndarray, nb: int, name: str) -> None:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    have = set(map(tuple, np.sort(e, 1).tolist()))
    missing = [(i, (i + 1) % nb) for i in range(nb) if tuple(sorted((i, (i + 1) % nb))) not in have]
    if missing:
        raise MeshError(
            f"panel {name}: the triangulation lost {len(missing)} outline segment(s) (first between outline points "
            f"{missing[0]}); use a smaller edge length or smooth sharp concave corners of the pattern"
        )


@dataclass
class GarmentMesh:
    """All panels of a pattern in one mesh. Seam vertices are not yet merged: `stitches`
    [S,2] pairs them. `corner_uv` [F,3,2] holds each face's material coordinates (per
    face corner, so that they stay right when seam vertices merge)."""

    pattern: Pattern
    points2d: np.ndarray          # [N,2] panel coordinates
    uv: np.ndarray                # [N,2] material coordinates (grain frame)
    faces: np.ndarray             # [F,3]
    panel_of_vertex: np.ndarray   # [N]
    panel_names: list[str]
    edge_vertices: dict[tuple[str, str], np.ndarray]
    stitches: np.ndarray          # [S,2]
    corner_uv: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.corner_uv = self.uv[self.faces]

    @property
    def num_vertices(self) -> int:
        return len(self.uv)


def triangulate_pattern(pattern: Pattern, edge_length: float = 0.01) -> GarmentMesh:
    """Triangulate every panel with seam-matched vertices and collect the stitch pairs."""
    seg = edge_segments(pattern, edge_length)
    points, uvs, faces, owner, edges = [], [], [], [], {}
    offset = 0
    for k, p in enumerate(pattern.panels):
        pm = triangulate_panel(p, {e.name: seg[(p.name, e.name)] for e in p.edges}, edge_length)
        points.append(pm.points)
        uvs.append(pm.material_uv())
        faces.append(pm.faces + offset)
        owner.append(np.full(len(pm.points), k))
        for name, idx in pm.edge_vertices.items():
            edges[(p.name, name)] = idx + offset
        offset += len(pm.points)
    stitches = []
    for s in pattern.seams:
        va, vb = edges[s.a], edges[s.b]
        if s.reverse:
            vb = vb[::-1]
        if len(va) != len(vb):  # pragma: no cover - edge_segments guarantees equal counts
            raise MeshError(f"seam {s.a}-{s.b}: {len(va)} vs {len(vb)} vertices")
        stitches.append(np.stack([va, vb], 1))
    st = np.concatenate(stitches) if stitches else np.zeros((0, 2), np.int64)
    st = np.unique(np.sort(st[st[:, 0] != st[:, 1]], 1), axis=0)
    return GarmentMesh(pattern, np.vstack(points), np.vstack(uvs), np.vstack(faces).astype(np.int64),
                       np.concatenate(owner), [p.name for p in pattern.panels], edges, st.astype(np.int64))


def merge_stitched(mesh: GarmentMesh, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Weld stitched vertices (`stitch_alias`: chains of stitch pairs join, so corners where several
    seams meet become one vertex). Returns (positions [M,3] averaged over each group,
    faces [F,3] re-indexed, corner_uv [F,3,2], group index of each old vertex [N])."""
    n = mesh.num_vertices
    alias = stitch_alias(mesh.stitches, n)
    group = np.arange(n) if alias is None else alias
    m = int(group.max()) + 1 if n else 0
    pos = np.zeros((m, 3))
    cnt = np.zeros(m)
    np.add.at(pos, group, x)
    np.add.at(cnt, group, 1)
    faces = group[mesh.faces]
    return pos / cnt[:, None], faces, mesh.corner_uv.copy(), group


def remesh_pattern(pattern: Pattern, edge_length: float) -> PatternMesh:
    """`pattern` triangulated at `edge_length` with its seams welded, as the plain data a
    scene's `PatternOrigin` hands to the simulator's tools (time-parallel coarsening)."""
    gm = triangulate_pattern(pattern, edge_length)
    _, faces, corner_uv, _ = merge_stitched(gm, np.zeros((gm.num_vertices, 3)))
    return PatternMesh(faces.astype(np.int64), corner_uv, gm.panel_of_vertex[gm.faces[:, 0]])


def transfer_mesh(ref: GarmentMesh, pattern: Pattern) -> GarmentMesh:
    """The triangles of `ref` (a triangulation of another size of the same draft) laid
    on the panels of `pattern`: one garment topology for every size, so that a learned
    model predicts the same vertices whatever the size.

    Every outline vertex keeps its edge and its fraction of that edge's arc length (seam
    partners stay partners); the inside follows by the harmonic extension of the
    outline's displacement (uniform graph Laplacian per panel). Raises `MeshError` when
    the patterns differ in panels or edges, or when a triangle would flip."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    names = [p.name for p in pattern.panels]
    if names != ref.panel_names:
        raise MeshError(f"cannot transfer the {ref.pattern.name} mesh: its panels {ref.panel_names} differ from {names}")
    new2d = ref.points2d.copy()
    uv = ref.uv.copy()
    edges = np.unique(np.sort(np.concatenate([ref.faces[:, [0, 1]], ref.faces[:, [1, 2]], ref.faces[:, [2, 0]]]), 1), axis=0)
    for k, panel in enumerate(pattern.panels):
        own = ref.panel_of_vertex == k
        on_outline = np.zeros(len(new2d), bool)
        for e in panel.edges:
            idx = ref.edge_vertices.get((panel.name, e.name))
            if idx is None:
                raise MeshError(f"cannot transfer the {ref.pattern.name} mesh: panel {panel.name} has no edge {e.name!r} there")
            new2d[idx] = e.sample(len(idx) - 1)
            on_outline[idx] = True
        inside = np.nonzero(own & ~on_outline)[0]
        if len(inside):
            e = edges[own[edges[:, 0]] & own[edges[:, 1]]]
            n = len(new2d)
            adj = coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
            lap = (coo_matrix((np.asarray(adj.sum(1)).ravel(), (np.arange(n), np.arange(n))), shape=(n, n)) - adj).tocsr()
            fixed = np.nonzero(own & on_outline)[0]
            shift = new2d[fixed] - ref.points2d[fixed]
            rhs = -(lap[inside][:, fixed] @ shift)
            sol = spsolve(lap[inside][:, inside].tocsc(), rhs)
            new2d[inside] = ref.points2d[inside] + np.asarray(sol).reshape(-1, 2)
        g = np.asarray(panel.grain)
        uv[own] = np.stack([new2d[own] @ g, new2d[own] @ np.array([-g[1], g[0]])], 1)
    p = new2d[ref.faces]
    area = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1])
    if (area <= 0).any():
        raise MeshError(f"transferring the {ref.pattern.name} mesh to {pattern.meta.get('size', 'another size')} flips "
                        f"{int((area <= 0).sum())} triangles; triangulate that size on its own")
    return GarmentMesh(pattern, new2d, uv, ref.faces.copy(), ref.panel_of_vertex.copy(), list(ref.panel_names),
                       dict(ref.edge_vertices), ref.stitches.copy())
