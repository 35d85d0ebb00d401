"""Mesh files: Wavefront OBJ in and out, binary PLY and GLB out.

All writers are atomic (temporary file + rename, see :mod:`tryon.io.atomic`). Arrays may
be numpy arrays or torch tensors; vertices are ``[N, 3]`` metres, faces ``[F, 3]``
zero-based vertex indices.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tryon.errors import InputFileError, MeshError
from tryon.io.atomic import atomic_write

__all__ = ["ObjMesh", "read_obj", "split_by_uv", "write_obj", "write_ply", "write_glb"]

log = logging.getLogger(__name__)

PathLike = str | os.PathLike[str]


@dataclass
class ObjMesh:
    """Content of an OBJ file, triangulated.

    ``uv`` is set when every vertex carries exactly one texture coordinate (no UV
    seams); vertices no face references get ``(0, 0)``. ``face_uv``/``uv_coords`` are
    the per-corner texture coordinates (``uv_coords[face_uv[f, k]]`` is the uv of corner
    ``k`` of face ``f``), set whenever every face has ``vt`` indices; use
    :func:`split_by_uv` to get a mesh with one uv per vertex when there are seams.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    face_uv: np.ndarray | None = None
    uv_coords: np.ndarray | None = None


# ----------------------------------------------------------------------------- reading


