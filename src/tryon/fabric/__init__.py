"""Fabric models for the cloth simulator.

* `WangFabric`: the measured data-driven fabrics of Wang, O'Brien, Ramamoorthi 2011,
  evaluated exactly as ARCSim 0.3.1 applies them (stretching table, bending lookup,
  load-time multipliers).
* `IsotropicFabric`: plane-stress St. Venant-Kirchhoff membrane + constant bending.

Presets: `list_presets`, `load_fabric`, `save_fabric`, `preset_summaries`,
`mean_preset_fabric`. Data licence and citation: ``data/wang2011/NOTICE.txt``.
"""

from tryon.fabric.base import Fabric
from tryon.fabric.isotropic import IsotropicFabric
from tryon.fabric.presets import list_presets, load_fabric, mean_preset_fabric, preset_summaries, save_fabric
from tryon.fabric.wang2011 import MEASURED_FABRICS, WangFabric

__all__ = [
    "Fabric",
    "WangFabric",
    "IsotropicFabric",
    "MEASURED_FABRICS",
    "list_presets",
    "load_fabric",
    "save_fabric",
    "preset_summaries",
    "mean_preset_fabric",
]
