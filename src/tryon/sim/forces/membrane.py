"""In-plane (membrane) force of a triangle cloth, as in ARCSim 0.3.1 ``physics.cpp``.

Per face ``f = (i, j, k)`` with material coordinates ``u`` and world positions ``x``
(Narain et al. 2012; Wang et al. 2011 stiffness model)::

    F = [x_j - x_i, x_k - x_i] @ Dm^-1          (3x2 deformation gradient, columns Fu, Fv)
    G = (F^T F - I) / 2                         (Green strain: Guu, Gvv, Guv)
    E_f = A_f / 2 * (k0 Guu^2 + 2 k1 Guu Gvv + k2 Gvv^2 + 2 k3 Guv^2)

``k = stiffness_fn(G)`` (N/m) is held constant when differentiating, as ARCSim does, so
the gradient is ``A_f (S_uu dGuu/dx + S_vv dGvv/dx + 2 k3 Guv dGuv/dx)`` with
``S_uu = k0 Guu + k1 Gvv``, ``S_vv = k1 Guu + k2 Gvv``; the force is its negative.

Hessian (ARCSim ``stretching_force``): the Gauss-Newton term ``A J^T K J`` with
``J = d(Guu, Gvv, Guv)/dx`` and ``K = [[k0, k1, 0], [k1, k2, 0], [0, 0, 2 k3]]``, plus the
geometric terms ``A (k0 max(Guu,0) + k1 max(Gvv,0)) d2Guu/dx2`` and
``A (k2 max(Gvv,0) + k1 max(Guu,0)) d2Gvv/dx2``; ARCSim drops ``Guv d2Guv/dx2`` because it
can be indefinite. The result equals the exact Hessian (k constant) when ``Guu, Gvv >= 0``
and ``Guv = 0``. ARCSim's block is positive semi-definite only when ``K`` is
(``k1^2 <= k0 k2``), which one measured row violates slightly (navy-sparkle-sweat). Here the
Hessian uses ``k0, k2, k3`` clamped at 0 and ``k1`` clamped to ``+-sqrt(k0 k2)`` (a no-op
whenever ARCSim's block is PSD already), so every 9x9 block is PSD.

Layout: gradients ``[F, 9]`` vertex-major ``(x_i, x_j, x_k)``, Hessians ``[F, 9, 9]``.

Two code paths give the same numbers: differentiable torch expressions (used whenever
autograd is recording and an input requires grad, and for non-CPU tensors) and a numba
kernel for the simulation's no-grad hot path.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch
from numba import njit

from tryon.sim.forces.geometry import as_numpy, numba_path_ok, output_buffer

F64 = torch.float64
StiffnessFn = Callable[[torch.Tensor], torch.Tensor]


# --------------------------------------------------------------------------- torch path


def _edge_weights(Dm_inv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weights ``a, b [3, F]`` with ``Fu = sum_c a_c x_c`` and ``Fv = sum_c b_c x_c``."""
    d00, d01, d10, d11 = Dm_inv[:, 0, 0], Dm_inv[:, 0, 1], Dm_inv[:, 1, 0], Dm_inv[:, 1, 1]
    return torch.stack([-d00 - d10, d00, d10]), torch.stack([-d01 - d11, d01, d11])


