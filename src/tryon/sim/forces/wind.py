"""Aerodynamic force on cloth faces: ARCSim 0.3.1's face drag model (``physics.cpp``, ``wind_force``).

For each face with unit normal ``n = unit((x1 - x0) x (x2 - x0))`` and material (rest) area
``A`` (ARCSim's ``face->a``)::

    v_rel = wind_velocity - (v0 + v1 + v2) / 3,     v_n = v_rel . n
    f_face = air_density A |v_n| v_n n + drag A (v_rel - v_n n)

``air_density`` (kg/m^3) scales the pressure drag along the normal and ``drag`` (kg/(m^2 s))
the linear tangential drag. One third of ``f_face`` goes to each corner. ARCSim adds this as
an explicit force; for implicit integration the velocity Jacobian is returned too::

    d f_a / d v_b = -D_ab,   D_ab = M / 9 for all corners a, b,
    M = 2 air_density A |v_n| n n^T + drag A (I - n n^T)

``D`` is positive semi-definite for ``air_density, drag >= 0``; the dependence of ``n`` on
positions is left out of the Jacobian (it is not a velocity derivative).
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit

from tryon.errors import SceneError
from tryon.sim.forces.geometry import as_numpy, numba_path_ok, output_buffer

TINY = 1e-300


def _face_normals(x: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Unit normals ``[3, F]`` (zero for a collapsed face)."""
    X = x.t()[:, faces.t()]  # [coord, corner, F]
    N = torch.linalg.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], dim=0)
    return N / N.norm(dim=0).clamp_min(TINY)


def _check_args(wind_velocity: torch.Tensor, air_density: float, drag: float) -> torch.Tensor:
    wind_velocity = torch.as_tensor(wind_velocity, dtype=torch.float64)
    if wind_velocity.shape != (3,) or not bool(torch.isfinite(wind_velocity.detach()).all()):
        raise SceneError(f"wind velocity must be 3 finite numbers (m/s), got {wind_velocity.detach().tolist()}")
    for name, value in (("air density", air_density), ("wind drag", drag)):
        if not float(value) >= 0.0:
            raise SceneError(f"{name} must be >= 0, got {value}; use 0 to switch the term off")
    return wind_velocity


def wind_forces(
    x: torch.Tensor,
    v: torch.Tensor,
    faces: torch.Tensor,
    rest_area: torch.Tensor,
    wind_velocity: torch.Tensor,
    air_density: float,
    drag: float,
    with_jacobian: bool = True,
    jac_out: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Vertex forces ``[N, 3]`` of ARCSim's face drag model and damping blocks ``D [F, 9, 9]``.

    ``D`` is the per-face velocity Jacobian with the sign flipped (``df/dv = -D``), blocks
    ordered like the face's corners; it is None when ``with_jacobian`` is False. When
    autograd is recording and ``x``, ``v``, ``rest_area`` or ``wind_velocity`` requires grad,
    the outputs are torch expressions; otherwise a numba kernel computes the same numbers
    (writing ``D`` into ``jac_out`` when given, to reuse one buffer across steps).
    """
    wind_velocity = _check_args(wind_velocity, air_density, drag).to(x.device)
    if numba_path_ok(x, v, rest_area, wind_velocity):
        return _wind_numba(x, v, faces, rest_area, wind_velocity, air_density, drag, with_jacobian, jac_out)
    n = _face_normals(x, faces)
    v_face = v.t()[:, faces.t()].mean(dim=1)  # [3, F]
    v_rel = wind_velocity[:, None] - v_face
    v_n = (v_rel * n).sum(0)
    normal_part = air_density * rest_area * v_n.abs() * v_n
    f_face = normal_part * n + drag * rest_area * (v_rel - v_n * n)  # [3, F]
    share = (f_face.t() / 3.0)[:, None, :].expand(-1, 3, 3).reshape(-1, 3)
    force = torch.zeros_like(x).index_add(0, faces.reshape(-1), share)
    if not with_jacobian:
        return force, None
    return force, _damping_blocks(n, v_n, rest_area, air_density, drag)


def _damping_blocks(
    n: torch.Tensor, v_n: torch.Tensor, area: torch.Tensor, air_density: float, drag: float
) -> torch.Tensor:
    """``D = ones(3, 3) (x) M / 9`` per face with ``M = 2 rho A |v_n| n n^T + drag A (I - n n^T)``."""
    nnT = n[:, None] * n[None]  # [3, 3, F]
    eye = torch.eye(3, dtype=n.dtype, device=n.device)[:, :, None]
    M = (2.0 * air_density * area * v_n.abs() - drag * area) * nnT + drag * area * eye
    M9 = (M / 9.0).reshape(9, -1).t().reshape(-1, 1, 3, 1, 3)
    return M9.expand(-1, 3, 3, 3, 3).reshape(-1, 9, 9)


@njit(cache=True)
def _wind_kernel(x, v, faces, area, wind, rho, drag, force, damping, with_jacobian):
    """Accumulate the face drag into ``force [N, 3]`` (zeroed) and fill ``damping [F, 9, 9]``."""
    n = np.empty(3)
    rel = np.empty(3)
    for f in range(faces.shape[0]):
        i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
        ax, ay, az = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]
        bx, by, bz = x[k, 0] - x[i, 0], x[k, 1] - x[i, 1], x[k, 2] - x[i, 2]
        n[0], n[1], n[2] = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        norm = max(np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), TINY)
        v_n = 0.0
        for r in range(3):
            n[r] /= norm
            rel[r] = wind[r] - (v[i, r] + v[j, r] + v[k, r]) / 3.0
            v_n += rel[r] * n[r]
        A = area[f]
        for r in range(3):
            share = (rho * A * abs(v_n) * v_n * n[r] + drag * A * (rel[r] - v_n * n[r])) / 3.0
            force[i, r] += share
            force[j, r] += share
            force[k, r] += share
        if not with_jacobian:
            continue
        along = 2.0 * rho * A * abs(v_n) - drag * A
        for r in range(3):
            for s in range(3):
                m = along * n[r] * n[s] / 9.0
                if r == s:
                    m += drag * A / 9.0
                for a in range(3):
                    for b in range(3):
                        damping[f, 3 * a + r, 3 * b + s] = m


def _wind_numba(x, v, faces, rest_area, wind_velocity, air_density, drag, with_jacobian, jac_out):
    fs = as_numpy(faces, np.int64)
    force = torch.zeros_like(x)
    shape = (fs.shape[0], 9, 9) if with_jacobian else (1, 9, 9)
    damping = output_buffer(shape, jac_out if with_jacobian else None, "jac_out")
    _wind_kernel(
        as_numpy(x), as_numpy(v), fs, as_numpy(rest_area), as_numpy(wind_velocity),
        float(air_density), float(drag), force.numpy(), damping.numpy(), with_jacobian,
    )
    return force, (damping if with_jacobian else None)
