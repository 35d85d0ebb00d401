"""What the draping network sees and predicts from.

- The body: the A-posed target body's vertices in the region the garment can touch (Anny's
  vertex order, so a 1D convolution runs along it), with their normals.
- The prior: the size's reference drape carried to the body by skinning (each garment
  vertex follows its nearest point on the fit model's skin to the same point on the
  person's). It is also the `skinning` baseline; the network predicts the correction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tryon.body.anny_model import ShapeParams, body_model
from tryon.body.measure import drafting_measurements
from tryon.body.pose import BodyPose, posed_body

REGION_DISTANCE = 0.08  # m: body vertices this close to a reference drape are in the region


def a_posed_body(params: ShapeParams) -> BodyPose:
    """The body `tryon drape` drapes on: Anny's shape, A-pose, crotch landmark."""
    shape = body_model().rest_shape(params)
    return posed_body(shape, "a", drafting_measurements(shape)["crotch_height"])


def body_region(references: list[tuple[np.ndarray, np.ndarray]], distance: float = REGION_DISTANCE) -> np.ndarray:
    """Sorted body vertex ids within `distance` of any (garment vertices, body vertices) reference."""
    from scipy.spatial import cKDTree

    keep = set()
    for garment, body in references:
        d, _ = cKDTree(garment).query(body, distance_upper_bound=distance)
        keep.update(np.nonzero(np.isfinite(d))[0].tolist())
    return np.array(sorted(keep), np.int64)


@dataclass
class SkinPrior:
    """A reference drape bound to its fit model's skin (nearest face + barycentrics)."""

    x_ref: np.ndarray      # [N,3] the reference drape
    corners: np.ndarray    # [N,3] body vertex ids of each garment vertex's nearest face
    bary: np.ndarray       # [N,3]
    anchor: np.ndarray     # [N,3] those nearest points on the fit model

    @classmethod
    def bind(cls, x_ref: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray) -> "SkinPrior":
        from tryon.sim.geometry import nearest_surface_locations

        _, face, bary = nearest_surface_locations(x_ref, body_vertices, body_faces)
        corners = body_faces[face]
        anchor = np.einsum("nk,nkd->nd", bary, body_vertices[corners])
        return cls(np.asarray(x_ref, np.float64), corners.astype(np.int64), bary, anchor)

    def carry(self, body_vertices: np.ndarray) -> np.ndarray:
        """The reference drape carried to a body of the same topology."""
        return self.x_ref + np.einsum("nk,nkd->nd", self.bary, body_vertices[self.corners]) - self.anchor

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}x_ref": self.x_ref.astype(np.float32), f"{prefix}corners": self.corners.astype(np.int32),
                f"{prefix}bary": self.bary.astype(np.float32), f"{prefix}anchor": self.anchor.astype(np.float32)}

    @classmethod
    def from_arrays(cls, a: dict, prefix: str) -> "SkinPrior":
        return cls(*(np.asarray(a[f"{prefix}{k}"], np.float64 if k != "corners" else np.int64)
                     for k in ("x_ref", "corners", "bary", "anchor")))