def _deformation(x: torch.Tensor, faces: torch.Tensor, Dm_inv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Columns ``Fu, Fv [3, F]`` of the deformation gradient ``F = Ds Dm^-1``."""
    X = x.t()[:, faces.t()]  # [coord, corner, F]
    e1, e2 = X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]
    Fu = e1 * Dm_inv[:, 0, 0] + e2 * Dm_inv[:, 1, 0]
    Fv = e1 * Dm_inv[:, 0, 1] + e2 * Dm_inv[:, 1, 1]
    return Fu, Fv


def _green(Fu: torch.Tensor, Fv: torch.Tensor) -> torch.Tensor:
    """Green strain ``[F, 3] = (Guu, Gvv, Guv)`` from the deformation-gradient columns."""
    Guu = 0.5 * ((Fu * Fu).sum(0) - 1.0)
    Gvv = 0.5 * ((Fv * Fv).sum(0) - 1.0)
    Guv = 0.5 * (Fu * Fv).sum(0)
    return torch.stack([Guu, Gvv, Guv], dim=1)


def _energy_density(G: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    Guu, Gvv, Guv = G.unbind(1)
    k0, k1, k2, k3 = k.unbind(1)
    return 0.5 * (k0 * Guu * Guu + 2.0 * k1 * Guu * Gvv + k2 * Gvv * Gvv + 2.0 * k3 * Guv * Guv)


def membrane_strain(x: torch.Tensor, faces: torch.Tensor, Dm_inv: torch.Tensor) -> torch.Tensor:
    """Green strain ``G [F, 3] = (Guu, Gvv, Guv)`` of each face in its material frame."""
    return _green(*_deformation(x, faces, Dm_inv))


def membrane_energy(
    x: torch.Tensor, faces: torch.Tensor, Dm_inv: torch.Tensor, rest_area: torch.Tensor, k: torch.Tensor
) -> torch.Tensor:
    """Per-face energy ``E_f = A_f/2 (k0 Guu^2 + 2 k1 Guu Gvv + k2 Gvv^2 + 2 k3 Guv^2)`` [F].

    ``k [F, 4]`` is given (not looked up), so the autograd gradient of this with respect to
    ``x`` is ARCSim's force with k held constant.
    """
    return rest_area * _energy_density(membrane_strain(x, faces, Dm_inv), k)


def psd_stiffness(k: torch.Tensor) -> torch.Tensor:
    """``k`` with ``k0, k2, k3 >= 0`` and ``|k1| <= sqrt(k0 k2)`` (the Hessian's K made PSD)."""
    k0, k1, k2, k3 = k.unbind(1)
    k0, k2, k3 = k0.clamp_min(0.0), k2.clamp_min(0.0), k3.clamp_min(0.0)
    bound = torch.sqrt((k0 * k2).clamp_min(1e-300))
    return torch.stack([k0, torch.minimum(torch.maximum(k1, -bound), bound), k2, k3], dim=1)


def _gradient_torch(Fu, Fv, a, b, G, k, area) -> torch.Tensor:
    """``g_c = A (S_uu a_c + k3 Guv b_c) Fu + A (S_vv b_c + k3 Guv a_c) Fv`` per corner c."""
    Guu, Gvv, Guv = G.t()
    k0, k1, k2, k3 = k.t()
    s_uu = area * (k0 * Guu + k1 * Gvv)
    s_vv = area * (k1 * Guu + k2 * Gvv)
    s_uv = area * k3 * Guv
    p = s_uu * a + s_uv * b  # [corner, F]
    q = s_vv * b + s_uv * a
    grad = p[:, None, :] * Fu[None] + q[:, None, :] * Fv[None]  # [corner, coord, F]
    return grad.reshape(9, -1).t().contiguous()


def _hessian_torch(Fu, Fv, a, b, G, k, area) -> torch.Tensor:
    """``A [J^T K J + (cu a a^T + cv b b^T) (x) I3]`` per face with the PSD-projected ``K``."""
    k0, k1, k2, k3 = (psd_stiffness(k) * area[:, None]).t()
    Guu, Gvv = G[:, 0].clamp_min(0.0), G[:, 1].clamp_min(0.0)
    cu = (k0 * Guu + k1 * Gvv).clamp_min(0.0)
    cv = (k2 * Gvv + k1 * Guu).clamp_min(0.0)
    fuu = (a[:, None] * Fu[None]).reshape(9, -1)  # dGuu/dx, [9, F]
    fvv = (b[:, None] * Fv[None]).reshape(9, -1)
    fuv = (0.5 * (a[:, None] * Fv[None] + b[:, None] * Fu[None])).reshape(9, -1)
    wu, wv, w3 = k0 * fuu + k1 * fvv, k1 * fuu + k2 * fvv, 2.0 * k3 * fuv
    H = fuu[:, None] * wu[None] + fvv[:, None] * wv[None] + fuv[:, None] * w3[None]  # [9, 9, F]
    geo = cu * a[:, None] * a[None] + cv * b[:, None] * b[None]  # [corner, corner, F]
    eye = torch.eye(3, dtype=H.dtype, device=H.device)
    H = H + (geo[:, None, :, None] * eye[None, :, None, :, None]).reshape(9, 9, -1)
    return H.reshape(81, -1).t().reshape(-1, 9, 9).contiguous()


def _forces_torch(x, faces, Dm_inv, rest_area, stiffness_fn, with_hessian):
    Fu, Fv = _deformation(x, faces, Dm_inv)
    G = _green(Fu, Fv)
    k = _stiffness(stiffness_fn, G)
    energy = rest_area * _energy_density(G, k)
    a, b = _edge_weights(Dm_inv)
    grad = _gradient_torch(Fu, Fv, a, b, G, k, rest_area)
    hess = _hessian_torch(Fu, Fv, a, b, G, k, rest_area) if with_hessian else None
    return energy, grad, hess


def _stiffness(stiffness_fn: StiffnessFn, G: torch.Tensor) -> torch.Tensor:
    k = stiffness_fn(G)
    if not isinstance(k, torch.Tensor) or tuple(k.shape) != (G.shape[0], 4):
        shape = tuple(k.shape) if isinstance(k, torch.Tensor) else type(k).__name__
        raise ValueError(f"stiffness_fn must map G [F, 3] to k [F, 4], returned {shape}")
    return k.to(G.dtype)


# --------------------------------------------------------------------------- numba path


@njit(cache=True)
def _strain_kernel(x, faces, Dm_inv, G):
    """Green strain ``G [F, 3]`` (same formula as `_green`), one face at a time."""
    for f in range(faces.shape[0]):
        i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
        uu = 0.0
        vv = 0.0
        uv = 0.0
        for r in range(3):
            e1 = x[j, r] - x[i, r]
            e2 = x[k, r] - x[i, r]
            fu = e1 * Dm_inv[f, 0, 0] + e2 * Dm_inv[f, 1, 0]
            fv = e1 * Dm_inv[f, 0, 1] + e2 * Dm_inv[f, 1, 1]
            uu += fu * fu
            vv += fv * fv
            uv += fu * fv
        G[f, 0] = 0.5 * (uu - 1.0)
        G[f, 1] = 0.5 * (vv - 1.0)
        G[f, 2] = 0.5 * uv


@njit(cache=True)
def _membrane_kernel(x, faces, Dm_inv, area, G, k, energy, grad, hess, with_hessian):
    """Energy, gradient and (optionally) Hessian per face: the formulas of `_gradient_torch`
    and `_hessian_torch`, with the Hessian's upper triangle mirrored (exactly symmetric)."""
    Fu = np.empty(3)
    Fv = np.empty(3)
    a = np.empty(3)
    b = np.empty(3)
    fuu = np.empty(9)
    fvv = np.empty(9)
    fuv = np.empty(9)
    for f in range(faces.shape[0]):
        i, j, l = faces[f, 0], faces[f, 1], faces[f, 2]
        d00, d01, d10, d11 = Dm_inv[f, 0, 0], Dm_inv[f, 0, 1], Dm_inv[f, 1, 0], Dm_inv[f, 1, 1]
        for r in range(3):
            e1 = x[j, r] - x[i, r]
            e2 = x[l, r] - x[i, r]
            Fu[r] = e1 * d00 + e2 * d10
            Fv[r] = e1 * d01 + e2 * d11
        a[0], a[1], a[2] = -d00 - d10, d00, d10
        b[0], b[1], b[2] = -d01 - d11, d01, d11
        Guu, Gvv, Guv = G[f, 0], G[f, 1], G[f, 2]
        k0, k1, k2, k3 = k[f, 0], k[f, 1], k[f, 2], k[f, 3]
        A = area[f]
        energy[f] = A * 0.5 * (k0 * Guu * Guu + 2.0 * k1 * Guu * Gvv + k2 * Gvv * Gvv + 2.0 * k3 * Guv * Guv)
        s_uu = A * (k0 * Guu + k1 * Gvv)
        s_vv = A * (k1 * Guu + k2 * Gvv)
        s_uv = A * k3 * Guv
        for c in range(3):
            p = s_uu * a[c] + s_uv * b[c]
            q = s_vv * b[c] + s_uv * a[c]
            for r in range(3):
                grad[f, 3 * c + r] = p * Fu[r] + q * Fv[r]
        if not with_hessian:
            continue
        # PSD-projected stiffness, times the area
        h0, h2, h3 = max(k0, 0.0), max(k2, 0.0), max(k3, 0.0)
        bound = np.sqrt(max(h0 * h2, 1e-300))
        h1 = min(max(k1, -bound), bound)
        h0, h1, h2, h3 = A * h0, A * h1, A * h2, A * h3
        pu, pv = max(Guu, 0.0), max(Gvv, 0.0)
        cu = max(h0 * pu + h1 * pv, 0.0)
        cv = max(h2 * pv + h1 * pu, 0.0)
        for c in range(3):
            for r in range(3):
                m = 3 * c + r
                fuu[m] = a[c] * Fu[r]
                fvv[m] = b[c] * Fv[r]
                fuv[m] = 0.5 * (a[c] * Fv[r] + b[c] * Fu[r])
        for m in range(9):
            wu = h0 * fuu[m] + h1 * fvv[m]
            wv = h1 * fuu[m] + h2 * fvv[m]
            w3 = 2.0 * h3 * fuv[m]
            for n in range(m, 9):
                value = fuu[n] * wu + fvv[n] * wv + fuv[n] * w3
                if n % 3 == m % 3:
                    c, d = m // 3, n // 3
                    value += cu * a[c] * a[d] + cv * b[c] * b[d]
                hess[f, m, n] = value
                hess[f, n, m] = value


def _forces_kernel(x, faces, Dm_inv, rest_area, stiffness_fn, with_hessian, hess_out):
    xs, fs, ds, area = as_numpy(x), as_numpy(faces, np.int64), as_numpy(Dm_inv), as_numpy(rest_area)
    num = fs.shape[0]
    G = np.empty((num, 3))
    _strain_kernel(xs, fs, ds, G)
    k = _stiffness(stiffness_fn, torch.from_numpy(G))
    if torch.is_grad_enabled() and k.requires_grad:
        return None
    energy, grad = torch.from_numpy(np.empty(num)), torch.from_numpy(np.empty((num, 9)))
    hess = output_buffer((num, 9, 9), hess_out, "hess_out") if with_hessian else torch.empty(1, 9, 9, dtype=F64)
    _membrane_kernel(xs, fs, ds, area, G, as_numpy(k), energy.numpy(), grad.numpy(), hess.numpy(), with_hessian)
    return energy, grad, (hess if with_hessian else None)


# --------------------------------------------------------------------------- public


def membrane_forces(
    x: torch.Tensor,
    faces: torch.Tensor,
    Dm_inv: torch.Tensor,
    rest_area: torch.Tensor,
    stiffness_fn: StiffnessFn,
    with_hessian: bool = True,
    hess_out: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Membrane energy ``[F]``, gradient ``dE/dx [F, 9]`` and PSD Hessian ``[F, 9, 9]`` or None.

    Closed forms (no autograd), ARCSim 0.3.1 ``stretching_force``: ``k = stiffness_fn(G)``
    (``G [F, 3] -> k [F, 4]``) is held constant in the derivatives; the force on the face's
    vertices is ``-grad``. When autograd is recording and ``x``, ``Dm_inv``, ``rest_area`` or
    ``k`` require grad, every output is a torch expression of them (so gradients flow to
    positions and fabric parameters); otherwise a numba kernel computes the same numbers.
    ``hess_out`` (optional, ``[F, 9, 9]`` float64) receives the Hessian on the numba path, so a
    caller can reuse one buffer across steps instead of allocating 81 F doubles each time.
    """
    if numba_path_ok(x, Dm_inv, rest_area):
        result = _forces_kernel(x, faces, Dm_inv, rest_area, stiffness_fn, with_hessian, hess_out)
        if result is not None:
            return result
    return _forces_torch(x, faces, Dm_inv, rest_area, stiffness_fn, with_hessian)
