"""A garment from an OBJ file instead of a drafted pattern.

The OBJ holds the sewn garment as one welded surface, in metres with Z up, placed around
the person's body in the A-pose (`body.obj` of any `tryon drape` run shows where that is),
and its texture coordinates are material space: each face corner's `vt` is its position
in the flat panel, in metres, with the grain along +v. Faces meeting at a seam share 3D
vertices and keep their own `vt`s, the way pattern-making tools export.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tryon.errors import InputFileError
from tryon.drape.dress import DressedGarment, clear_of_skin
from tryon.body.pose import BodyPose

# median (3D edge length / material edge length) a garment at rest stays within
UV_SCALE_RANGE = (0.5, 2.0)


def garment_from_obj(path: str | Path, body: BodyPose | None = None, clearance: float = 0.006) -> DressedGarment:
    """Read a garment OBJ (see the module docstring); with `body`, vertices closer to the
    skin than `clearance` (or inside it) are moved out along the skin normal."""
    from tryon.io.mesh_io import read_obj

    path = Path(path)
    obj = read_obj(path)
    if obj.face_uv is None or obj.uv_coords is None:
        raise InputFileError(f"{path}: a garment OBJ needs texture coordinates (vt, f v/vt) in material space (metres)")
    x = np.asarray(obj.vertices, dtype=np.float64)
    faces = np.asarray(obj.faces, dtype=np.int64)
    corner_uv = np.asarray(obj.uv_coords, dtype=np.float64)[obj.face_uv]
    _check_uv_scale(path, x, faces, corner_uv)
    used = np.unique(faces)
    if len(used) != len(x):  # drop vertices no face uses
        remap = np.full(len(x), -1)
        remap[used] = np.arange(len(used))
        x, faces = x[used], remap[faces]
    uv = np.zeros((len(x), 2))
    uv[faces.reshape(-1)] = corner_uv.reshape(-1, 2)
    stats = {"source": str(path), "vertices": int(len(x)), "faces": int(len(faces)), "pushed_out_at_start": 0}
    if body is not None:
        x, stats["pushed_out_at_start"] = clear_of_skin(x, body, clearance)
    return DressedGarment(x, faces, uv, corner_uv, np.zeros(len(faces), dtype=np.int64), None, np.zeros(0, np.int64), stats)


def _check_uv_scale(path: Path, x: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray) -> None:
    ratios = []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        d3 = np.linalg.norm(x[faces[:, a]] - x[faces[:, b]], axis=1)
        duv = np.linalg.norm(corner_uv[:, a] - corner_uv[:, b], axis=1)
        ok = duv > 1e-12
        ratios.append(d3[ok] / duv[ok])
    r = np.concatenate(ratios)
    if len(r) == 0:
        raise InputFileError(f"{path}: all texture coordinates coincide; they must be material coordinates in metres")
    med = float(np.median(r))
    if not UV_SCALE_RANGE[0] <= med <= UV_SCALE_RANGE[1]:
        raise InputFileError(f"{path}: the texture coordinates are not material coordinates in metres (3D edges are "
                             f"{med:.3g}x their vt length; expected about 1). Export the flat panels' coordinates in "
                             f"metres as vt.")
