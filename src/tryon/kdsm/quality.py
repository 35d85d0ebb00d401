"""How a skinned volume holds up in a pose: inverted tets, volume ratios, and how much of
the arms' air runs into the torso's."""

from __future__ import annotations

import numpy as np

from tryon.kdsm.embed import find_parents
from tryon.kdsm.skinning import VolumeSkin
from tryon.kdsm.volume import TetVolume, tet_volumes


def pose_quality(volume: TetVolume, posed: np.ndarray, skin: VolumeSkin | None = None, shape=None,
                 region: np.ndarray | None = None) -> dict:
    """How the posed volume holds up: inverted tets (count and share) and the smallest
    volume ratio to the rest pose; with `skin` and `shape`, also how much of the arms' air
    has moved into the torso's (`arm_torso_overlap_pct`: arm tets whose centre lies in a
    torso tet, as a share of the arm tets)."""
    rest = volume.signed_volumes()
    now = tet_volumes(posed, volume.tets)
    ratio = now / rest
    out = {"tets": int(len(rest)), "inverted": int((now <= 0).sum()), "inverted_pct": float(100.0 * (now <= 0).mean()),
           "min_volume_ratio": float(ratio.min()), "median_volume_ratio": float(np.median(ratio))}
    if skin is not None and shape is not None:
        out.update(arm_torso_overlap(volume, posed, skin, shape, region))
    return out


def tet_regions(volume: TetVolume, skin: VolumeSkin, shape) -> np.ndarray:
    """Each tet's region [T]: 1 arm (its corners' weight mostly on a bone from the upper
    arm down), 2 torso (mostly on the spine, neck, clavicles or pelvis), 0 other."""
    parents, labels = shape.bone_parents, shape.bone_labels

    def under(j: int, roots: set[int]) -> bool:
        while j >= 0:
            if j in roots:
                return True
            j = parents[j]
        return False

    arm_roots = {labels.index(b) for b in ("upperarm01.L", "upperarm01.R") if b in labels}
    limbs = arm_roots | {j for j, name in enumerate(labels) if name.startswith(("upperleg", "neck", "head"))}
    arm = np.array([under(j, arm_roots) for j in range(len(labels))])
    torso = np.array([not under(j, limbs) for j in range(len(labels))])
    dense = np.zeros((len(volume.vertices), len(labels)))
    np.add.at(dense, (np.repeat(np.arange(len(skin.index)), skin.index.shape[1]), skin.index.ravel()), skin.weight.ravel())
    per_tet = dense[volume.tets].mean(1)
    share_arm, share_torso = per_tet[:, arm].sum(1), per_tet[:, torso].sum(1)
    return np.where(share_arm > 0.5, 1, np.where(share_torso > 0.5, 2, 0))


def arm_torso_overlap(volume: TetVolume, posed: np.ndarray, skin: VolumeSkin, shape,
                      region: np.ndarray | None = None) -> dict:
    """Arm tets whose centre lies inside a torso tet in the posed volume (they overlap
    there: a cloth vertex in that air has parents of both)."""
    region = tet_regions(volume, skin, shape) if region is None else region   # pose-independent: pass it over many poses
    arm, torso = np.flatnonzero(region == 1), np.flatnonzero(region == 2)
    if not len(arm) or not len(torso):
        return {"arm_tets": int(len(arm)), "arm_torso_overlap": 0, "arm_torso_overlap_pct": 0.0}
    centres = posed[volume.tets[arm]].mean(1)
    inside = np.unique(find_parents(centres, posed, volume.tets[torso], tol=0.0).point)
    return {"arm_tets": int(len(arm)), "arm_torso_overlap": int(len(inside)),
            "arm_torso_overlap_pct": float(100.0 * len(inside) / len(arm))}