class _ObjParser:
    """Line-by-line OBJ reader that remembers the source line of every record for errors."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.verts: list[list[float]] = []
        self.vert_lines: list[int] = []
        self.uvs: list[list[float]] = []
        self.tri_v: list[int] = []
        self.tri_t: list[int] = []
        self.tri_lines: list[int] = []
        self.faces_with_uv = 0
        self.faces_without_uv = 0

    def fail(self, lineno: int, what: str) -> InputFileError:
        return InputFileError(f"{self.path}:{lineno}: {what}; fix or re-export the OBJ file")

    def floats(self, parts: list[str], count: int, lineno: int) -> list[float]:
        try:
            return [float(p) for p in parts[:count]]
        except ValueError:
            raise self.fail(lineno, f"expected numbers, got {' '.join(parts)!r}") from None

    def parse_line(self, lineno: int, line: str) -> None:
        parts = line.split()
        key = parts[0]
        if key == "v":
            if len(parts) < 4:
                raise self.fail(lineno, "vertex line needs 3 coordinates 'v x y z'")
            self.verts.append(self.floats(parts[1:], 3, lineno))
            self.vert_lines.append(lineno)
        elif key == "vt":
            if len(parts) < 2:
                raise self.fail(lineno, "texture line needs coordinates 'vt u v'")
            uv = self.floats(parts[1:], 2, lineno)
            self.uvs.append(uv if len(uv) == 2 else [uv[0], 0.0])
        elif key == "f":
            self.parse_face(parts[1:], lineno)
        # vn, vp, o, g, s, l, usemtl, mtllib and unknown keywords carry nothing we use.

    def resolve(self, token: str, count: int, lineno: int, kind: str) -> int:
        """OBJ index (1-based, or negative = relative to the records read so far) to 0-based."""
        try:
            idx = int(token)
        except ValueError:
            raise self.fail(lineno, f"bad {kind} index {token!r}") from None
        if idx == 0:
            raise self.fail(lineno, f"{kind} index 0 is invalid (OBJ indices start at 1)")
        return idx - 1 if idx > 0 else count + idx

    def parse_face(self, corners: list[str], lineno: int) -> None:
        if len(corners) < 3:
            raise self.fail(lineno, f"face needs at least 3 corners, got {len(corners)}")
        v_idx: list[int] = []
        t_idx: list[int] = []
        for token in corners:
            fields = token.split("/")
            v_idx.append(self.resolve(fields[0], len(self.verts), lineno, "vertex"))
            if len(fields) > 1 and fields[1]:
                t_idx.append(self.resolve(fields[1], len(self.uvs), lineno, "texture"))
        if t_idx and len(t_idx) != len(v_idx):
            raise self.fail(lineno, "some corners of this face have texture indices and others do not")
        n_tri = len(v_idx) - 2
        # Polygon -> triangle fan (0, k, k+1).
        for k in range(1, len(v_idx) - 1):
            self.tri_v.extend((v_idx[0], v_idx[k], v_idx[k + 1]))
            if t_idx:
                self.tri_t.extend((t_idx[0], t_idx[k], t_idx[k + 1]))
        self.tri_lines.extend([lineno] * n_tri)
        if t_idx:
            self.faces_with_uv += 1
        else:
            self.faces_without_uv += 1


def _read_text(path: Path, allow_large: bool | None = None) -> str:
    from tryon.limits import check_file_size

    if path.exists():
        check_file_size(path, "OBJ file", allow_large)
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise InputFileError(f"OBJ file {path} does not exist; check the path") from None
    except OSError as exc:
        raise InputFileError(f"cannot read OBJ file {path}: {exc}") from exc


def _check_indices(idx: np.ndarray, count: int, lines: np.ndarray, path: Path, kind: str) -> None:
    bad = np.nonzero(((idx < 0) | (idx >= count)).any(axis=1))[0]
    if bad.size:
        raise InputFileError(
            f"{path}:{int(lines[bad[0]])}: {kind} index out of range (the file has {count} {kind} records)"
            "; fix or re-export the OBJ file"
        )


def _per_vertex_uv(n_vertices: int, faces: np.ndarray, face_uv: np.ndarray, coords: np.ndarray) -> np.ndarray | None:
    """One uv per vertex if every corner of a vertex uses the same uv value, else None."""
    corner_uv = coords[face_uv.reshape(-1)]
    corner_v = faces.reshape(-1)
    uv = np.zeros((n_vertices, 2))
    uv[corner_v] = corner_uv
    return uv if np.array_equal(uv[corner_v], corner_uv) else None


def read_obj(path: PathLike, allow_large: bool | None = None) -> ObjMesh:
    """Read a Wavefront OBJ file; polygons are triangulated as fans.

    Supports ``f v``, ``f v/vt``, ``f v/vt/vn`` and ``f v//vn`` corners and negative
    (relative) indices. Raises :class:`InputFileError` naming the file and line for
    malformed lines and out-of-range indices, :class:`MeshError` for NaN/inf
    coordinates or a file without faces, :class:`LimitError` for files larger than
    ``max_file_bytes`` (unless `allow_large`).
    """
    path = Path(path)
    parser = _ObjParser(path)
    for lineno, raw in enumerate(_read_text(path, allow_large).splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if line:
            parser.parse_line(lineno, line)

    vertices = np.asarray(parser.verts, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        line = parser.vert_lines[int(np.argmin(finite))]
        raise MeshError(f"{path}:{line}: vertex coordinate is NaN or infinite; fix the exporter output")
    if not parser.tri_lines:
        raise MeshError(f"OBJ file {path} has no faces ('f' lines); a surface mesh is needed")
    lines = np.asarray(parser.tri_lines)
    faces = np.asarray(parser.tri_v, dtype=np.int64).reshape(-1, 3)
    _check_indices(faces, len(vertices), lines, path, "vertex")

    mesh = ObjMesh(vertices=vertices, faces=faces)
    if parser.faces_with_uv and parser.faces_without_uv:
        log.warning("%s: only some faces have texture coordinates; ignoring the texture coordinates", path)
    elif parser.faces_with_uv:
        coords = np.asarray(parser.uvs, dtype=np.float64).reshape(-1, 2)
        if not np.isfinite(coords).all():
            raise MeshError(f"{path}: a 'vt' texture coordinate is NaN or infinite; fix the exporter output")
        face_uv = np.asarray(parser.tri_t, dtype=np.int64).reshape(-1, 3)
        _check_indices(face_uv, len(coords), lines, path, "texture")
        mesh.face_uv, mesh.uv_coords = face_uv, coords
        mesh.uv = _per_vertex_uv(len(vertices), faces, face_uv, coords)
    return mesh


def split_by_uv(obj: ObjMesh, return_index: bool = False) -> tuple[np.ndarray, ...]:
    """Duplicate vertices along UV seams so that every vertex has exactly one uv.

    Returns ``(vertices [M,3], faces [F,3], uv [M,2])``; with ``return_index=True`` also
    ``source [M]``, the index of the original vertex each new vertex copies (vertices
    sharing a source are the two sides of a seam). Corners whose uv values are equal
    share a vertex even if the file used different ``vt`` records. Vertices no face
    uses are dropped.
    """
    if obj.face_uv is None or obj.uv_coords is None:
        raise MeshError("split_by_uv needs an OBJ with texture coordinates ('vt' and f v/vt corners)")
    unique_coords, canon = np.unique(obj.uv_coords, axis=0, return_inverse=True)
    pairs = np.stack([obj.faces.reshape(-1), canon.reshape(-1)[obj.face_uv.reshape(-1)]], axis=1)
    unique_pairs, inverse = np.unique(pairs, axis=0, return_inverse=True)
    source = unique_pairs[:, 0]
    vertices = obj.vertices[source]
    uv = unique_coords[unique_pairs[:, 1]]
    faces = inverse.reshape(-1, 3).astype(np.int64)
    if return_index:
        return vertices, faces, uv, source
    return vertices, faces, uv


# ----------------------------------------------------------------------------- writing


def _as_numpy(x: Any, dtype: type | np.dtype | None = None) -> np.ndarray:
    if hasattr(x, "detach"):  # torch tensor
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=dtype)


def _checked_mesh(vertices: Any, faces: Any, out: Path) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert a mesh about to be written to ``out``."""
    v = _as_numpy(vertices, np.float64)
    f = _as_numpy(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"writing {out}: vertices must be [N, 3], got shape {tuple(v.shape)}")
    if not np.isfinite(v).all():
        raise MeshError(f"writing {out}: vertices contain NaN or inf; check the simulation output")
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and not np.issubdtype(f.dtype, np.integer)):
        raise MeshError(f"writing {out}: faces must be an integer [F, 3] array, got {f.dtype} {tuple(f.shape)}")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise MeshError(f"writing {out}: face indices must lie in [0, {len(v)}), got [{f.min()}, {f.max()}]")
    return v, f


