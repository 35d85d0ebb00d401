"""Isotropic plane-stress St. Venant-Kirchhoff fabric with a constant bending stiffness.

Membrane energy density (per unit rest area) for the Green strain G:

    W(G) = mu G:G + lam/2 tr(G)^2,
    lam = E h nu / (1 - nu^2),  mu = E h / (2 (1 + nu))      (plane stress, E h in N/m)

Written with ARCSim's k-coefficients, E_f = A_f/2 (k0 Guu^2 + 2 k1 Guu Gvv + k2 Gvv^2
+ 2 k3 Guv^2) with k0 = k2 = lam + 2 mu, k1 = lam, k3 = 2 mu.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from tryon.errors import FabricError
from tryon.fabric.base import Fabric, as_float64, check_bending_args, check_strain

N_PARAMETERS = 4


def _validate(
    density: torch.Tensor, membrane: torch.Tensor, nu: torch.Tensor, bending: torch.Tensor, name: str
) -> None:
    """Physical ranges: density > 0, E h > 0, 0 <= nu < 0.5, bending >= 0, all finite."""
    values = {
        "density_kg_m2": float(density.detach()),
        "youngs_modulus_pa * thickness_m": float(membrane.detach()),
        "poisson_ratio": float(nu.detach()),
        "bending_stiffness_nm": float(bending.detach()),
    }
    for key, value in values.items():
        if not math.isfinite(value):
            raise FabricError(f"isotropic fabric {name!r}: {key} must be finite, got {value}")
    if values["density_kg_m2"] <= 0.0:
        raise FabricError(f"isotropic fabric {name!r}: density_kg_m2 must be > 0, got {values['density_kg_m2']}")
    if values["youngs_modulus_pa * thickness_m"] <= 0.0:
        raise FabricError(f"isotropic fabric {name!r}: youngs_modulus_pa and thickness_m must be > 0")
    if not 0.0 <= values["poisson_ratio"] < 0.5:
        raise FabricError(
            f"isotropic fabric {name!r}: poisson_ratio must be in [0, 0.5), got {values['poisson_ratio']}"
        )
    if values["bending_stiffness_nm"] < 0.0:
        raise FabricError(
            f"isotropic fabric {name!r}: bending_stiffness_nm must be >= 0, got {values['bending_stiffness_nm']}"
        )


class IsotropicFabric(Fabric):
    """Isotropic StVK membrane (plane stress) + constant bending stiffness.

    Parameter vector: ``[density (kg/m^2), E*h (N/m), poisson_ratio, bending_stiffness (N*m)]``;
    the thickness is kept fixed by `with_parameters` (only E*h enters the membrane model).
    """

    kind = "isotropic"

    def __init__(
        self,
        youngs_modulus_pa: Any,
        poisson_ratio: Any,
        thickness_m: Any,
        bending_stiffness_nm: Any,
        density_kg_m2: Any,
        name: str = "isotropic",
        composition: str = "",
    ) -> None:
        youngs = as_float64(youngs_modulus_pa, "youngs_modulus_pa").reshape(())
        thickness = float(as_float64(thickness_m, "thickness_m").detach().reshape(()))
        if not math.isfinite(thickness) or thickness <= 0.0:
            raise FabricError(f"isotropic fabric {name!r}: thickness_m must be finite and > 0, got {thickness}")
        youngs_value = float(youngs.detach())
        if not math.isfinite(youngs_value) or youngs_value <= 0.0:
            raise FabricError(
                f"isotropic fabric {name!r}: youngs_modulus_pa must be finite and > 0, got {youngs_value}"
            )
        self._set(
            density=as_float64(density_kg_m2, "density_kg_m2").reshape(()),
            membrane=youngs * thickness,
            nu=as_float64(poisson_ratio, "poisson_ratio").reshape(()),
            bending=as_float64(bending_stiffness_nm, "bending_stiffness_nm").reshape(()),
            thickness=thickness,
            name=name,
            composition=composition,
        )

    def _set(self, density, membrane, nu, bending, thickness: float, name: str, composition: str) -> None:
        _validate(density, membrane, nu, bending, name)
        self._density, self._membrane, self._nu, self._bending = density, membrane, nu, bending
        self.thickness_m = thickness
        self.name = name
        self.composition = composition

    # -- data

    @property
    def density(self) -> torch.Tensor:
        return self._density

    @property
    def youngs_modulus_pa(self) -> torch.Tensor:
        return self._membrane / self.thickness_m

    @property
    def poisson_ratio(self) -> torch.Tensor:
        return self._nu

    @property
    def bending_stiffness_nm(self) -> torch.Tensor:
        return self._bending

    def lame(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Plane-stress Lame parameters (lam, mu) in N/m."""
        nu = self._nu
        return self._membrane * nu / (1.0 - nu * nu), self._membrane / (2.0 * (1.0 + nu))

    def parameters(self) -> torch.Tensor:
        return torch.stack([self._density, self._membrane, self._nu, self._bending])

    def with_parameters(self, p: torch.Tensor) -> "IsotropicFabric":
        p = as_float64(p, f"parameters of fabric {self.name!r}")
        if tuple(p.shape) != (N_PARAMETERS,):
            raise FabricError(
                f"an isotropic fabric takes {N_PARAMETERS} parameters [density, E*h, poisson_ratio, bending], "
                f"got shape {tuple(p.shape)}"
            )
        fabric = IsotropicFabric.__new__(IsotropicFabric)
        fabric._set(p[0], p[1], p[2], p[3], self.thickness_m, self.name, self.composition)
        return fabric

    # -- stiffness

    def stretching_stiffness(self, G: torch.Tensor) -> torch.Tensor:
        """Constant k = (lam + 2 mu, lam, lam + 2 mu, 2 mu) broadcast to ``G.shape[:-1]``."""
        G = check_strain(G)
        lam, mu = self.lame()
        k = torch.stack([lam + 2.0 * mu, lam, lam + 2.0 * mu, 2.0 * mu]).to(G.device)
        return k.expand(*G.shape[:-1], 4).clone()

    def bending_stiffness(self, alpha: torch.Tensor, edge_dir_uv: torch.Tensor) -> torch.Tensor:
        """Constant ke = bending_stiffness_nm for every edge."""
        alpha, _ = check_bending_args(alpha, edge_dir_uv)
        return self._bending.to(alpha.device).expand(alpha.shape).clone()

    def summary(self) -> dict:
        info = self._summary_common()
        info.update(
            {
                "youngs_modulus_pa": float(self.youngs_modulus_pa.detach()),
                "poisson_ratio": float(self._nu.detach()),
                "thickness_m": float(self.thickness_m),
            }
        )
        return info

    def to_dict(self) -> dict:
        """The ``{"type": "isotropic", ...}`` layout read by `tryon.fabric.load_fabric`."""
        return {
            "type": "isotropic",
            "name": self.name,
            "composition": self.composition,
            "youngs_modulus_pa": float(self.youngs_modulus_pa.detach()),
            "poisson_ratio": float(self._nu.detach()),
            "thickness_m": float(self.thickness_m),
            "bending_stiffness_nm": float(self._bending.detach()),
            "density_kg_m2": float(self._density.detach()),
        }

    @classmethod
    def from_dict(cls, data: dict, source: str = "isotropic fabric") -> "IsotropicFabric":
        """Inverse of `to_dict`; unknown or missing keys raise `FabricError`."""
        required = ("youngs_modulus_pa", "poisson_ratio", "thickness_m", "bending_stiffness_nm", "density_kg_m2")
        allowed = set(required) | {"type", "name", "composition"}
        unknown = sorted(set(data) - allowed)
        missing = [key for key in required if key not in data]
        if unknown or missing:
            raise FabricError(
                f"{source}: isotropic fabric needs {', '.join(required)} (optional name, composition); "
                f"missing {missing or 'nothing'}, unknown {unknown or 'nothing'}"
            )
        for key in required:
            value = data[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise FabricError(f"{source}: {key} must be a number, got {value!r}")
        return cls(
            data["youngs_modulus_pa"],
            data["poisson_ratio"],
            data["thickness_m"],
            data["bending_stiffness_nm"],
            data["density_kg_m2"],
            name=str(data.get("name", "isotropic")),
            composition=str(data.get("composition", "")),
        )


__all__ = ["IsotropicFabric"]
