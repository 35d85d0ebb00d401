"""Pose-dependent cloth through a kinematically deforming skinned mesh (KDSM): a
tetrahedral volume of the air around the body, skinned with it; cloth embedded in it as
material-space points plus a learned pose-dependent displacement d(theta).

    from tryon.kdsm import build_volume, skin_volume, embed, reconstruct, SurfaceBinding
"""

from tryon.kdsm.embed import Embedded, Parents, embed, find_parents, locate_rest, reconstruct, smooth_offsets
from tryon.kdsm.offsets import SurfaceBinding
from tryon.kdsm.quality import pose_quality
from tryon.kdsm.skinning import VolumeSkin, skin_volume
from tryon.kdsm.volume import TetVolume, build_volume

__all__ = ["Embedded", "Parents", "embed", "find_parents", "locate_rest", "reconstruct", "smooth_offsets",
           "SurfaceBinding", "VolumeSkin", "pose_quality", "skin_volume", "TetVolume", "build_volume"]