def _checked_uv(uv: Any, n: int, out: Path) -> np.ndarray:
    arr = _as_numpy(uv, np.float64)
    if arr.shape != (n, 2) or not np.isfinite(arr).all():
        raise MeshError(f"writing {out}: uv must be finite [N, 2] = [{n}, 2], got shape {tuple(arr.shape)}")
    return arr


def write_obj(path: PathLike, vertices: Any, faces: Any, uv: Any = None, precision: int = 9,
              corner_uv: Any = None) -> Path:
    """Write a triangle mesh as OBJ (atomic); ``uv [N,2]`` becomes one ``vt`` per vertex,
    or ``corner_uv [F,3,2]`` one per face corner (seams keep both sides' coordinates).

    ``precision`` is the number of significant digits (9 keeps sub-micrometre detail
    for metre-scale meshes).
    """
    out = Path(path)
    v, f = _checked_mesh(vertices, faces, out)
    num = f"%.{precision}g"
    with atomic_write(out, "w") as fh:
        fh.write("# written by tryon\n")
        np.savetxt(fh, v, fmt=f"v {num} {num} {num}")
        if corner_uv is not None:
            c = _as_numpy(corner_uv).astype(np.float64)
            if c.shape != (len(f), 3, 2) or not np.isfinite(c).all():
                raise MeshError(f"writing {out}: corner_uv must be finite [{len(f)}, 3, 2], got shape {tuple(c.shape)}")
            coords, index = np.unique(c.reshape(-1, 2), axis=0, return_inverse=True)
            np.savetxt(fh, coords, fmt=f"vt {num} {num}")
            corners = np.stack([f + 1, index.reshape(-1, 3) + 1], axis=2).reshape(len(f), 6)
            np.savetxt(fh, corners, fmt="f %d/%d %d/%d %d/%d")
        elif uv is None:
            np.savetxt(fh, f + 1, fmt="f %d %d %d")
        else:
            np.savetxt(fh, _checked_uv(uv, len(v), out), fmt=f"vt {num} {num}")
            np.savetxt(fh, np.repeat(f + 1, 2, axis=1), fmt="f %d/%d %d/%d %d/%d")
    return out


def _colors_uint8(colors: Any, n: int, out: Path, what: str) -> np.ndarray:
    """Colours as uint8 ``[n, 3|4]``; floats are read as 0..1, integers as 0..255."""
    c = _as_numpy(colors)
    if c.ndim != 2 or c.shape[0] != n or c.shape[1] not in (3, 4):
        raise MeshError(f"writing {out}: {what} must be [{n}, 3] or [{n}, 4], got shape {tuple(c.shape)}")
    if np.issubdtype(c.dtype, np.floating):
        if not np.isfinite(c).all():
            raise MeshError(f"writing {out}: {what} contain NaN or inf")
        c = np.rint(np.clip(c, 0.0, 1.0) * 255.0)
    return np.clip(c, 0, 255).astype(np.uint8)


