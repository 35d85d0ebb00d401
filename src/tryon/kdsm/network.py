"""The pixel-based network (Jin et al. 2020) that every method shares.

Input: the pose as the bones' transforms relative to the rest pose (3x4 each, flattened:
a 1x1xK vector). Output: one 128x128 image of three channels per pattern panel (front,
back, each sleeve), laid out in the panel's material coordinates: transposed
convolutions with batch norm and ReLU from 4x4 up. A garment vertex reads its panel's
image bilinearly at its material coordinates (`PanelAtlas`), so the loss is the L2 error
at the vertices and a prediction is one forward pass and one sampling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

RESOLUTION = 128
CHANNELS = (256, 128, 64, 32, 16)   # after 4x4, 8x8, 16x16, 32x32, 64x64


MARGIN = 0.04   # of each panel image left around the panel's material box


@dataclass
class PanelAtlas:
    """Where each garment vertex reads the images: its panel [n] and its position in that
    panel's image, in grid_sample's [-1, 1] coordinates [n,2]. `frame` [panels,3] is the
    material box each image spans (centre u, centre v, side in m), which carries the
    images to any triangulation of the same pattern (`on_garment`)."""

    panel: np.ndarray
    coords: np.ndarray
    panels: int
    frame: np.ndarray | None = None

    @staticmethod
    def panel_frames(corner_uv: np.ndarray, face_panel: np.ndarray) -> np.ndarray:
        """Each panel's material bounding box as (centre u, centre v, longer side) [panels,3]."""
        frames = []
        for p in range(int(face_panel.max()) + 1):
            uv = corner_uv[face_panel == p].reshape(-1, 2)
            lo, hi = uv.min(0), uv.max(0)
            frames.append([*(0.5 * (lo + hi)), (hi - lo).max()])
        return np.asarray(frames)

    @classmethod
    def from_garment(cls, faces: np.ndarray, corner_uv: np.ndarray, face_panel: np.ndarray, margin: float = MARGIN,
                     frame: np.ndarray | None = None) -> "PanelAtlas":
        """One image per panel, the panel's material bounding box (or `frame`'s box) filling
        it less a margin; a vertex on a seam reads the panel of the first face that holds it."""
        faces, corner_uv, face_panel = np.asarray(faces), np.asarray(corner_uv, np.float64), np.asarray(face_panel)
        n = int(faces.max()) + 1
        panel = np.full(n, -1, np.int64)
        uv = np.zeros((n, 2))
        for k in range(3):
            for f in range(len(faces)):
                v = faces[f, k]
                if panel[v] < 0:
                    panel[v], uv[v] = face_panel[f], corner_uv[f, k]
        frame = cls.panel_frames(corner_uv, face_panel) if frame is None else np.asarray(frame, np.float64)
        coords = np.zeros((n, 2))
        for p in range(len(frame)):
            at = panel == p
            centred = (uv[at] - frame[p, :2]) / frame[p, 2]          # in [-0.5, 0.5], aspect kept
            coords[at] = 2.0 * (1.0 - margin) * centred
        return cls(panel, coords, len(frame), frame)

    def on_garment(self, faces: np.ndarray, corner_uv: np.ndarray, face_panel: np.ndarray, tol: float = 0.01) -> "PanelAtlas":
        """The same images read by another triangulation of the same pattern: its vertices
        placed in each panel's image by their material coordinates. Refuses a garment whose
        panels are not this pattern's (other count, or boxes more than `tol` m apart)."""
        from tryon.errors import TryonError

        if self.frame is None:
            raise TryonError("this model predates material-space transfer (no panel frames); retrain it with tryon train kdsm")
        theirs = self.panel_frames(np.asarray(corner_uv, np.float64), np.asarray(face_panel))
        if theirs.shape != self.frame.shape or np.abs(theirs - self.frame).max() > tol:
            raise TryonError(f"the garment's pattern ({len(theirs)} panels) is not the model's ({self.panels} panels, "
                             f"material boxes {np.round(self.frame, 3).tolist()} m): drape the model's garment and size")
        return self.from_garment(faces, corner_uv, face_panel, frame=self.frame)

    def sample(self, images: torch.Tensor) -> torch.Tensor:
        """Per-vertex values [B,n,3] from images [B, panels*3, H, W]."""
        B = images.shape[0]
        out = images.new_zeros((B, len(self.panel), 3))
        for p in range(self.panels):
            at = torch.from_numpy(np.flatnonzero(self.panel == p))
            grid = torch.as_tensor(self.coords[self.panel == p], dtype=images.dtype)[None, None].expand(B, 1, -1, 2)
            vals = nn.functional.grid_sample(images[:, 3 * p:3 * p + 3], grid, mode="bilinear", align_corners=False)
            out[:, at] = vals[:, :, 0].transpose(1, 2)
        return out


class PixelNet(nn.Module):
    """Pose vector [B,K] -> panel images [B, panels*3, 128, 128]."""

    def __init__(self, inputs: int, panels: int):
        super().__init__()
        self.fc = nn.Sequential(nn.Linear(inputs, CHANNELS[0] * 16), nn.ReLU())
        layers = []
        for a, b in zip(CHANNELS[:-1], CHANNELS[1:]):
            layers += [nn.ConvTranspose2d(a, b, 4, stride=2, padding=1), nn.BatchNorm2d(b), nn.ReLU()]
        layers += [nn.ConvTranspose2d(CHANNELS[-1], 3 * panels, 4, stride=2, padding=1)]
        self.up = nn.Sequential(*layers)

    def forward(self, pose: torch.Tensor) -> torch.Tensor:
        return self.up(self.fc(pose).view(-1, CHANNELS[0], 4, 4))
