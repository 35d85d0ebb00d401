"""Wang, O'Brien, Ramamoorthi 2011 measured fabrics, evaluated exactly as ARCSim 0.3.1 does.

Reference: H. Wang, J. O'Brien, R. Ramamoorthi, "Data-Driven Elastic Models for Cloth:
Modeling and Measurement", SIGGRAPH 2011; data and evaluation code from ARCSim 0.3.1
(Narain, Samii, O'Brien 2012), ``dde.cpp`` and ``conf.cpp``. The data layout and every
step below are described in ``/work/shared/fabrics/wang2011/FORMAT.md``.

Stretching (``dde.cpp: evaluate_stretching_sample``), for a Green strain G:

1. C = 2G + I; lambda_max = sqrt of its largest eigenvalue, theta = angle of the
   matching eigenvector (closed-form 2x2 eigen-decomposition, ARCSim's branches for
   G_uv = 0 included), folded to [0, 90] degrees.
2. s = clamp(6 (lambda_max - 1), 0, 1 - 1e-6); a = clamp(theta / 22.5 deg, 0, 4 - 1e-6),
   r = floor(a), t = a - r.
3. c = (1 - s) row0 + s [(1 - t) row(1 + r) + t row(2 + r)]; k = 2 max(c, 0).

ARCSim samples this on a 30^3 grid of (G_uu, G_vv, |G_uv|) once and interpolates the
grid trilinearly (clamped at the boundary) at run time; `WangFabric.stretching_stiffness`
reproduces that table and lookup, including ARCSim's single-precision ``atan2f`` /
``fabsf`` calls.

Bending (``dde.cpp: bending_stiffness``): 3 direction rows x 5 curvature columns, bilinear
in (beta, alpha / 5), clamped at >= 0, with ARCSim's linear extrapolation for negative
alpha (the truncating ``(int)`` cast keeps the first segment).

Load-time multipliers (``conf.cpp``): density *= density_mult * thicken, stretching
*= stretching_mult * thicken, bending *= bending_mult * thicken. The clamps above are
positively homogeneous (max(m c, 0) = m max(c, 0) for m > 0), so multiplying the raw
6x4 / 3x5 data by the multipliers is exactly ARCSim's scaling of the lookup tables; the
parameter vector of a `WangFabric` therefore holds the data with multipliers folded in.
"""

from __future__ import annotations

import functools
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numba import njit
from torch.autograd.function import once_differentiable

from tryon.errors import FabricError
from tryon.fabric.base import (
    DTYPE,
    Fabric,
    as_float64,
    check_bending_args,
    check_finite,
    check_positive_scalar,
    check_strain,
)

DATA_DIR = Path(__file__).resolve().parent / "data" / "wang2011"

DEMO_COMPOSITION = "ARCSim demo material, isotropic (not measured)"

# Garment and fibre content from ARCSim's materials/README (data/wang2011/ARCSIM_MATERIALS_README.txt).
WANG2011_FABRICS: dict[str, str] = {
    "ivory-rib-knit": "95% cotton / 5% spandex, underwear",
    "pink-ribbon-brown": "100% polyester, blanket",
    "white-dots-on-blk": "100% polyester, tablecloth",
    "navy-sparkle-sweat": "96% polyester / 4% spandex, sweater",
    "camel-ponte-roma": "60% polyester / 40% rayon, jacket",
    "gray-interlock": "60% cotton / 40% polyester, t-shirt",
    "11oz-black-denim": "99% cotton / 1% spandex, jeans",
    "white-swim-solid": "87% nylon / 13% spandex, swimsuit",
    "tango-red-jet-set": "100% polyester, jacket",
    "royal-target": "65% cotton / 35% polyester, pants",
    "paper": DEMO_COMPOSITION,
    "aluminium": DEMO_COMPOSITION,
}
MEASURED_FABRICS: tuple[str, ...] = tuple(name for name, comp in WANG2011_FABRICS.items() if comp != DEMO_COMPOSITION)