def write_ply(path: PathLike, vertices: Any, faces: Any, vertex_colors: Any = None) -> Path:
    """Write a binary little-endian PLY (float32 positions, optional uchar RGB(A) colours), atomically."""
    out = Path(path)
    v, f = _checked_mesh(vertices, faces, out)
    fields: list[tuple[str, str, int]] = [("xyz", "<f4", 3)]
    header = ["ply", "format binary_little_endian 1.0", "comment written by tryon", f"element vertex {len(v)}"]
    header += [f"property float {a}" for a in "xyz"]
    colors = None
    if vertex_colors is not None:
        colors = _colors_uint8(vertex_colors, len(v), out, "vertex_colors")
        fields.append(("rgba", "u1", colors.shape[1]))
        header += [f"property uchar {c}" for c in ("red", "green", "blue", "alpha")[: colors.shape[1]]]
    header += [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]

    vrec = np.empty(len(v), dtype=np.dtype(fields))
    vrec["xyz"] = v
    if colors is not None:
        vrec["rgba"] = colors
    frec = np.empty(len(f), dtype=np.dtype([("n", "u1"), ("idx", "<i4", 3)]))
    frec["n"] = 3
    frec["idx"] = f
    with atomic_write(out, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(vrec.tobytes())
        fh.write(frec.tobytes())
    return out


# Z-up (Anny / simulation frame) to glTF's Y-up: (x, y, z) -> (x, z, -y).
_Z_UP_TO_Y_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)


def _glb_visual(color: Any, n: int, name: str, out: Path) -> Any:
    """Uniform colour -> double-sided PBR material; per-vertex colours -> COLOR_0."""
    from trimesh.visual import ColorVisuals, TextureVisuals
    from trimesh.visual.material import PBRMaterial

    if color is None:
        color = (0.7, 0.7, 0.7, 1.0)
    arr = _as_numpy(color)
    if arr.ndim == 2:
        return ColorVisuals(vertex_colors=_colors_uint8(arr, n, out, f"colours of mesh {name!r}"))
    if arr.shape not in ((3,), (4,)):
        raise MeshError(f"writing {out}: colour of mesh {name!r} must be RGB(A) or [N, 3|4], got {tuple(arr.shape)}")
    rgba = _colors_uint8(arr[None], 1, out, f"colour of mesh {name!r}")[0]
    if rgba.shape[0] == 3:
        rgba = np.append(rgba, np.uint8(255))
    material = PBRMaterial(
        name=f"{name}_material", baseColorFactor=rgba, metallicFactor=0.0, roughnessFactor=0.8, doubleSided=True
    )
    return TextureVisuals(material=material)


def write_glb(path: PathLike, meshes: Sequence[Sequence[Any]], y_up: bool = True) -> Path:
    """Write several meshes as one binary glTF scene (atomic).

    ``meshes`` holds ``(vertices, faces, color, name)`` tuples (``name`` optional);
    ``color`` is an RGB(A) tuple (floats 0..1 or ints 0..255) for a uniform
    double-sided material, or per-vertex colours ``[N, 3|4]``, or None for grey. With
    ``y_up`` (default) each node carries the rotation from the project's Z-up frame to
    glTF's Y-up frame (geometry stays in the original coordinates), so viewers show
    the body upright and facing +Z (glTF's forward).
    """
    import trimesh

    out = Path(path)
    if len(meshes) == 0:
        raise MeshError(f"writing {out}: no meshes given")
    scene = trimesh.Scene()
    transform = _Z_UP_TO_Y_UP if y_up else np.eye(4)
    used: set[str] = set()
    for i, item in enumerate(meshes):
        if len(item) not in (3, 4):
            raise MeshError(f"writing {out}: mesh {i} must be (vertices, faces, color[, name]), got {len(item)} items")
        name = str(item[3]) if len(item) == 4 and item[3] else f"mesh_{i}"
        if name in used:
            name = f"{name}_{i}"
        used.add(name)
        v, f = _checked_mesh(item[0], item[1], out)
        mesh = trimesh.Trimesh(vertices=v, faces=f, process=False, visual=_glb_visual(item[2], len(v), name, out))
        scene.add_geometry(mesh, geom_name=name, node_name=name, transform=transform)
    data = scene.export(file_type="glb")
    with atomic_write(out, "wb") as fh:
        fh.write(data)
    return out

