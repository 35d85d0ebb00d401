"""Dihedral-angle bending of a triangle cloth, as in ARCSim 0.3.1 ``physics.cpp``.

A hinge ``(v0, v1, v2, v3)`` (see `tryon.sim.forces.geometry.build_hinges`) is an interior
edge ``v0 - v1`` with face0 ``(v0, v1, v2)`` and face1 ``(v1, v0, v3)``. ARCSim's signed
dihedral angle (``geometry.cpp``, ``dihedral_angle``) is::

    n0 = unit((x1 - x0) x (x2 - x0)),  n1 = unit((x0 - x1) x (x3 - x1)),  e = unit(x0 - x1)
    theta = atan2(e . (n0 x n1), n0 . n1)

so ``theta > 0`` when the wings fold towards the side their normals point to (the sheet
bends into a valley seen from ``+n``), and the Wang 2011 lookup, which is sign-dependent,
sees ``alpha = theta l / (2 (A0 + A1))`` with ``l`` the current edge length and ``A0 + A1``
the rest (material) areas of the two faces. The energy (Grinspun et al. 2003 "discrete
shells" form, ARCSim ``bending_energy``) is::

    E_h = ke l^2 (theta - theta_rest)^2 / (8 (A0 + A1)),   ke = stiffness_fn(alpha, edge_dir_uv)

Like ARCSim, the gradient holds ``ke`` and ``l`` constant:
``grad = ke l^2 / (4 (A0 + A1)) (theta - theta_rest) dtheta/dx``, and the Hessian is the
Gauss-Newton term ``ke l^2 / (4 (A0 + A1)) dtheta/dx dtheta/dx^T`` (PSD). ``dtheta/dx`` is
the closed form of Bridson et al. 2003: with ``h0, h1`` the heights of ``v2, v3`` over the
edge (clamped at ``1e-3 l`` as ARCSim does) and ``t0, t1`` their projections along the edge,
``dtheta/dx2 = n0/h0``, ``dtheta/dx3 = n1/h1``,
``dtheta/dx0 = -((1-t0) n0/h0 + (1-t1) n1/h1)``, ``dtheta/dx1 = -(t0 n0/h0 + t1 n1/h1)``.

Layout: gradients ``[H, 12]`` vertex-major ``(x0, x1, x2, x3)``, Hessians ``[H, 12, 12]``.
As in `tryon.sim.forces.membrane`, a torch path (autograd) and a numba path (no-grad hot
path) compute the same numbers.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import torch
from numba import njit

from tryon.errors import MeshError
from tryon.sim.forces.geometry import DTYPE, as_numpy, check_faces, check_vertices, numba_path_ok, output_buffer

BendingStiffnessFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]

MIN_HEIGHT_FRACTION = 1e-3  # ARCSim physics.cpp distance(): h >= 1e-3 |e|
TINY = 1e-300
F64 = torch.float64


# --------------------------------------------------------------------------- torch path


def _unwrap(theta: torch.Tensor, reference: torch.Tensor | None) -> torch.Tensor:
    """ARCSim ``unwrap_angle``: shift by multiples of 2 pi to lie within pi of the reference."""
    if reference is None:
        return theta
    turns = torch.floor((reference.detach() - theta.detach()) / (2.0 * math.pi) + 0.5)
    return theta + 2.0 * math.pi * turns


def _hinge_frame(x: torch.Tensor, hinges: torch.Tensor):
    """Corner positions ``[3, H]`` each, edge vector ``E = x1 - x0`` and the raw face normals."""
    X = x.t()[:, hinges.t()]  # [coord, corner, H]
    x0, x1, x2, x3 = X.unbind(1)
    E = x1 - x0
    N0 = torch.linalg.cross(E, x2 - x0, dim=0)
    N1 = torch.linalg.cross(x3 - x1, E, dim=0)  # (x0 - x1) x (x3 - x1)
    return x0, x2, x3, E, N0, N1


def _theta_from_frame(E, N0, N1, length, reference):
    """``theta`` (0 where a face has collapsed, as in ARCSim) and the unit normals."""
    a0, a1 = N0.norm(dim=0), N1.norm(dim=0)
    n0 = N0 / a0.clamp_min(TINY)
    n1 = N1 / a1.clamp_min(TINY)
    sine = -(E * torch.linalg.cross(n0, n1, dim=0)).sum(0) / length
    cosine = (n0 * n1).sum(0)
    theta = torch.where((a0 > 0) & (a1 > 0), torch.atan2(sine, cosine), torch.zeros_like(sine))
    return _unwrap(theta, reference), n0, n1


def dihedral_angle(x: torch.Tensor, hinges: torch.Tensor, reference_theta: torch.Tensor | None = None) -> torch.Tensor:
    """Signed dihedral angle ``theta [H]`` of each hinge, ARCSim convention (see module doc).

    ``reference_theta`` (optional, e.g. the previous step's angles) unwraps ``theta`` to within
    pi of it, as ARCSim does with ``edge->reference_angle``; without it theta is in (-pi, pi].
    """
    _, _, _, E, N0, N1 = _hinge_frame(x, hinges)
    length = E.norm(dim=0).clamp_min(TINY)
    return _theta_from_frame(E, N0, N1, length, reference_theta)[0]


def bending_energy(
    x: torch.Tensor, hinges: torch.Tensor, rest_theta: torch.Tensor, area_sum: torch.Tensor, ke: torch.Tensor
) -> torch.Tensor:
    """Per-hinge energy ``E_h = ke l^2 (theta - theta_rest)^2 / (8 (A0 + A1))`` [H], ``ke`` given.

    Plain torch expression with the current edge length ``l`` (its autograd gradient also
    differentiates ``l``, which ARCSim's force does not; see `bending_forces`).
    """
    _, _, _, E, N0, N1 = _hinge_frame(x, hinges)
    length = E.norm(dim=0)
    theta = _theta_from_frame(E, N0, N1, length.clamp_min(TINY), None)[0]
    return ke * length * length * (theta - rest_theta) ** 2 / (8.0 * area_sum)


def _theta_gradient(x0, x2, x3, E, n0, n1, N0, N1, length) -> torch.Tensor:
    """Closed-form ``dtheta/dx [4, 3, H]`` (Bridson et al. 2003, ARCSim ``bending_force``)."""
    floor = MIN_HEIGHT_FRACTION * length
    h0 = torch.maximum(N0.norm(dim=0) / length, floor)
    h1 = torch.maximum(N1.norm(dim=0) / length, floor)
    t0 = ((x2 - x0) * E).sum(0) / (length * length)
    t1 = ((x3 - x0) * E).sum(0) / (length * length)
    g2, g3 = n0 / h0, n1 / h1
    g0 = -((1.0 - t0) * g2 + (1.0 - t1) * g3)
    g1 = -(t0 * g2 + t1 * g3)
    return torch.stack([g0, g1, g2, g3])


def _forces_torch(x, hinges, rest_theta, area_sum, edge_dir_uv, stiffness_fn, with_hessian, reference_theta):
    x0, x2, x3, E, N0, N1 = _hinge_frame(x, hinges)
    length = E.norm(dim=0).clamp_min(TINY)
    theta, n0, n1 = _theta_from_frame(E, N0, N1, length, reference_theta)
    ke = _stiffness(stiffness_fn, theta * length / (2.0 * area_sum), edge_dir_uv)
    coeff = ke * length * length / (4.0 * area_sum)
    energy = 0.5 * coeff * (theta - rest_theta) ** 2
    dtheta = _theta_gradient(x0, x2, x3, E, n0, n1, N0, N1, length).reshape(12, -1)  # [12, H]
    grad = (coeff * (theta - rest_theta) * dtheta).t().contiguous()
    hess = None
    if with_hessian:
        dtheta_h = dtheta.t()
        hess = (coeff[:, None] * dtheta_h)[:, :, None] * dtheta_h[:, None, :]
    return energy, grad, hess


def _stiffness(stiffness_fn: BendingStiffnessFn, alpha: torch.Tensor, edge_dir_uv: torch.Tensor) -> torch.Tensor:
    ke = stiffness_fn(alpha, edge_dir_uv)
    if not isinstance(ke, torch.Tensor) or tuple(ke.shape) != tuple(alpha.shape):
        shape = tuple(ke.shape) if isinstance(ke, torch.Tensor) else type(ke).__name__
        raise ValueError(f"stiffness_fn must map alpha [H] and edge_dir_uv [H, 2] to ke [H], returned {shape}")
    return ke.to(alpha.dtype)


# --------------------------------------------------------------------------- numba path


@njit(cache=True)
def _theta_kernel(x, hinges, reference, use_reference, theta, length, dtheta):
    """theta [H], l [H] and dtheta/dx [H, 12] of every hinge (unnormalised normals N0, N1:
    atan2 is invariant to their positive scale |N0| |N1|)."""
    for h in range(hinges.shape[0]):
        v0, v1, v2, v3 = hinges[h, 0], hinges[h, 1], hinges[h, 2], hinges[h, 3]
        ex, ey, ez = x[v1, 0] - x[v0, 0], x[v1, 1] - x[v0, 1], x[v1, 2] - x[v0, 2]
        ax, ay, az = x[v2, 0] - x[v0, 0], x[v2, 1] - x[v0, 1], x[v2, 2] - x[v0, 2]
        bx, by, bz = x[v3, 0] - x[v0, 0], x[v3, 1] - x[v0, 1], x[v3, 2] - x[v0, 2]
        cx, cy, cz = bx - ex, by - ey, bz - ez  # x3 - x1
        N0x, N0y, N0z = ey * az - ez * ay, ez * ax - ex * az, ex * ay - ey * ax  # E x (x2 - x0)
        N1x, N1y, N1z = cy * ez - cz * ey, cz * ex - cx * ez, cx * ey - cy * ex  # (x3 - x1) x E
        l2 = max(ex * ex + ey * ey + ez * ez, TINY)
        l = np.sqrt(l2)
        a0 = np.sqrt(N0x * N0x + N0y * N0y + N0z * N0z)
        a1 = np.sqrt(N1x * N1x + N1y * N1y + N1z * N1z)
        t = 0.0
        if a0 > 0.0 and a1 > 0.0:
            mx, my, mz = N0y * N1z - N0z * N1y, N0z * N1x - N0x * N1z, N0x * N1y - N0y * N1x
            t = np.arctan2(-(ex * mx + ey * my + ez * mz) / l, N0x * N1x + N0y * N1y + N0z * N1z)
        if use_reference:
            t += 2.0 * np.pi * np.floor((reference[h] - t) / (2.0 * np.pi) + 0.5)
        theta[h] = t
        length[h] = l
        # n / h = N / (|N| max(|N| / l, 1e-3 l))
        floor = MIN_HEIGHT_FRACTION * l
        s0 = 1.0 / (a0 * max(a0 / l, floor)) if a0 > 0.0 else 0.0
        s1 = 1.0 / (a1 * max(a1 / l, floor)) if a1 > 0.0 else 0.0
        t0 = (ax * ex + ay * ey + az * ez) / l2
        t1 = (bx * ex + by * ey + bz * ez) / l2
        g2x, g2y, g2z = N0x * s0, N0y * s0, N0z * s0
        g3x, g3y, g3z = N1x * s1, N1y * s1, N1z * s1
        dtheta[h, 0] = -((1.0 - t0) * g2x + (1.0 - t1) * g3x)
        dtheta[h, 1] = -((1.0 - t0) * g2y + (1.0 - t1) * g3y)
        dtheta[h, 2] = -((1.0 - t0) * g2z + (1.0 - t1) * g3z)
        dtheta[h, 3] = -(t0 * g2x + t1 * g3x)
        dtheta[h, 4] = -(t0 * g2y + t1 * g3y)
        dtheta[h, 5] = -(t0 * g2z + t1 * g3z)
        dtheta[h, 6], dtheta[h, 7], dtheta[h, 8] = g2x, g2y, g2z
        dtheta[h, 9], dtheta[h, 10], dtheta[h, 11] = g3x, g3y, g3z


@njit(cache=True)
def _bending_kernel(theta, rest_theta, coeff, dtheta, energy, grad, hess, with_hessian):
    """``E = c/2 (theta - rest)^2``, ``grad = c (theta - rest) dtheta``, ``hess = c dtheta dtheta^T``
    with ``c = ke l^2 / (4 (A0 + A1))``."""
    for h in range(theta.shape[0]):
        d = theta[h] - rest_theta[h]
        c = coeff[h]
        energy[h] = 0.5 * c * d * d
        s = c * d
        for m in range(12):
            grad[h, m] = s * dtheta[h, m]
        if with_hessian:
            for m in range(12):
                cm = c * dtheta[h, m]
                for n in range(m, 12):
                    value = cm * dtheta[h, n]
                    hess[h, m, n] = value
                    hess[h, n, m] = value


def _hinge_terms(x, hinges, rest_theta, area_sum, edge_dir_uv, stiffness_fn, reference_theta):
    """(theta, rest, coeff c, dtheta) of every hinge, numpy; None when the stiffness needs
    autograd."""
    hs = as_numpy(hinges, np.int64)
    num = hs.shape[0]
    theta, length, dtheta = np.empty(num), np.empty(num), np.empty((num, 12))
    reference = as_numpy(reference_theta) if reference_theta is not None else np.zeros(1)
    _theta_kernel(as_numpy(x), hs, reference, reference_theta is not None, theta, length, dtheta)
    theta_t, length_t = torch.from_numpy(theta), torch.from_numpy(length)
    ke = _stiffness(stiffness_fn, theta_t * length_t / (2.0 * area_sum), edge_dir_uv)
    if torch.is_grad_enabled() and ke.requires_grad:
        return None
    coeff = as_numpy(ke * length_t * length_t / (4.0 * area_sum))
    return theta, as_numpy(rest_theta), coeff, dtheta


def _forces_kernel(x, hinges, rest_theta, area_sum, edge_dir_uv, stiffness_fn, with_hessian, reference_theta, hess_out):
    terms = _hinge_terms(x, hinges, rest_theta, area_sum, edge_dir_uv, stiffness_fn, reference_theta)
    if terms is None:
        return None
    theta, rest, coeff, dtheta = terms
    num = theta.shape[0]
    energy, grad = torch.from_numpy(np.empty(num)), torch.from_numpy(np.empty((num, 12)))
    hess = output_buffer((num, 12, 12), hess_out, "hess_out") if with_hessian else torch.empty(1, 12, 12, dtype=F64)
    _bending_kernel(theta, rest, coeff, dtheta, energy.numpy(), grad.numpy(), hess.numpy(), with_hessian)
    return energy, grad, (hess if with_hessian else None)


# --------------------------------------------------------------------------- public


def bending_forces(
    x: torch.Tensor,
    hinges: torch.Tensor,
    rest_theta: torch.Tensor,
    area_sum: torch.Tensor,
    edge_dir_uv: torch.Tensor,
    stiffness_fn: BendingStiffnessFn,
    with_hessian: bool = True,
    reference_theta: torch.Tensor | None = None,
    hess_out: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Bending energy ``[H]``, gradient ``[H, 12]`` and Gauss-Newton Hessian ``[H, 12, 12]`` or None.

    ARCSim 0.3.1 ``bending_force``: ``ke = stiffness_fn(alpha [H], edge_dir_uv [H, 2]) -> [H]``
    with ``alpha = theta l / (2 (A0 + A1))``; ``ke`` and the current edge length ``l`` are
    held constant in the derivatives. The force is ``-grad``. ``reference_theta`` unwraps the
    angle (see `dihedral_angle`). When autograd is recording and an input (``x``,
    ``rest_theta``, ``area_sum`` or ``ke``) requires grad, the outputs are torch expressions;
    otherwise a numba kernel computes the same numbers, writing the Hessian into ``hess_out``
    (``[H, 12, 12]`` float64) when given so that one buffer can be reused across steps.
    """
    if numba_path_ok(x, rest_theta, area_sum):
        result = _forces_kernel(
            x, hinges, rest_theta, area_sum, edge_dir_uv, stiffness_fn, with_hessian, reference_theta, hess_out
        )
        if result is not None:
            return result
    return _forces_torch(x, hinges, rest_theta, area_sum, edge_dir_uv, stiffness_fn, with_hessian, reference_theta)


def bending_forces_rank_one(
    x: torch.Tensor,
    hinges: torch.Tensor,
    rest_theta: torch.Tensor,
    area_sum: torch.Tensor,
    edge_dir_uv: torch.Tensor,
    stiffness_fn: BendingStiffnessFn,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`bending_forces` without autograd, its Hessian left as the rank-one factors it is
    made of: (energy [H], gradient [H, 12], c [H], dtheta [H, 12]) with Hessian
    ``c dtheta dtheta^T``, numpy. The assembly adds the factors' products straight into
    the system's blocks (`tryon.sim.linear.scatter_rank_one_blocks`, the same numbers)
    instead of writing and reading 144 numbers per hinge."""
    terms = _hinge_terms(x, hinges, rest_theta, area_sum, edge_dir_uv, stiffness_fn, None) \
        if numba_path_ok(x, rest_theta, area_sum) else None
    if terms is None:
        raise ValueError("bending_forces_rank_one runs the numba kernel only: give CPU float64 tensors and call it "
                         "under torch.no_grad() (it records no gradients; use bending_forces for those)")
    theta, rest, coeff, dtheta = terms
    num = theta.shape[0]
    energy, grad = np.empty(num), np.empty((num, 12))
    _bending_kernel(theta, rest, coeff, dtheta, energy, grad, np.empty((1, 12, 12)), False)
    return energy, grad, coeff, dtheta


# --------------------------------------------------------------------------- rest state


def hinge_rest_data(
    x_rest: torch.Tensor | None, uv: torch.Tensor, faces: torch.Tensor, hinges: torch.Tensor
) -> dict[str, torch.Tensor]:
    """Per-hinge rest quantities of ARCSim's bending term.

    * ``rest_theta [H]``: rest dihedral angle ``theta_ideal``. ARCSim's ``reset_plasticity``
      sets it to the dihedral angle of the mesh as loaded (world space), so pass the initial
      positions as ``x_rest`` to match ARCSim; ``None`` means a flat rest shape (zeros).
    * ``area_sum [H]``: ``A0 + A1``, the material-space areas of the two hinge faces
      ``(v0, v1, v2)`` and ``(v1, v0, v3)``.
    * ``edge_dir_uv [H, 2]``: ``u(v1) - u(v0)``, the material-space edge direction used by the
      Wang 2011 bending lookup (ARCSim ``dde.cpp``, ``bending_stiffness``).

    ``faces`` is used to validate that ``hinges`` and ``uv`` describe the same mesh.
    """
    uv = check_vertices(uv, 2, "uv (material coordinates)")
    faces = check_faces(faces, uv.shape[0])
    hinges = _check_hinges(hinges, uv.shape[0])
    u0, u1, u2, u3 = (uv[hinges[:, c]] for c in range(4))
    area0 = 0.5 * _cross2(u1 - u0, u2 - u0).abs()
    area1 = 0.5 * _cross2(u0 - u1, u3 - u1).abs()
    if x_rest is None:
        rest_theta = torch.zeros(hinges.shape[0], dtype=DTYPE)
    else:
        x_rest = check_vertices(x_rest, 3, "x_rest (rest positions)")
        if x_rest.shape[0] != uv.shape[0]:
            raise MeshError(f"x_rest has {x_rest.shape[0]} vertices but uv has {uv.shape[0]}; give one row per vertex")
        rest_theta = dihedral_angle(x_rest, hinges)
    return {"rest_theta": rest_theta, "area_sum": area0 + area1, "edge_dir_uv": u1 - u0}


def hinge_rest_data_corners(
    corner_uv: torch.Tensor, faces: torch.Tensor, hinges: torch.Tensor, hinge_faces: torch.Tensor
) -> dict[str, torch.Tensor]:
    """`hinge_rest_data` (flat rest shape) from material coordinates per face corner
    [F,3,2]: the areas come from each hinge face's own corners and the edge direction
    from the first face's, so a hinge across a welded seam sees both panels' patterns."""
    f0, f1 = hinge_faces[:, 0], hinge_faces[:, 1]

    def area(f: torch.Tensor) -> torch.Tensor:
        c = corner_uv[f]
        return 0.5 * _cross2(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]).abs()

    def corner_of(f: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        k = (faces[f] == v[:, None]).to(torch.int64).argmax(1)
        return corner_uv[f, k]

    edge_dir = corner_of(f0, hinges[:, 1]) - corner_of(f0, hinges[:, 0])
    return {"rest_theta": torch.zeros(hinges.shape[0], dtype=DTYPE), "area_sum": area(f0) + area(f1), "edge_dir_uv": edge_dir}


def _check_hinges(hinges: torch.Tensor, num_vertices: int) -> torch.Tensor:
    if not isinstance(hinges, torch.Tensor) or hinges.ndim != 2 or hinges.shape[1] != 4:
        shape = tuple(hinges.shape) if isinstance(hinges, torch.Tensor) else type(hinges).__name__
        raise MeshError(f"hinges must be an integer tensor [H, 4] from build_hinges, got {shape}")
    hinges = hinges.to(torch.int64)
    if hinges.numel() and (int(hinges.min()) < 0 or int(hinges.max()) >= num_vertices):
        raise MeshError(f"hinges index vertices beyond the {num_vertices} given; rebuild them with build_hinges(faces)")
    return hinges


def _cross2(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


# --------------------------------------------------------------------------- kernel-path helpers
