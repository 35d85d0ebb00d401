"""Rest-state precomputation for the cloth force terms (ARCSim 0.3.1 conventions).

Everything here runs once per mesh (or once per remesh), not every step:

* `rest_state`: per-face inverse material-space edge matrix ``Dm^-1`` and material area,
  used by the membrane term (`tryon.sim.forces.membrane`).
* `build_hinges`: the interior edges with their two opposite vertices, ordered exactly like
  ARCSim's ``Edge`` (``n[0], n[1]``, ``adjf[0], adjf[1]``), used by the bending term.
(The bending term's rest data per hinge, `tryon.sim.forces.bending.hinge_rest_data`, needs
its dihedral angle and lives beside it.)
"""

from __future__ import annotations

import numpy as np
import torch

from tryon.errors import MeshError

DTYPE = torch.float64

# A material triangle whose |det Dm| is below this fraction of its squared edge lengths is
# treated as degenerate (collinear or coincident material coordinates).
DEGENERATE_RELATIVE_AREA = 1e-10


def check_vertices(values: torch.Tensor, width: int, what: str) -> torch.Tensor:
    """Validate a finite ``[N, width]`` float tensor and return it as float64."""
    if not isinstance(values, torch.Tensor) or values.ndim != 2 or values.shape[1] != width:
        shape = tuple(values.shape) if isinstance(values, torch.Tensor) else type(values).__name__
        raise MeshError(f"{what} must be a tensor of shape [N, {width}], got {shape}; pass one row per vertex")
    if not values.is_floating_point():
        values = values.to(DTYPE)
    if not bool(torch.isfinite(values.detach()).all()):
        bad = torch.nonzero(~torch.isfinite(values.detach()).all(dim=1)).flatten()[:5].tolist()
        raise MeshError(f"{what} contains NaN or infinite values (vertices {bad}); fix the input coordinates")
    return values.to(DTYPE)


def check_faces(faces: torch.Tensor, num_vertices: int, what: str = "faces") -> torch.Tensor:
    """Validate an int64 ``[F, 3]`` face array indexing ``num_vertices`` vertices."""
    if not isinstance(faces, torch.Tensor) or faces.ndim != 2 or faces.shape[1] != 3:
        shape = tuple(faces.shape) if isinstance(faces, torch.Tensor) else type(faces).__name__
        raise MeshError(f"{what} must be an integer tensor of shape [F, 3], got {shape}; triangulate the mesh")
    if faces.is_floating_point() or faces.dtype == torch.bool:
        raise MeshError(f"{what} must hold integer vertex indices, got dtype {faces.dtype}")
    faces = faces.to(torch.int64)
    if faces.numel() and (int(faces.min()) < 0 or int(faces.max()) >= num_vertices):
        raise MeshError(
            f"{what} index vertices in [{int(faces.min())}, {int(faces.max())}] but there are only "
            f"{num_vertices} vertices; fix the face indices (0-based)"
        )
    return faces


def check_distinct_corners(faces: torch.Tensor) -> None:
    """Raise `MeshError` if a face uses the same vertex twice."""
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    if bool(repeated.any()):
        f = int(torch.nonzero(repeated)[0])
        raise MeshError(f"face {f} {faces[f].tolist()} repeats a vertex; remove degenerate faces from the mesh")


