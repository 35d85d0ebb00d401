"""Everything fixed for one body and garment: the KDSM rig.

`KdsmRig.build(rest)` takes a pose dataset's rest drape (the garment at rest on the body
in the A-pose) and builds the volume around the body where the garment can reach, its
skinning, and the garment's binding to the skin (for the surface-offset baseline and
Method 2). It then turns a pose (per-bone axis-angle, tryon.body.pose convention) into
bone transforms, the posed body, the skinned garment, and the per-vertex targets each
method learns:

| method | target per vertex | prediction to positions |
|---|---|---|
| `skinning` | nothing | the rest drape's material points skinned through the volume |
| `jin-uvn` | offset from the skin point in its tangent-normal frame | skin point + frame x offset |
| `kdsm-method1`, `-method2`, `-hybrid` | d = u(theta) - u0 (material space) | u0 + d embedded in the rest volume, skinned |
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tryon.kdsm.embed import embed, reconstruct, smooth_offsets
from tryon.kdsm.offsets import SurfaceBinding
from tryon.kdsm.skinning import VolumeSkin, skin_volume
from tryon.kdsm.volume import TetVolume, build_volume

METHODS = ("skinning", "jin-uvn", "kdsm-method1", "kdsm-method2", "kdsm-hybrid")
MARGIN = 0.05          # m around the rest drape's bounding box that the volume covers
# Screened-Poisson strength of the hybrid's d (graph Laplacian units). 0.25 rebuilds from-rest
# poses to 0.13 cm (1: 0.28 cm) and trained to 12 % lower validation error than 1.
HYBRID_SMOOTHING = 0.25
SMOOTHING_BEFORE_SETTING = 1.0  # what hybrids were smoothed with before it was a setting (cards without it)


@dataclass
class KdsmRig:
    volume: TetVolume
    skin: VolumeSkin
    binding: SurfaceBinding
    x0: np.ndarray              # rest drape [n,3] (= its material points)
    faces: np.ndarray           # garment faces
    shape: object               # BodyShape
    rest_body: np.ndarray       # body vertices in the A-pose [V,3]

    @classmethod
    def build(cls, garment_vertices: np.ndarray, garment_faces: np.ndarray, shape, cell: float = 0.02,
              inner: float = 0.01, outer: float = 0.10) -> "KdsmRig":
        from tryon.body.pose import named_pose, posed_body

        body = posed_body(shape, "a")
        x0 = np.asarray(garment_vertices, np.float64)
        volume = build_volume(body.vertices, body.faces, cell, inner, outer, bounds=(x0.min(0) - MARGIN, x0.max(0) + MARGIN))
        G_a = _transforms(shape, named_pose(shape, "a"))
        skin = skin_volume(volume, body.vertices, body.faces, shape.weight_index, shape.weight, G_a)
        return cls(volume, skin, SurfaceBinding.bind(x0, body.vertices, body.faces), x0, np.asarray(garment_faces),
                   shape, body.vertices)

    # -- poses
    def transforms(self, pose: np.ndarray, translation: np.ndarray | None = None) -> np.ndarray:
        """Bone transforms [J,4,4] of per-bone axis-angle rotations [J,3] (and a root translation)."""
        from tryon.body.pose import axis_angle

        return _transforms(self.shape, axis_angle(np.asarray(pose, np.float64)), translation)

    def body(self, G: np.ndarray) -> np.ndarray:
        """The body's vertices [V,3] under bone transforms G."""
        s = self.shape
        M = np.einsum("vk,vkab->vab", s.weight, G[s.weight_index])
        v = s.vertices.numpy()
        return np.einsum("vab,vb->va", M[:, :3, :3], v) + M[:, :3, 3]

    # -- per method
    def skinned(self, G: np.ndarray) -> np.ndarray:
        """The skinning baseline: the rest drape carried by the volume."""
        return reconstruct(self.x0, self.volume, self.skin, G)

    def target(self, method: str, x: np.ndarray, G: np.ndarray, body: np.ndarray | None = None,
               smoothing: float = HYBRID_SMOOTHING) -> np.ndarray:
        """What `method` learns [n,3] for cloth `x` in the pose of G (`smoothing`: the
        screened-Poisson strength applied to the hybrid's d)."""
        body = self.body(G) if body is None else body
        faces = self.shape.faces
        if method == "jin-uvn":
            return self.binding.offsets(x, body, faces)
        if method not in ("kdsm-method1", "kdsm-method2", "kdsm-hybrid"):
            raise ValueError(f"method {method!r} has no target; methods: {', '.join(METHODS)}")
        kind = method.split("-")[1]
        m2 = None
        if kind in ("method2", "hybrid"):
            m2 = self.binding.positions(self.binding.offsets(x, body, faces), self.rest_body, faces)
        posed = self.skin.pose(self.volume.vertices, G)
        d = embed(x, posed, self.volume, kind, surface_material=m2).material - self.x0
        return smooth_offsets(d, self.faces, smoothing) if kind == "hybrid" else d

    def positions(self, method: str, value: np.ndarray | None, G: np.ndarray, body: np.ndarray | None = None,
                  located: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Cloth positions [n,3] from a method's per-vertex value in the pose of G (KDSM
        methods: `located`, the material points' parents if already found)."""
        if method == "skinning":
            return self.skinned(G)
        if method == "jin-uvn":
            return self.binding.positions(value, self.body(G) if body is None else body, self.shape.faces)
        return reconstruct(self.x0 + value, self.volume, self.skin, G, located=located)


def _transforms(shape, rotations: np.ndarray, translation: np.ndarray | None = None) -> np.ndarray:
    import torch

    from tryon.body.pose import bone_transforms

    with torch.no_grad():
        return bone_transforms(shape, rotations, translation).numpy()
