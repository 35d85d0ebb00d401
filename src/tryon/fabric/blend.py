"""Fabrics between the measured presets, and the few numbers a learned model sees of a fabric.

`blend_fabrics` mixes two Wang 2011 fabrics parameter by parameter (density, the 6x4
stretching samples and the 3x5 bending samples): a fabric between two measured ones that
the learned draping models can be trained on so that they interpolate between presets.

`fabric_features` summarises any fabric in `FEATURE_NAMES` order: the stiffnesses a
drape depends on most, on a log scale because the presets span three decades.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from tryon.errors import FabricError
from tryon.fabric.base import Fabric
from tryon.fabric.wang2011 import WangFabric

FEATURE_NAMES = ("log10_stretch_N_m", "log10_shear_N_m", "log10_bending_N_m", "density_kg_m2")


def blend_fabrics(a: WangFabric, b: WangFabric, t: float) -> WangFabric:
    """The fabric (1 - t) a + t b, parameter by parameter (t in [0, 1])."""
    if not isinstance(a, WangFabric) or not isinstance(b, WangFabric):
        raise FabricError("only Wang 2011 fabrics (the measured presets) can be blended")
    if not (math.isfinite(t) and 0.0 <= t <= 1.0):
        raise FabricError(f"blend weight {t!r} is outside 0-1")
    p = (1.0 - t) * a.parameters() + t * b.parameters()
    mixed = a.with_parameters(p)
    mixed.name = f"{a.name}+{b.name}@{t:.3f}"
    mixed.composition = f"{1 - t:.0%} {a.name}, {t:.0%} {b.name} (blended parameters)"
    mixed.multipliers = {}
    return mixed


def scaled_stiffness(fabric: WangFabric, stretching_mult: float, bending_mult: float, name: str | None = None) -> WangFabric:
    """`fabric` with its stretching data times `stretching_mult` and its bending data times
    `bending_mult`; density, anisotropy and non-linearity kept (the log10 stiffness features
    move by the logs of the factors)."""
    if not isinstance(fabric, WangFabric):
        raise FabricError("only Wang 2011 fabrics (the measured presets) can be scaled")
    if not (math.isfinite(stretching_mult) and math.isfinite(bending_mult) and stretching_mult > 0 and bending_mult > 0):
        raise FabricError(f"stiffness factors must be positive, got {stretching_mult!r} and {bending_mult!r}")
    p = fabric.parameters().detach().clone()
    p[1:25] *= stretching_mult
    p[25:] *= bending_mult
    out = fabric.with_parameters(p)
    out.name = name or f"{fabric.name} x{stretching_mult:.3g} stretching x{bending_mult:.3g} bending"
    out.composition, out.multipliers = f"{fabric.name} with scaled stiffness", {}
    return out


def fabric_features(fabric: Fabric) -> np.ndarray:
    """[4] float32 in `FEATURE_NAMES` order: log10 of the warp-weft geometric mean stretching
    stiffness and of the shear stiffness at 16 % strain (where the Wang samples saturate),
    log10 of the mean bending stiffness, and the areal density."""
    s = fabric.summary()
    stretch = s.get("stretch_N_m_at_16pct", s.get("stretch_N_m"))
    bend = s["bending_N_m"]
    if stretch is None or not bend:
        raise FabricError(f"fabric {fabric.name!r} reports no stiffness to summarise")
    warp_weft = math.sqrt(max(stretch["warp_u"], 1e-9) * max(stretch["weft_v"], 1e-9))
    bending = float(np.mean([max(v, 1e-12) for v in bend.values()]))
    with torch.no_grad():
        density = float(fabric.density)
    return np.array([math.log10(warp_weft), math.log10(max(stretch["shear"], 1e-9)), math.log10(bending), density],
                    np.float32)
