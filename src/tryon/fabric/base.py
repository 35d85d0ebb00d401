"""The `Fabric` interface the cloth simulator talks to.

A fabric supplies three things to the simulator, all in SI units and float64:

* an areal density (kg/m^2), used to lump mass to the vertices;
* membrane stiffnesses ``k = (k0, k1, k2, k3)`` (N/m) for a Green strain ``G`` in the
  material (u, v) frame, plugged into ARCSim's per-face energy (Narain et al. 2012,
  ``physics.cpp``)::

      E_f = A_f * 0.5 * (k0*Guu^2 + 2*k1*Guu*Gvv + k2*Gvv^2 + 2*k3*Guv^2)

* a bending stiffness ``ke`` (N*m) per hinge edge, used in ARCSim's dihedral-angle
  bending energy ``E_e = ke * l^2 * (theta - theta_rest)^2 / (8 (A0 + A1))``.

Every fabric is also a flat vector of physical parameters (`parameters` /
`with_parameters`) so that fabric estimation can differentiate through the simulator.
"""

from __future__ import annotations

import abc
import math
from typing import Any

import torch

from tryon.errors import FabricError

DTYPE = torch.float64

# Strain of Wang 2011's second sample: principal stretch lambda = 1 + 1/6.
SATURATED_STRETCH = 1.0 + 1.0 / 6.0


def as_float64(value: Any, what: str) -> torch.Tensor:
    """Convert ``value`` to a float64 tensor, keeping autograd links of float64 tensors."""
    try:
        tensor = torch.as_tensor(value, dtype=DTYPE)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise FabricError(f"{what}: expected numbers, got {value!r} ({exc}); give plain numbers in SI units") from exc
    return tensor


def check_finite(tensor: torch.Tensor, what: str) -> None:
    """Raise `FabricError` unless every entry of ``tensor`` is finite."""
    if not bool(torch.isfinite(tensor.detach()).all()):
        raise FabricError(f"{what} contains NaN or infinity: {tensor.detach().tolist()}; give finite values")


def check_positive_scalar(value: Any, what: str, allow_zero: bool = False) -> float:
    """Validate a finite (strictly) positive multiplier / scalar and return it as float."""
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise FabricError(f"{what} must be a number, got {value!r}") from exc
    bad = number < 0.0 if allow_zero else number <= 0.0
    if not math.isfinite(number) or bad:
        bound = ">= 0" if allow_zero else "> 0"
        raise FabricError(f"{what} must be finite and {bound}, got {value!r}")
    return number


def check_strain(G: torch.Tensor) -> torch.Tensor:
    """Validate the ``[..., 3]`` Green-strain argument of `Fabric.stretching_stiffness`."""
    if not isinstance(G, torch.Tensor) or G.ndim < 1 or G.shape[-1] != 3:
        shape = tuple(G.shape) if isinstance(G, torch.Tensor) else type(G).__name__
        raise FabricError(
            f"stretching_stiffness expects a tensor [..., 3] of (G_uu, G_vv, G_uv), got {shape}; "
            "pass the Green strain components in the material frame"
        )
    return G.detach().to(DTYPE)


