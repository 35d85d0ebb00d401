"""Triangle cloth meshes with 2D material (rest) coordinates.

A `ClothMesh` holds world positions [N,3], material coordinates `uv` [N,2] in metres
(for a garment they come from its sewing pattern; for an OBJ they are its `vt`), faces
[F,3] and the derived topology (unique edges, bending hinges). It validates its input so
that the simulator never sees NaN, degenerate triangles or non-manifold edges.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from tryon.errors import MeshError

DTYPE = torch.float64


@dataclass
class ClothMesh:
    """A validated cloth mesh: positions x [N,3], material coords uv [N,2] (m), faces [F,3].

    `face_uv` [F,3,2], when given, holds material coordinates per face corner and takes
    precedence over `uv` for the rest shape: a garment whose seams are welded has vertices
    that belong to two panels, each with its own pattern coordinates."""

    x: torch.Tensor
    uv: torch.Tensor
    faces: torch.Tensor
    name: str = "cloth"
    face_uv: torch.Tensor | None = None
    edges: torch.Tensor = field(init=False)

    def __post_init__(self) -> None:
        self.x = torch.as_tensor(self.x, dtype=DTYPE).contiguous()
        self.uv = torch.as_tensor(self.uv, dtype=DTYPE).contiguous()
        self.faces = torch.as_tensor(self.faces, dtype=torch.int64).contiguous()
        if self.face_uv is not None:
            self.face_uv = torch.as_tensor(self.face_uv, dtype=DTYPE).contiguous()
            if tuple(self.face_uv.shape) != (self.faces.shape[0], 3, 2):
                raise MeshError(f"{self.name}: face_uv must have shape [F,3,2] = [{self.faces.shape[0]},3,2], got {tuple(self.face_uv.shape)}")
        validate_mesh(self.x, self.uv, self.faces, self.name, self.face_uv)
        self.edges = unique_edges(self.faces)

    def corner_uv(self) -> torch.Tensor:
        """Material coordinates of every face corner [F,3,2]."""
        return self.face_uv if self.face_uv is not None else self.uv[self.faces]

    @property
    def num_vertices(self) -> int:
        return int(self.x.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])

    def size(self) -> float:
        """Characteristic size: the diagonal of the material-space bounding box (m)."""
        extent = self.uv.max(0).values - self.uv.min(0).values
        return float(torch.linalg.norm(extent))


def unique_edges(faces: torch.Tensor) -> torch.Tensor:
    """Unique undirected edges [E,2] (sorted vertex pairs) of a triangle mesh."""
    e = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = torch.sort(e, dim=1).values
    return torch.unique(e, dim=0)


def validate_mesh(x: torch.Tensor, uv: torch.Tensor, faces: torch.Tensor, name: str, face_uv: torch.Tensor | None = None) -> None:
    """Raise MeshError naming the first problem found in a cloth mesh."""
    if x.ndim != 2 or x.shape[1] != 3:
        raise MeshError(f"{name}: vertex positions must have shape [N,3], got {tuple(x.shape)}")
    if uv.ndim != 2 or uv.shape[1] != 2 or uv.shape[0] != x.shape[0]:
        raise MeshError(
            f"{name}: material coordinates (uv) must have shape [N,2] with N={x.shape[0]}, got "
            f"{tuple(uv.shape)}; give the OBJ 'vt' coordinates in metres or use a generated grid"
        )
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] == 0:
        raise MeshError(f"{name}: faces must be a non-empty [F,3] array, got {tuple(faces.shape)}")
    if int(faces.min()) < 0 or int(faces.max()) >= x.shape[0]:
        raise MeshError(f"{name}: face indices must lie in [0, {x.shape[0] - 1}]")
    if face_uv is not None and not bool(torch.isfinite(face_uv).all()):
        raise MeshError(f"{name}: face_uv holds NaN or infinite material coordinates")
    bad = ~torch.isfinite(x).all(1) | ~torch.isfinite(uv).all(1)
    if bool(bad.any()):
        i = int(torch.nonzero(bad)[0])
        raise MeshError(f"{name}: vertex {i} has a NaN or infinite position or uv")
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    if bool(repeated.any()):
        f = int(torch.nonzero(repeated)[0])
        raise MeshError(f"{name}: face {f} repeats a vertex {faces[f].tolist()}")
    _check_areas(x, uv[faces] if face_uv is None else face_uv, faces, name)
    _check_manifold(faces, name)


def _check_areas(x: torch.Tensor, corner_uv: torch.Tensor, faces: torch.Tensor, name: str) -> None:
    u0, u1, u2 = (corner_uv[:, k] for k in range(3))
    d1, d2 = u1 - u0, u2 - u0
    uv_area = 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).abs()
    p0, p1, p2 = (x[faces[:, k]] for k in range(3))
    xyz_area = 0.5 * torch.linalg.norm(torch.cross(p1 - p0, p2 - p0, dim=1), dim=1)
    scale = float(uv_area.mean()) if len(uv_area) else 0.0
    tiny = 1e-10 * max(scale, 1e-12)
    for label, area in (("material (uv)", uv_area), ("world", xyz_area)):
        small = area <= tiny
        if bool(small.any()):
            f = int(torch.nonzero(small)[0])
            raise MeshError(
                f"{name}: face {f} {faces[f].tolist()} has zero {label} area; remove degenerate "
                f"triangles (or check that 'vt' holds material coordinates in metres)"
            )


def _check_manifold(faces: torch.Tensor, name: str) -> None:
    e = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = torch.sort(e, dim=1).values
    uniq, counts = torch.unique(e, dim=0, return_counts=True)
    over = counts > 2
    if bool(over.any()):
        k = int(torch.nonzero(over)[0])
        raise MeshError(
            f"{name}: edge {uniq[k].tolist()} is shared by {int(counts[k])} faces (non-manifold); "
            f"each edge may border at most two triangles"
        )


def grid_mesh(
    resolution: tuple[int, int],
    size: tuple[float, float] = (1.0, 1.0),
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
    orientation: str = "horizontal",
    name: str = "cloth",
) -> ClothMesh:
    """A rectangular cloth of `resolution` = (nu, nv) vertices and `size` (m).

    Material u runs along world x; material v runs along world y ("horizontal", lying in the
    z = origin plane) or along world z ("vertical", hanging in the y = origin plane). The
    diagonals alternate so the triangulation has no preferred shear direction.
    """
    nu, nv = int(resolution[0]), int(resolution[1])
    if nu < 2 or nv < 2:
        raise MeshError(f"{name}: grid resolution must be at least 2x2 vertices, got {nu}x{nv}")
    if size[0] <= 0 or size[1] <= 0:
        raise MeshError(f"{name}: grid size must be positive, got {size}")
    us = np.linspace(0.0, size[0], nu)
    vs = np.linspace(0.0, size[1], nv)
    uu, vv = np.meshgrid(us, vs, indexing="xy")  # [nv, nu]
    uv = np.stack([uu.ravel(), vv.ravel()], 1)
    x = np.zeros((nu * nv, 3))
    x[:, 0] = uv[:, 0]
    if orientation == "horizontal":
        x[:, 1] = uv[:, 1]
    elif orientation == "vertical":
        x[:, 2] = uv[:, 1]
    else:
        raise MeshError(f"{name}: grid orientation must be 'horizontal' or 'vertical', got {orientation!r}")
    x += np.asarray(origin, dtype=np.float64)
    idx = np.arange(nu * nv).reshape(nv, nu)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    ii, jj = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="xy")
    flip = ((ii + jj) % 2 == 1).ravel()
    f1 = np.where(flip[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    f2 = np.where(flip[:, None], np.stack([b, d, c], 1), np.stack([a, d, c], 1))
    faces = np.concatenate([f1, f2])
    return ClothMesh(torch.from_numpy(x), torch.from_numpy(uv), torch.from_numpy(faces), name=name)


def grid_corner(mesh_resolution: tuple[int, int], corner: str) -> int:
    """Vertex index of a named corner of a grid made by `grid_mesh`.

    Names: 'top-left', 'top-right' (max v), 'bottom-left', 'bottom-right' (min v).
    """
    nu, nv = mesh_resolution
    table = {
        "bottom-left": 0,
        "bottom-right": nu - 1,
        "top-left": (nv - 1) * nu,
        "top-right": nv * nu - 1,
    }
    if corner not in table:
        raise MeshError(f"unknown grid corner {corner!r}; use one of {sorted(table)}")
    return table[corner]


def mesh_from_obj(path: str | Path, name: str | None = None) -> ClothMesh:
    """Load a cloth mesh from an OBJ whose `vt` coordinates are material space in metres."""
    from tryon.io.mesh_io import read_obj, split_by_uv

    obj = read_obj(path)
    if obj.uv is None and obj.face_uv is None:
        raise MeshError(
            f"{path}: the OBJ has no 'vt' texture coordinates; a cloth mesh needs material "
            f"coordinates (in metres) for every vertex"
        )
    vertices, faces, uv = split_by_uv(obj)
    check_material_scale(vertices, faces, uv, str(path))
    return ClothMesh(torch.from_numpy(vertices), torch.from_numpy(uv), torch.from_numpy(faces), name=name or Path(path).stem)


MATERIAL_SCALE_RANGE = (1 / 3, 3.0)  # median 3D / material edge length of a cloth at rest


def check_material_scale(x: np.ndarray, faces: np.ndarray, uv: np.ndarray, name: str) -> None:
    """Refuse material coordinates on another scale than the 3D mesh (0-1 texture
    coordinates on a 10 cm cloth would start the run at -90 % strain)."""
    x, faces, uv = np.asarray(x, np.float64), np.asarray(faces, np.int64), np.asarray(uv, np.float64)
    d3 = np.concatenate([np.linalg.norm(x[faces[:, a]] - x[faces[:, b]], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))])
    duv = np.concatenate([np.linalg.norm(uv[faces[:, a]] - uv[faces[:, b]], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))])
    ok = (duv > 0) & np.isfinite(duv) & np.isfinite(d3)
    if not ok.any():
        return  # degenerate material coordinates: validate_mesh names the face
    ratio = float(np.median(d3[ok] / duv[ok]))
    low, high = MATERIAL_SCALE_RANGE
    if not low <= ratio <= high:
        raise MeshError(f"{name}: the 'vt' coordinates are not material coordinates in metres (3D edges are {ratio:.3g}x "
                        f"their vt length, a {100 * (ratio - 1):+.0f} % strain at the start); 'vt' must be in "
                        "metres (the flat cloth's size), not 0-1 texture coordinates")