def rest_state(uv: torch.Tensor, faces: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse material edge matrices and material areas of the triangles.

    ``Dm = [u_j - u_i, u_k - u_i]`` (2x2, columns are material-space edges) for each face
    ``(i, j, k)``; the deformation gradient is then ``F = [x_j - x_i, x_k - x_i] @ Dm^-1``
    (Narain et al. 2012 / ARCSim ``compute_ms_data``). The rest area is ``|det Dm| / 2``:
    ARCSim's material area is unsigned, so a uniformly mirrored UV chart (e.g. v pointing
    down) is accepted and gives the same physics.

    Raises `MeshError` for degenerate material triangles (zero area, collinear or coincident
    uv) and for triangles folded over in the chart (signed area opposite to the mesh's
    dominant orientation), naming the face index.

    Returns ``(Dm_inv [F, 2, 2], rest_area [F])`` in float64.
    """
    uv = check_vertices(uv, 2, "uv (material coordinates)")
    faces = check_faces(faces, uv.shape[0])
    check_distinct_corners(faces)
    ui, uj, uk = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
    d1, d2 = uj - ui, uk - ui
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    _reject_degenerate(det, d1, d2)
    _reject_folded(det)
    inv_det = 1.0 / det
    # inverse of [[d1u, d2u], [d1v, d2v]]
    row0 = torch.stack([d2[:, 1], -d2[:, 0]], dim=1) * inv_det[:, None]
    row1 = torch.stack([-d1[:, 1], d1[:, 0]], dim=1) * inv_det[:, None]
    Dm_inv = torch.stack([row0, row1], dim=1)
    return Dm_inv, 0.5 * det.abs()


def _reject_degenerate(det: torch.Tensor, d1: torch.Tensor, d2: torch.Tensor) -> None:
    scale = (d1 * d1).sum(1) + (d2 * d2).sum(1)
    degenerate = det.detach().abs() <= DEGENERATE_RELATIVE_AREA * scale.detach()
    if bool(degenerate.any()):
        bad = torch.nonzero(degenerate).flatten()
        raise MeshError(
            f"{bad.numel()} material (uv) triangle(s) have zero area, first is face {int(bad[0])}; "
            "give every face three distinct, non-collinear material coordinates (remove slivers)"
        )


def _reject_folded(det: torch.Tensor) -> None:
    positive = int((det > 0).sum())
    negative = det.numel() - positive
    minority = det < 0 if positive >= negative else det > 0
    if bool(minority.any()):
        bad = torch.nonzero(minority).flatten()
        raise MeshError(
            f"{bad.numel()} material (uv) triangle(s) are flipped relative to the rest of the chart "
            f"(negative area), first is face {int(bad[0])}; the uv layout folds over itself there, "
            "fix the uv coordinates or the face's vertex order"
        )


def build_hinges(faces: torch.Tensor, return_faces: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Interior edges of a triangle mesh as hinges ``[H, 4] = (v0, v1, v2, v3)``.

    Follows ARCSim's ``Mesh::add(Face*)``: an edge's node order ``(v0, v1)`` is the order in
    which the first face containing it (lowest face index) traverses it, that face is
    ``adjf[0]`` = ``(v0, v1, v2)`` (cyclically), and the other face ``adjf[1]`` traverses it
    as ``v1 -> v0`` and has opposite vertex ``v3``. Boundary edges (one face) have no hinge.

    Raises `MeshError` for an edge shared by more than two faces (non-manifold) or by two
    faces that traverse it in the same direction (inconsistent orientation), naming the edge.
    With ``return_faces=True`` also returns the two face indices ``[H, 2]`` of each hinge.
    """
    faces = check_faces(faces, int(faces.max()) + 1 if faces.numel() else 0)
    check_distinct_corners(faces)
    num_faces = faces.shape[0]
    start = faces.reshape(-1)
    end = faces[:, [1, 2, 0]].reshape(-1)
    opposite = faces[:, [2, 0, 1]].reshape(-1)
    lo, hi = torch.minimum(start, end), torch.maximum(start, end)
    key = lo * (int(faces.max()) + 1 if num_faces else 1) + hi
    order = torch.argsort(key, stable=True)
    _, counts = torch.unique_consecutive(key[order], return_counts=True)
    group_start = torch.cumsum(counts, 0) - counts
    _reject_non_manifold(counts, group_start, order, lo, hi)
    interior = counts == 2
    first, second = order[group_start[interior]], order[group_start[interior] + 1]
    _reject_misoriented(first, second, start, end)
    hinges = torch.stack([start[first], end[first], opposite[first], opposite[second]], dim=1)
    if return_faces:
        return hinges, torch.stack([first // 3, second // 3], dim=1)
    return hinges


def _reject_non_manifold(
    counts: torch.Tensor, group_start: torch.Tensor, order: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor
) -> None:
    if bool((counts > 2).any()):
        g = int(torch.nonzero(counts > 2)[0])
        h = int(order[group_start[g]])
        members = order[group_start[g] : group_start[g] + counts[g]] // 3
        raise MeshError(
            f"non-manifold edge ({int(lo[h])}, {int(hi[h])}) is shared by {int(counts[g])} faces "
            f"{members.tolist()}; split the mesh so every edge has at most two faces"
        )


def _reject_misoriented(first: torch.Tensor, second: torch.Tensor, start: torch.Tensor, end: torch.Tensor) -> None:
    same_direction = start[second] == start[first]
    if bool(same_direction.any()):
        h = int(torch.nonzero(same_direction)[0])
        f0, f1 = int(first[h]) // 3, int(second[h]) // 3
        raise MeshError(
            f"faces {f0} and {f1} traverse their shared edge ({int(start[first[h]])}, {int(end[first[h]])}) in the "
            "same direction (inconsistent orientation or duplicated face); orient all faces consistently"
        )


def numba_path_ok(*tensors: torch.Tensor) -> bool:
    """True when the numba fast path may replace the torch ops: CPU float64 inputs and no
    autograd graph to record (grad mode off, or no input requiring grad)."""
    if any(t.device.type != "cpu" or t.dtype != DTYPE for t in tensors):
        return False
    return not (torch.is_grad_enabled() and any(t.requires_grad for t in tensors))


def as_numpy(t: torch.Tensor, dtype: type = np.float64) -> np.ndarray:
    """Contiguous numpy view (or copy) of a CPU tensor, detached."""
    return np.ascontiguousarray(t.detach().numpy(), dtype=dtype)


def output_buffer(shape: tuple[int, ...], out: torch.Tensor | None, what: str) -> torch.Tensor:
    """A float64 CPU tensor of ``shape`` to fill: ``out`` if given (reused between steps to
    skip page-faulting a fresh large array), else a new one allocated through numpy."""
    if out is None:
        return torch.from_numpy(np.empty(shape))
    if tuple(out.shape) != shape or out.dtype != DTYPE or out.device.type != "cpu" or not out.is_contiguous():
        raise ValueError(f"{what} must be a contiguous float64 CPU tensor of shape {shape}, got {tuple(out.shape)}")
    return out