NSAMPLES = 30  # ARCSim's stretching grid size per axis
GRID_ORIGIN = -0.25  # smallest G_uu, G_vv on the grid
STRETCH_SHAPE = (6, 4)
BEND_SHAPE = (3, 5)
N_PARAMETERS = 1 + 6 * 4 + 3 * 5
MULTIPLIER_KEYS = ("density_mult", "stretching_mult", "bending_mult", "thicken")

_STRAIN_CLAMP = 1.0 - 1e-6
_ANGLE_CLAMP = 4.0 - 1e-6
_LOOKUP_CLAMP = NSAMPLES - 1 - 1e-5
# Flat-index offsets of the 8 trilinear corners, (i, j, k) in i-major order.
_CORNER_OFFSETS = [di * NSAMPLES * NSAMPLES + dj * NSAMPLES + dk for di in (0, 1) for dj in (0, 1) for dk in (0, 1)]


# ----------------------------------------------------------------------------- stretching formula


def _atan2f(y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """C ``atan2f``: both arguments rounded to float32, result in float32."""
    return torch.atan2(y.to(torch.float32), x.to(torch.float32))


def _principal_stretch_and_angle(G: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """lambda_max and ARCSim's angle weight theta / 22.5 deg for Green strains ``G [..., 3]``.

    Closed-form eigen-decomposition of the symmetric 2x2 C = 2G + I as ARCSim's
    ``eigen_decomposition<2>``: for C_uv != 0 the major eigenvector is
    (l1 - C_vv, C_uv) / norm; for C_uv = 0 it is (1, 0) if C_uu >= C_vv else (0, 1).
    The angle weight is ``fabsf(atan2f(V1, V0) / pi) * 8`` in single precision.

    When C_uu < C_vv and C_uv is tiny, l1 - C_vv cancels catastrophically (ARCSim then
    picks a near-random angle; its grid never has 0 < |G_uv| < 1/30, so the table is not
    affected). There we use the parallel vector sign(C_uv) (C_uv, l1 - C_uu), which is
    the same eigenvector with ARCSim's orientation (first component >= 0).
    """
    a = 1.0 + 2.0 * G[..., 0]
    d = 1.0 + 2.0 * G[..., 1]
    b = 2.0 * G[..., 2]
    amd, apd = a - d, a + d
    l1 = 0.5 * (apd + torch.sqrt(4.0 * b * b + amd * amd))
    offdiag = b != 0
    u_major = a >= d
    v0 = torch.where(u_major, l1 - d, b.abs())
    v1 = torch.where(u_major, b, torch.sign(b) * (l1 - a))
    norm = torch.where(offdiag, torch.sqrt(v0 * v0 + v1 * v1), torch.ones_like(b))
    v0 = torch.where(offdiag, v0 / norm, u_major.to(DTYPE))
    v1 = torch.where(offdiag, v1 / norm, (~u_major).to(DTYPE))
    angle = _atan2f(v1, v0)
    angle_weight = ((angle.to(DTYPE) / math.pi).to(torch.float32).abs() * 8).to(DTYPE)
    return torch.sqrt(l1.clamp(min=0.0)), angle_weight


def stretching_row_weights(G: torch.Tensor) -> torch.Tensor:
    """Weights ``W [..., 6]`` with c = W @ rows, the bilinear (strain, angle) blend of FORMAT.md step 4."""
    G = G.detach().to(DTYPE)
    stretch, angle_weight = _principal_stretch_and_angle(G)
    s = ((stretch - 1.0) * 6.0).clamp(0.0, _STRAIN_CLAMP)
    a = angle_weight.clamp(0.0, _ANGLE_CLAMP)
    r = a.floor()
    t = a - r
    r = r.to(torch.int64).clamp(0, 3)
    W = torch.zeros(*G.shape[:-1], 6, dtype=DTYPE, device=G.device)
    W[..., 0] = (1.0 - s) * (1.0 - t) + (1.0 - s) * t
    W.scatter_add_(-1, (1 + r).unsqueeze(-1), (s * (1.0 - t)).unsqueeze(-1))
    W.scatter_add_(-1, (2 + r).unsqueeze(-1), (s * t).unsqueeze(-1))
    return W


def evaluate_stretching_formula(G: torch.Tensor, stretching: torch.Tensor) -> torch.Tensor:
    """ARCSim's ``evaluate_stretching_sample``: k = 2 max(c, 0) for strains ``G [..., 3]``.

    ``stretching`` is the 6x4 data (multipliers folded in). Gradients flow to
    ``stretching`` only; G is treated as a constant.
    """
    return evaluate_from_weights(stretching_row_weights(G), stretching)


def evaluate_from_weights(W: torch.Tensor, stretching: torch.Tensor) -> torch.Tensor:
    """k = 2 max(W @ rows, 0)."""
    return 2.0 * (W @ stretching).clamp(min=0.0)


def grid_strains() -> torch.Tensor:
    """The strains ``[30, 30, 30, 3]`` G = (-0.25 + i/30, -0.25 + j/30, k/30) of ARCSim's table."""
    steps = torch.arange(NSAMPLES, dtype=DTYPE) / (NSAMPLES * 1.0)
    i, j, k = torch.meshgrid(steps, steps, steps, indexing="ij")
    return torch.stack([GRID_ORIGIN + i, GRID_ORIGIN + j, k], dim=-1)


@functools.lru_cache(maxsize=4)
def _grid_row_weights(device: str) -> torch.Tensor:
    """Row weights ``[30^3, 6]`` of the grid nodes (independent of the fabric, computed once)."""
    return stretching_row_weights(grid_strains().reshape(-1, 3)).to(device)


def build_stretching_table(stretching: torch.Tensor) -> torch.Tensor:
    """ARCSim's precomputed table ``[30, 30, 30, 4]`` (``evaluate_stretching_samples``), differentiable."""
    W = _grid_row_weights(str(stretching.device))
    return evaluate_from_weights(W, stretching).reshape(NSAMPLES, NSAMPLES, NSAMPLES, 4)


# ----------------------------------------------------------------------------- table lookup


def trilinear_corners(G: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Flat grid indices ``[N, 8]`` and weights ``[N, 8]`` of ARCSim's ``stretching_stiffness`` lookup.

    Coordinates a = (G_uu + 0.25) 30, b = (G_vv + 0.25) 30, c = fabsf(G_uv) 30 (single
    precision, as in ARCSim), each clamped to [0, 29 - 1e-5], so strains outside the
    grid take the boundary values.
    """
    G = G.reshape(-1, 3)
    a = (G[:, 0] + 0.25) * NSAMPLES
    b = (G[:, 1] + 0.25) * NSAMPLES
    c = (G[:, 2].to(torch.float32).abs() * NSAMPLES).to(DTYPE)
    coords = torch.stack([a, b, c], dim=1).clamp(0.0, _LOOKUP_CLAMP)
    base = coords.floor()
    frac = coords - base
    base = base.to(torch.int64).clamp(0, NSAMPLES - 2)
    flat = (base[:, 0] * NSAMPLES + base[:, 1]) * NSAMPLES + base[:, 2]
    offsets = torch.tensor(_CORNER_OFFSETS, dtype=torch.int64, device=G.device)
    idx = flat.unsqueeze(1) + offsets
    w01 = torch.stack([1.0 - frac, frac], dim=2)  # [N, 3 axes, 2]
    weights = w01[:, 0, :, None, None] * w01[:, 1, None, :, None] * w01[:, 2, None, None, :]
    return idx, weights.reshape(-1, 8)


def _interpolate(table_flat: torch.Tensor, idx: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    return (table_flat[idx] * weights.unsqueeze(-1)).sum(dim=1)


@njit(cache=True)
def _grid_cell(x: float, n: int) -> tuple[int, float]:
    """Clamp a grid coordinate to [0, n - 1 - 1e-5] and split it into cell index and fraction."""
    if x != x:  # NaN strain: any in-bounds cell, the NaN fraction propagates to k
        return 0, x
    x = min(max(x, 0.0), n - 1 - 1e-5)
    i = min(max(int(np.floor(x)), 0), n - 2)
    return i, x - i


@njit(cache=True)
def _corners(g: np.ndarray, n: int, nodes: np.ndarray, weights: np.ndarray) -> None:
    """The 8 grid nodes and trilinear weights of one strain, as ARCSim's ``stretching_stiffness``."""
    ai, a = _grid_cell((g[0] + 0.25) * n, n)
    bi, b = _grid_cell((g[1] + 0.25) * n, n)
    ci, c = _grid_cell(np.float64(np.float32(abs(np.float32(g[2]))) * np.float32(n)), n)
    corner = 0
    for di in range(2):
        wa = a if di else 1.0 - a
        for dj in range(2):
            wb = b if dj else 1.0 - b
            for dk in range(2):
                weights[corner] = wa * wb * (c if dk else 1.0 - c)
                nodes[corner] = ((ai + di) * n + bi + dj) * n + ci + dk
                corner += 1


@njit(cache=True)
def _lookup_kernel(G: np.ndarray, table: np.ndarray, out: np.ndarray) -> None:
    """k[f] = sum over the 8 corners of weight * table[node], in ARCSim's summation order."""
    nodes = np.empty(8, np.int64)
    weights = np.empty(8)
    for f in range(G.shape[0]):
        _corners(G[f], NSAMPLES, nodes, weights)
        for comp in range(4):
            total = 0.0
            for corner in range(8):
                total += table[nodes[corner], comp] * weights[corner]
            out[f, comp] = total


@njit(cache=True)
def _scatter_kernel(G: np.ndarray, grad_k: np.ndarray, node_grad: np.ndarray) -> None:
    """Adjoint of `_lookup_kernel`: node_grad[node] += weight * grad_k[f]."""
    nodes = np.empty(8, np.int64)
    weights = np.empty(8)
    for f in range(G.shape[0]):
        _corners(G[f], NSAMPLES, nodes, weights)
        for corner in range(8):
            for comp in range(4):
                node_grad[nodes[corner], comp] += weights[corner] * grad_k[f, comp]


def lookup_stretching_table(table_flat: torch.Tensor, G: torch.Tensor, compiled: bool | None = None) -> torch.Tensor:
    """Trilinear lookup ``[N, 4]`` of a flat ``[27000, 4]`` table at strains ``G [N, 3]`` (no autograd).

    ``compiled=None`` sends CPU tensors through the numba kernel and other devices through
    the vectorised torch gather (same result to rounding).
    """
    if (G.device.type == "cpu") if compiled is None else compiled:
        out = np.empty((G.shape[0], 4))
        _lookup_kernel(np.ascontiguousarray(G.numpy()), np.ascontiguousarray(table_flat.numpy()), out)
        return torch.from_numpy(out)
    idx, weights = trilinear_corners(G)
    return _interpolate(table_flat, idx, weights)


def scatter_to_table(
    G: torch.Tensor, grad_k: torch.Tensor, n_nodes: int, compiled: bool | None = None
) -> torch.Tensor:
    """Adjoint of `lookup_stretching_table`: d(sum grad_k * k) / d table, shape ``[n_nodes, 4]``."""
    if (G.device.type == "cpu") if compiled is None else compiled:
        node_grad = np.zeros((n_nodes, 4))
        _scatter_kernel(np.ascontiguousarray(G.numpy()), np.ascontiguousarray(grad_k.numpy()), node_grad)
        return torch.from_numpy(node_grad)
    idx, weights = trilinear_corners(G)
    contributions = (weights.unsqueeze(-1) * grad_k.unsqueeze(1)).reshape(-1, 4)
    node_grad = torch.zeros(n_nodes, 4, dtype=DTYPE, device=G.device)
    return node_grad.index_add_(0, idx.reshape(-1), contributions)


class _TableLookup(torch.autograd.Function):
    """Trilinear lookup of a cached (detached) table with the gradient routed to the 6x4 data.

    table = 2 max(W @ data, 0), so d table / d data = 2 [W @ data >= 0] W: the backward
    scatters the output gradient onto the grid nodes and maps it back through W^T.
    Keeping the table detached lets one Fabric serve any number of separate backward
    passes without rebuilding it.
    """

    @staticmethod
    def forward(ctx, stretching, table_flat, active, G):
        ctx.save_for_backward(active, G)
        return lookup_stretching_table(table_flat, G)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_k):
        active, G = ctx.saved_tensors
        node_grad = scatter_to_table(G, grad_k.to(DTYPE), active.shape[0])
        W = _grid_row_weights(str(grad_k.device))
        grad_data = W.transpose(0, 1) @ (2.0 * active.to(DTYPE) * node_grad)
        return grad_data, None, None, None


# ----------------------------------------------------------------------------- bending


def bending_lookup(alpha: torch.Tensor, edge_dir_uv: torch.Tensor, bending: torch.Tensor) -> torch.Tensor:
    """ARCSim's ``bending_stiffness`` (dde.cpp) for signed half curvatures ``alpha [E]`` (1/m).

    Column coordinate alpha / 5 capped at 4 (alpha > 20 1/m uses the last column); the
    truncating ``(int)`` cast keeps segment 0 for alpha < 0, giving the linear
    extrapolation b0 + (b0 - b1) |alpha| / 5. Row coordinate beta = |atan2f(d_v, d_u)| / 45
    deg folded into [0, 2]. Bilinear blend, clamped at >= 0. Gradients flow to ``bending``.
    """
    value = (alpha * 0.2).clamp(max=4.0)
    col = value.trunc().to(torch.int64).clamp(0, 3)
    value = value - col
    beta = (_atan2f(edge_dir_uv[..., 1], edge_dir_uv[..., 0]).to(DTYPE) * 4.0 / math.pi).abs()
    beta = torch.where(beta > 4.0, 8.0 - beta, beta)
    beta = torch.where(beta > 2.0, 4.0 - beta, beta)
    row = beta.trunc().to(torch.int64).clamp(0, 1)
    beta = beta - row
    flat = bending.reshape(-1)

    def at(dr: int, dc: int) -> torch.Tensor:
        return flat[(row + dr) * BEND_SHAPE[1] + col + dc]

    ke = (
        at(0, 0) * (1.0 - beta) * (1.0 - value)
        + at(1, 0) * beta * (1.0 - value)
        + at(0, 1) * (1.0 - beta) * value
        + at(1, 1) * beta * value
    )
    return ke.clamp(min=0.0)


# ----------------------------------------------------------------------------- files


def _strip_comments(text: str) -> str:
    """Remove ``//`` and ``/* */`` comments outside strings (jsoncpp accepts them, json does not)."""
    out: list[str] = []
    i, n = 0, len(text)
    in_string = False
    while i < n:
        ch = text[i]
        if in_string:
            out.append(ch)
            if ch == "\\" and i + 1 < n:
                out.append(text[i + 1])
                i += 1
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
            out.append(ch)
        elif text.startswith("//", i):
            end = text.find("\n", i)
            i = n if end < 0 else end
            continue
        elif text.startswith("/*", i):
            end = text.find("*/", i + 2)
            i = n if end < 0 else end + 2
            continue
        else:
            out.append(ch)
        i += 1
    return "".join(out)


def read_json_with_comments(path: str | os.PathLike) -> Any:
    """Parse a JSON file that may contain ``//`` / ``/* */`` comments (ARCSim's paper.json, aluminium.json)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise FabricError(f"cannot read fabric file {path}: {exc.strerror or exc}; check the path") from exc
    try:
        return json.loads(_strip_comments(text))
    except json.JSONDecodeError as exc:
        raise FabricError(
            f"fabric file {path} is not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg}); "
            "expected ARCSim's layout {\"density\": .., \"stretching\": [6 x 4], \"bending\": [3 x 5]}"
        ) from exc


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FabricError(f"{what} must be a number, got {value!r}")
    return float(value)


def _matrix(value: Any, shape: tuple[int, int], what: str) -> list[list[float]]:
    """Validate a nested list of numbers with the given shape."""
    rows, cols = shape
    if not isinstance(value, (list, tuple)) or len(value) != rows:
        raise FabricError(f"{what} must be a list of {rows} rows of {cols} numbers, got {value!r}")
    result = []
    for r, row in enumerate(value):
        if not isinstance(row, (list, tuple)) or len(row) != cols:
            raise FabricError(f"{what} row {r} must hold {cols} numbers, got {row!r}")
        result.append([_number(x, f"{what}[{r}]") for x in row])
    return result


def parse_arcsim_material(data: Any, source: str) -> tuple[float, list[list[float]], list[list[float]]]:
    """Validate ARCSim's material layout and return (density, stretching 6x4, bending 3x5)."""
    if not isinstance(data, dict):
        raise FabricError(
            f"{source}: expected a JSON object with density/stretching/bending, got {type(data).__name__}"
        )
    missing = [key for key in ("density", "stretching", "bending") if key not in data]
    if missing:
        raise FabricError(f"{source}: missing {', '.join(missing)}; ARCSim materials need density, stretching, bending")
    density = _number(data["density"], f"{source}: density")
    stretching = _matrix(data["stretching"], STRETCH_SHAPE, f"{source}: stretching")
    bending = _matrix(data["bending"], BEND_SHAPE, f"{source}: bending")
    return density, stretching, bending


def preset_path(name: str) -> Path:
    """Path of a preset's ARCSim JSON file; unknown names raise `FabricError` listing the valid ones."""
    if name not in WANG2011_FABRICS:
        raise FabricError(f"unknown fabric preset {name!r}; valid presets: {', '.join(WANG2011_FABRICS)}")
    return DATA_DIR / f"{name}.json"


# ----------------------------------------------------------------------------- the fabric


class WangFabric(Fabric):
    """A Wang 2011 data-driven fabric (6x4 stretching, 3x5 bending samples) evaluated as ARCSim does.

    Parameter vector layout (40 numbers, multipliers folded in, see module docstring)::

        [density (1), stretching 6x4 row-major (24), bending 3x5 row-major (15)]
    """

    kind = "wang2011"

    def __init__(
        self,
        density: Any,
        stretching: Any,
        bending: Any,
        name: str = "wang2011-custom",
        composition: str = "",
        multipliers: dict[str, float] | None = None,
    ) -> None:
        self.name = name
        self.composition = composition
        self.multipliers = dict(multipliers or {})
        self._density = as_float64(density, f"fabric {name!r} density").reshape(())
        self._stretching = as_float64(stretching, f"fabric {name!r} stretching")
        self._bending = as_float64(bending, f"fabric {name!r} bending")
        self._validate()
        self._table_cache: tuple | None = None

    def _validate(self) -> None:
        for tensor, shape, what in (
            (self._stretching, STRETCH_SHAPE, "stretching"),
            (self._bending, BEND_SHAPE, "bending"),
        ):
            if tuple(tensor.shape) != shape:
                raise FabricError(f"fabric {self.name!r}: {what} must have shape {shape}, got {tuple(tensor.shape)}")
            check_finite(tensor, f"fabric {self.name!r} {what}")
        check_finite(self._density, f"fabric {self.name!r} density")
        density = float(self._density.detach())
        if density <= 0.0:
            raise FabricError(f"fabric {self.name!r}: density must be > 0 kg/m^2, got {density}")

    # -- construction

    @classmethod
    def from_arcsim_dict(
        cls,
        data: Any,
        name: str,
        composition: str = "",
        density_mult: float = 1.0,
        stretching_mult: float = 1.0,
        bending_mult: float = 1.0,
        thicken: float = 1.0,
        source: str | None = None,
    ) -> "WangFabric":
        """Build from ARCSim's ``{"density", "stretching", "bending"}`` layout, applying ``conf.cpp``'s multipliers."""
        density, stretching, bending = parse_arcsim_material(data, source or f"fabric {name!r}")
        mult = {
            "density_mult": check_positive_scalar(density_mult, "density_mult"),
            "stretching_mult": check_positive_scalar(stretching_mult, "stretching_mult"),
            "bending_mult": check_positive_scalar(bending_mult, "bending_mult"),
            "thicken": check_positive_scalar(thicken, "thicken"),
        }
        th = mult["thicken"]
        return cls(
            torch.tensor(density, dtype=DTYPE) * (mult["density_mult"] * th),
            torch.tensor(stretching, dtype=DTYPE) * (mult["stretching_mult"] * th),
            torch.tensor(bending, dtype=DTYPE) * (mult["bending_mult"] * th),
            name=name,
            composition=composition,
            multipliers=mult,
        )

    @classmethod
    def from_preset(
        cls,
        name: str,
        density_mult: float = 1.0,
        stretching_mult: float = 1.0,
        bending_mult: float = 1.0,
        thicken: float = 1.0,
    ) -> "WangFabric":
        """One of the 12 ARCSim materials by name (see `tryon.fabric.list_presets`)."""
        path = preset_path(name)
        return cls.from_arcsim_dict(
            read_json_with_comments(path),
            name=name,
            composition=WANG2011_FABRICS[name],
            density_mult=density_mult,
            stretching_mult=stretching_mult,
            bending_mult=bending_mult,
            thicken=thicken,
            source=str(path),
        )

    @classmethod
    def from_file(
        cls,
        path: str | os.PathLike,
        density_mult: float = 1.0,
        stretching_mult: float = 1.0,
        bending_mult: float = 1.0,
        thicken: float = 1.0,
    ) -> "WangFabric":
        """An ARCSim material JSON file (``//`` comments allowed); the name defaults to the file stem."""
        path = Path(path)
        data = read_json_with_comments(path)
        name = data.get("name", path.stem) if isinstance(data, dict) else path.stem
        default_comp = WANG2011_FABRICS.get(str(name), "")
        composition = data.get("composition", default_comp) if isinstance(data, dict) else ""
        return cls.from_arcsim_dict(
            data,
            name=str(name),
            composition=str(composition),
            density_mult=density_mult,
            stretching_mult=stretching_mult,
            bending_mult=bending_mult,
            thicken=thicken,
            source=str(path),
        )

    # -- data

    @property
    def density(self) -> torch.Tensor:
        return self._density

    @property
    def stretching_data(self) -> torch.Tensor:
        """The 6x4 stretching samples (N/m, before ARCSim's x2, multipliers included)."""
        return self._stretching

    @property
    def bending_data(self) -> torch.Tensor:
        """The 3x5 bending samples (N*m, multipliers included)."""
        return self._bending

    def parameters(self) -> torch.Tensor:
        return torch.cat([self._density.reshape(1), self._stretching.reshape(-1), self._bending.reshape(-1)])

    def with_parameters(self, p: torch.Tensor) -> "WangFabric":
        p = as_float64(p, f"parameters of fabric {self.name!r}")
        if tuple(p.shape) != (N_PARAMETERS,):
            raise FabricError(
                f"a Wang 2011 fabric takes {N_PARAMETERS} parameters "
                f"[density, stretching 6x4, bending 3x5], got shape {tuple(p.shape)}"
            )
        return WangFabric(
            p[0],
            p[1:25].reshape(STRETCH_SHAPE),
            p[25:].reshape(BEND_SHAPE),
            name=self.name,
            composition=self.composition,
            multipliers=self.multipliers,
        )

    # -- stiffness

    def stretching_table(self) -> torch.Tensor:
        """ARCSim's 30x30x30x4 table of k (N/m), built afresh with autograd links to the data."""
        return build_stretching_table(self._stretching)

    def _cached_table(self, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        """Detached flat table ``[27000, 4]`` and its active (unclamped) mask, rebuilt if the data changed."""
        key = (self._stretching._version, str(device))
        if self._table_cache is None or self._table_cache[0] != key:
            with torch.no_grad():
                W = _grid_row_weights(str(device))
                c = W @ self._stretching.detach().to(device)
                self._table_cache = (key, 2.0 * c.clamp(min=0.0), c >= 0.0)
        return self._table_cache[1], self._table_cache[2]

    def stretching_stiffness(self, G: torch.Tensor) -> torch.Tensor:
        """k ``[..., 4]`` (N/m): trilinear lookup of ARCSim's 30^3 table, x2 and multipliers included.

        G is treated as a constant (ARCSim holds k fixed when differentiating the energy);
        gradients flow to the fabric parameters.
        """
        G = check_strain(G)
        table, active = self._cached_table(G.device)
        flat_G = G.reshape(-1, 3)
        if torch.is_grad_enabled() and self._stretching.requires_grad:
            k = _TableLookup.apply(self._stretching.to(G.device), table, active, flat_G)
        else:
            k = lookup_stretching_table(table, flat_G)
        return k.reshape(*G.shape[:-1], 4)

    def stretching_stiffness_exact(self, G: torch.Tensor) -> torch.Tensor:
        """The formula ARCSim samples into its table, evaluated directly at ``G [..., 3]``."""
        G = check_strain(G)
        return evaluate_stretching_formula(G, self._stretching.to(G.device))

    def bending_stiffness(self, alpha: torch.Tensor, edge_dir_uv: torch.Tensor) -> torch.Tensor:
        """ke ``[E]`` (N*m), ARCSim's lookup including the signed-alpha extrapolation quirk."""
        alpha, edge_dir_uv = check_bending_args(alpha, edge_dir_uv)
        return bending_lookup(alpha, edge_dir_uv, self._bending.to(alpha.device))

    def stretching_stiffness_in_strain(self, G: torch.Tensor) -> torch.Tensor:
        """ARCSim's table lookup differentiable in G and the data: the 8 table nodes around
        each strain evaluated from the data and interpolated trilinearly (the full table
        and its backward would cost 27000 rows per step)."""
        W = _grid_row_weights(str(self._stretching.device))
        idx, weights = trilinear_corners(G)
        nodes = 2.0 * (W[idx] @ self._stretching).clamp(min=0.0)  # [F, 8, 4]
        return (nodes * weights[..., None]).sum(1)

    def bending_stiffness_in_curvature(self, alpha: torch.Tensor, edge_dir_uv: torch.Tensor) -> torch.Tensor:
        return bending_lookup(alpha, edge_dir_uv, self._bending)

    def _probe_stretching(self, G: torch.Tensor) -> torch.Tensor:
        return self.stretching_stiffness_exact(G)

    def summary(self) -> dict:
        """Name, composition, density and k / ke of the measured model (exact formula, not the grid)."""
        info = self._summary_common()
        info["source"] = "Wang, O'Brien, Ramamoorthi 2011 via ARCSim 0.3.1"
        info["multipliers"] = {key: float(self.multipliers.get(key, 1.0)) for key in MULTIPLIER_KEYS}
        return info

    def to_arcsim_dict(self) -> dict:
        """ARCSim's material layout (multipliers baked in) plus name and composition."""
        return {
            "name": self.name,
            "composition": self.composition,
            "density": float(self._density.detach()),
            "stretching": self._stretching.detach().cpu().tolist(),
            "bending": self._bending.detach().cpu().tolist(),
        }