def check_bending_args(alpha: torch.Tensor, edge_dir_uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Validate the ``alpha [E]`` / ``edge_dir_uv [E, 2]`` arguments of `Fabric.bending_stiffness`."""
    if not isinstance(alpha, torch.Tensor) or not isinstance(edge_dir_uv, torch.Tensor):
        raise FabricError("bending_stiffness expects torch tensors alpha [E] and edge_dir_uv [E, 2]")
    if edge_dir_uv.shape[-1:] != (2,) or edge_dir_uv.shape[:-1] != alpha.shape:
        raise FabricError(
            f"bending_stiffness: alpha has shape {tuple(alpha.shape)} and edge_dir_uv {tuple(edge_dir_uv.shape)}; "
            "expected alpha [E] and edge_dir_uv [E, 2] (material-space edge vector u1 - u0)"
        )
    return alpha.detach().to(DTYPE), edge_dir_uv.detach().to(DTYPE)


class Fabric(abc.ABC):
    """A cloth material: density, membrane stiffness and bending stiffness (SI units).

    Stiffness outputs depend on strain / curvature, but like ARCSim they are meant to be
    held constant when the energy is differentiated with respect to positions: the
    strain and curvature arguments are detached, and gradients flow only to the fabric
    parameters.
    """

    kind: str = "abstract"
    name: str
    composition: str

    @property
    @abc.abstractmethod
    def density(self) -> torch.Tensor:
        """Areal density (kg/m^2), a 0-dim float64 tensor, multipliers included."""

    @abc.abstractmethod
    def stretching_stiffness(self, G: torch.Tensor) -> torch.Tensor:
        """Membrane stiffnesses ``[..., 4] = (k0, k1, k2, k3)`` (N/m) for Green strains ``G [..., 3]``."""

    @abc.abstractmethod
    def bending_stiffness(self, alpha: torch.Tensor, edge_dir_uv: torch.Tensor) -> torch.Tensor:
        """Bending stiffness ``ke [E]`` (N*m) for signed half curvatures ``alpha [E]`` (1/m)."""

    def stretching_stiffness_in_strain(self, G: torch.Tensor) -> torch.Tensor:
        """`stretching_stiffness` differentiable in the strain G as well (for the gradient of
        a simulated step: `tryon.diff`). Models whose stiffness does not depend on strain
        need not override it."""
        return self.stretching_stiffness(G)

    def bending_stiffness_in_curvature(self, alpha: torch.Tensor, edge_dir_uv: torch.Tensor) -> torch.Tensor:
        """`bending_stiffness` differentiable in the curvature alpha as well (`tryon.diff`)."""
        return self.bending_stiffness(alpha, edge_dir_uv)

    @abc.abstractmethod
    def parameters(self) -> torch.Tensor:
        """All physical parameters as one flat float64 vector."""

    @abc.abstractmethod
    def with_parameters(self, p: torch.Tensor) -> "Fabric":
        """A fabric of the same kind whose values come from ``p`` (keeps autograd links)."""

    @abc.abstractmethod
    def summary(self) -> dict:
        """JSON-serialisable description (name, kind, composition, density, stiffnesses)."""

    def to(self, device: torch.device | str) -> "Fabric":
        """The same fabric with its parameters on ``device``."""
        return self.with_parameters(self.parameters().to(device))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, density={float(self.density.detach()):.4g} kg/m^2)"

    def _probe_stretching(self, G: torch.Tensor) -> torch.Tensor:
        """Stiffnesses reported by `summary` (subclasses may report their exact model)."""
        return self.stretching_stiffness(G)

    def _summary_common(self) -> dict:
        """Fields shared by every fabric's `summary`, with stiffnesses probed through the public API."""
        device = self.parameters().device
        with torch.no_grad():
            lam2 = SATURATED_STRETCH**2 - 1.0
            probes = torch.tensor(
                [
                    [0.0, 0.0, 0.0],  # rest
                    [lam2 / 2, 0.0, 0.0],  # 16.7% stretch along u
                    [0.0, lam2 / 2, 0.0],  # 16.7% stretch along v
                    [lam2 / 4, lam2 / 4, lam2 / 4],  # 16.7% stretch along the 45 degree bias
                ],
                dtype=DTYPE,
                device=device,
            )
            k = self._probe_stretching(probes).cpu()
            dirs = torch.tensor([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], dtype=DTYPE, device=device)
            ke = self.bending_stiffness(torch.zeros(3, dtype=DTYPE, device=device), dirs).cpu()
        return {
            "name": self.name,
            "kind": self.kind,
            "composition": self.composition,
            "density_kg_m2": float(self.density.detach()),
            "stretch_N_m": {
                "warp_u": float(k[0, 0]),
                "weft_v": float(k[0, 2]),
                "shear": float(k[0, 3]),
                "coupling": float(k[0, 1]),
            },
            "stretch_N_m_at_16pct": {
                "warp_u": float(k[1, 0]),
                "weft_v": float(k[2, 2]),
                "shear": float(k[3, 3]),
            },
            "bending_N_m": {
                "edge_along_u": float(ke[0]),
                "edge_diagonal": float(ke[1]),
                "edge_along_v": float(ke[2]),
            },
        }
