"""Tests for tryon.sim.forces: membrane, bending and wind terms against autograd, central
finite differences, hand-derived values and an independent transcription of ARCSim's
matrix formulas (Kronecker-product form of physics.cpp, evaluated face by face in numpy).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tryon.errors import MeshError, SceneError
from tryon.sim.forces import (
    bending_energy,
    bending_forces,
    build_hinges,
    dihedral_angle,
    hinge_rest_data,
    membrane_energy,
    membrane_forces,
    membrane_strain,
    rest_state,
    wind_forces,
)

F64 = torch.float64
K_CONST = torch.tensor([60.0, 12.0, 240.0, 35.0], dtype=F64)


# --------------------------------------------------------------------------- meshes


def grid(n: int = 4, size: float = 0.3) -> tuple[torch.Tensor, torch.Tensor]:
    """``n x n`` vertex grid: uv in metres and faces with alternating diagonals."""
    s = torch.linspace(0.0, size, n, dtype=F64)
    u, v = torch.meshgrid(s, s, indexing="ij")
    uv = torch.stack([u.reshape(-1), v.reshape(-1)], dim=1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            faces += [[a, b, c], [a, c, d]] if (i + j) % 2 == 0 else [[a, b, d], [b, c, d]]
    return uv, torch.tensor(faces, dtype=torch.int64)


def deformed(uv: torch.Tensor, seed: int, stretch=(1.0, 1.0), shear=0.0, bend=0.0, noise=0.0) -> torch.Tensor:
    """World positions: a sheared/stretched, bent and randomly perturbed copy of the chart."""
    gen = torch.Generator().manual_seed(seed)
    u, v = uv[:, 0], uv[:, 1]
    x = torch.stack([stretch[0] * u + shear * v, stretch[1] * v, bend * torch.sin(7.0 * u + 3.0 * v)], dim=1)
    angle = 0.7 + seed
    rot = torch.tensor(
        [[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0], [0.0, 0.0, 1.0]], dtype=F64
    )
    return x @ rot.T + noise * torch.randn(x.shape, generator=gen, dtype=F64)


DEFORMATIONS = [
    dict(stretch=(1.0, 1.0), noise=0.01),  # near rest, mixed signs of G
    dict(stretch=(1.3, 0.8), shear=0.2, noise=0.02),  # stretch + compression + shear
    dict(stretch=(1.6, 1.5), shear=-0.4, bend=0.05, noise=0.03),  # large strain, bent
    dict(stretch=(0.6, 0.7), bend=0.1, noise=0.02),  # strong compression, wrinkled
]


def smooth_stiffness(G: torch.Tensor) -> torch.Tensor:
    """A strain-dependent k [F, 4] (N/m), smooth in G, PSD membrane matrix."""
    s = 1.0 + 2.0 * torch.tanh(G[:, 0] ** 2 + G[:, 1] ** 2 + G[:, 2] ** 2)
    return K_CONST * s[:, None]


def const_stiffness(G: torch.Tensor) -> torch.Tensor:
    return K_CONST.expand(G.shape[0], 4)


def const_bending(alpha: torch.Tensor, edge_dir_uv: torch.Tensor) -> torch.Tensor:
    return torch.full_like(alpha, 2.0e-5)


def smooth_bending(alpha: torch.Tensor, edge_dir_uv: torch.Tensor) -> torch.Tensor:
    angle = torch.atan2(edge_dir_uv[:, 1], edge_dir_uv[:, 0])
    return 1.0e-5 * (1.0 + 0.1 * alpha + 0.05 * alpha**2) * (1.5 + torch.cos(2.0 * angle))


def central_difference(fn, x: torch.Tensor, eps: float) -> torch.Tensor:
    """d fn(x) / dx by central differences; fn returns a tensor of any shape -> [*out, *x]."""
    flat = x.reshape(-1)
    cols = []
    for i in range(flat.numel()):
        dx = torch.zeros_like(flat)
        dx[i] = eps
        cols.append((fn((flat + dx).reshape(x.shape)) - fn((flat - dx).reshape(x.shape))) / (2 * eps))
    return torch.stack(cols, dim=-1)


def scatter_grad(grad: torch.Tensor, elements: torch.Tensor, n: int) -> torch.Tensor:
    """Per-element vertex-major gradients [E, 3k] -> per-vertex [n, 3]."""
    k = elements.shape[1]
    return torch.zeros(n, 3, dtype=F64).index_add(0, elements.reshape(-1), grad.reshape(-1, k, 3).reshape(-1, 3))


def assemble(blocks: torch.Tensor, elements: torch.Tensor, n: int) -> torch.Tensor:
    """Dense [3n, 3n] matrix from per-element blocks [E, 3k, 3k]."""
    k = elements.shape[1]
    dofs = (elements[:, :, None] * 3 + torch.arange(3)).reshape(-1, 3 * k)
    M = torch.zeros(3 * n, 3 * n, dtype=F64)
    rows = dofs[:, :, None].expand(-1, -1, 3 * k).reshape(-1)
    cols = dofs[:, None, :].expand(-1, 3 * k, -1).reshape(-1)
    return M.index_put((rows, cols), blocks.reshape(-1), accumulate=True)


def rel_err(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-300))


def assert_psd(blocks: torch.Tensor) -> None:
    eig = torch.linalg.eigvalsh(0.5 * (blocks + blocks.transpose(1, 2)))
    scale = eig.abs().amax(dim=1).clamp_min(1e-300)
    assert bool((eig >= -1e-12 * scale[:, None]).all()), float((eig / scale[:, None]).min())


# --------------------------------------------------------------------------- rest state


def test_rest_state_inverts_material_edges_and_sums_area():
    uv, faces = grid(5, 0.4)
    Dm_inv, area = rest_state(uv, faces)
    Dm = torch.stack([uv[faces[:, 1]] - uv[faces[:, 0]], uv[faces[:, 2]] - uv[faces[:, 0]]], dim=2)
    assert torch.allclose(Dm @ Dm_inv, torch.eye(2, dtype=F64).expand_as(Dm), atol=1e-12)
    assert area.sum().item() == pytest.approx(0.4 * 0.4, rel=1e-12)
    # F = I at the rest state (x = (u, v, 0)) -> zero strain
    x = torch.cat([uv, torch.zeros(uv.shape[0], 1, dtype=F64)], dim=1)
    assert membrane_strain(x, faces, Dm_inv).abs().max() < 1e-14


def test_rest_state_accepts_mirrored_chart_with_same_physics():
    uv, faces = grid(4)
    mirrored = uv * torch.tensor([1.0, -1.0], dtype=F64)
    Dm_inv, area = rest_state(uv, faces)
    Dm_inv_m, area_m = rest_state(mirrored, faces)
    assert torch.allclose(area, area_m)
    x = deformed(uv, 1, **DEFORMATIONS[1])
    G, G_m = membrane_strain(x, faces, Dm_inv), membrane_strain(x, faces, Dm_inv_m)
    assert torch.allclose(G[:, :2], G_m[:, :2]) and torch.allclose(G[:, 2], -G_m[:, 2])


def test_rest_state_rejects_degenerate_triangle_naming_face():
    uv, faces = grid(4)
    uv = uv.clone()
    f = 7
    a, b, c = faces[f].tolist()
    uv[c] = 0.5 * (uv[a] + uv[b])  # collinear corners
    with pytest.raises(MeshError, match=r"face \d+"):
        rest_state(uv, faces)
    bad = torch.tensor([[0, 1, 2]], dtype=torch.int64)
    with pytest.raises(MeshError, match="face 0"):
        rest_state(torch.tensor([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0]], dtype=F64), bad)


def test_rest_state_rejects_folded_and_malformed_input():
    uv, faces = grid(4)
    flipped = faces.clone()
    flipped[5] = flipped[5][[0, 2, 1]]
    with pytest.raises(MeshError, match="face 5"):
        rest_state(uv, flipped)
    with pytest.raises(MeshError, match="repeats a vertex"):
        rest_state(uv, torch.tensor([[0, 0, 1]]))
    with pytest.raises(MeshError, match="index vertices"):
        rest_state(uv, torch.tensor([[0, 1, 99]]))
    nan_uv = uv.clone()
    nan_uv[3, 0] = float("nan")
    with pytest.raises(MeshError, match="NaN"):
        rest_state(nan_uv, faces)


# --------------------------------------------------------------------------- hinges


def test_build_hinges_grid_counts_and_arcsim_ordering():
    n = 5
    uv, faces = grid(n)
    hinges, hinge_faces = build_hinges(faces, return_faces=True)
    interior_edges = 3 * (n - 1) * (n - 1) - 2 * (n - 1)  # edges - boundary edges
    assert hinges.shape == (interior_edges, 4)
    for (v0, v1, v2, v3), (f0, f1) in zip(hinges.tolist(), hinge_faces.tolist()):
        assert f0 < f1  # adjf[0] is the first face containing the edge
        face0, face1 = faces[f0].tolist(), faces[f1].tolist()
        cyc0 = [face0[i:] + face0[:i] for i in range(3)]
        cyc1 = [face1[i:] + face1[:i] for i in range(3)]
        assert [v0, v1, v2] in cyc0  # face0 traverses v0 -> v1
        assert [v1, v0, v3] in cyc1  # face1 traverses v1 -> v0


def test_build_hinges_rejects_non_manifold_edge_naming_it():
    faces = torch.tensor([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(MeshError, match=r"non-manifold edge \(0, 1\)"):
        build_hinges(faces)


def test_build_hinges_rejects_inconsistent_orientation():
    faces = torch.tensor([[0, 1, 2], [0, 1, 3]])
    with pytest.raises(MeshError, match="same direction"):
        build_hinges(faces)


def test_hinge_rest_data_areas_direction_and_rest_angle():
    uv, faces = grid(4)
    hinges, hinge_faces = build_hinges(faces, return_faces=True)
    _, area = rest_state(uv, faces)
    data = hinge_rest_data(None, uv, faces, hinges)
    assert torch.allclose(data["area_sum"], area[hinge_faces[:, 0]] + area[hinge_faces[:, 1]])
    assert torch.allclose(data["edge_dir_uv"], uv[hinges[:, 1]] - uv[hinges[:, 0]])
    assert data["rest_theta"].abs().max() == 0.0
    x_rest = deformed(uv, 2, bend=0.08)
    bent = hinge_rest_data(x_rest, uv, faces, hinges)
    assert torch.allclose(bent["rest_theta"], dihedral_angle(x_rest, hinges))
    assert bent["rest_theta"].abs().max() > 0.01


# --------------------------------------------------------------------------- membrane


@pytest.mark.parametrize("case", range(len(DEFORMATIONS)))
@pytest.mark.parametrize("stiffness_fn", [const_stiffness, smooth_stiffness])
def test_membrane_gradient_matches_autograd_and_finite_differences(case, stiffness_fn):
    uv, faces = grid(4)
    Dm_inv, area = rest_state(uv, faces)
    x = deformed(uv, case, **DEFORMATIONS[case])
    energy, grad, _ = membrane_forces(x, faces, Dm_inv, area, stiffness_fn, with_hessian=False)
    k = stiffness_fn(membrane_strain(x, faces, Dm_inv)).detach()  # held constant (ARCSim)
    assert torch.allclose(energy, membrane_energy(x, faces, Dm_inv, area, k), rtol=1e-13, atol=0)
    xg = x.clone().requires_grad_(True)
    (auto,) = torch.autograd.grad(membrane_energy(xg, faces, Dm_inv, area, k).sum(), xg)
    n = x.shape[0]
    assert rel_err(scatter_grad(grad, faces, n), auto) < 1e-12
    fd = central_difference(lambda y: membrane_energy(y, faces, Dm_inv, area, k).sum(), x, 1e-6)
    assert rel_err(scatter_grad(grad, faces, n), fd.reshape(n, 3)) < 1e-6


@pytest.mark.parametrize("case", range(len(DEFORMATIONS)))
def test_membrane_numba_and_torch_paths_agree(case):
    uv, faces = grid(5)
    Dm_inv, area = rest_state(uv, faces)
    x = deformed(uv, case, **DEFORMATIONS[case])
    fast = membrane_forces(x, faces, Dm_inv, area, smooth_stiffness)
    xg = x.clone().requires_grad_(True)  # forces the differentiable torch path
    slow = membrane_forces(xg, faces, Dm_inv, area, smooth_stiffness)
    for a, b in zip(fast, slow):
        assert rel_err(a, b.detach()) < 1e-12
    assert torch.equal(fast[2], fast[2].transpose(1, 2))  # numba path is exactly symmetric


@pytest.mark.parametrize("case", range(len(DEFORMATIONS)))
def test_membrane_hessian_is_psd(case):
    uv, faces = grid(5)
    Dm_inv, area = rest_state(uv, faces)
    x = deformed(uv, case, **DEFORMATIONS[case])
    _, _, hess = membrane_forces(x, faces, Dm_inv, area, smooth_stiffness)
    assert_psd(hess)
    # k1^2 > k0 k2 (indefinite ARCSim block) and negative entries are projected away
    bad = torch.tensor([40.0, 150.0, 200.0, -5.0], dtype=F64)
    _, _, hess_bad = membrane_forces(x, faces, Dm_inv, area, lambda G: bad.expand(G.shape[0], 4))
    assert_psd(hess_bad)


def test_membrane_hessian_exact_where_arcsim_approximation_is_exact():
    """G >= 0 componentwise and Guv = 0: F = R [s_u e_u, s_v e_v] with s >= 1."""
    uv, faces = grid(4)
    Dm_inv, area = rest_state(uv, faces)
    x = deformed(uv, 0, stretch=(1.25, 1.1))
    G = membrane_strain(x, faces, Dm_inv)
    assert bool((G[:, :2] > 0).all()) and G[:, 2].abs().max() < 1e-14
    _, _, hess = membrane_forces(x, faces, Dm_inv, area, const_stiffness)
    n = x.shape[0]
    H = assemble(hess, faces, n)
    k = const_stiffness(G)

    def grad_at(y):
        return scatter_grad(membrane_forces(y, faces, Dm_inv, area, const_stiffness, False)[1], faces, n).reshape(-1)

    fd = central_difference(grad_at, x, 1e-6)
    assert rel_err(H, fd) < 1e-6
    exact = torch.autograd.functional.hessian(lambda y: membrane_energy(y, faces, Dm_inv, area, k).sum(), x)
    assert rel_err(H, exact.reshape(3 * n, 3 * n)) < 1e-12
    # away from that regime (shear, compression) the approximation differs from the exact Hessian
    y = deformed(uv, 1, **DEFORMATIONS[1])
    approx = assemble(membrane_forces(y, faces, Dm_inv, area, const_stiffness)[2], faces, n)
    exact_y = torch.autograd.functional.hessian(lambda z: membrane_energy(z, faces, Dm_inv, area, k).sum(), y)
    assert rel_err(approx, exact_y.reshape(3 * n, 3 * n)) > 1e-3


def _arcsim_reference_hessian(x, faces, Dm_inv, area, k):
    """physics.cpp stretching_force, transcribed with its Kronecker-product matrices (numpy)."""
    out = []
    for f in range(faces.shape[0]):
        X = x[faces[f]].reshape(9).numpy()
        Y = Dm_inv[f].numpy()
        D = np.stack([-Y[0] - Y[1], Y[0], Y[1]])  # rows: corners, cols: (u, v)
        Du = np.kron(D[:, 0][None, :], np.eye(3))
        Dv = np.kron(D[:, 1][None, :], np.eye(3))
        fu, fv = Du @ X, Dv @ X
        G = 0.5 * np.array([[fu @ fu - 1, fu @ fv], [fu @ fv, fv @ fv - 1]])
        k0, k1, k2, k3 = k[f].numpy()
        fuu, fvv, fuv = Du.T @ fu, Dv.T @ fv, (Du.T @ fv + Dv.T @ fu) / 2
        hess = (
            k0 * (np.outer(fuu, fuu) + max(G[0, 0], 0) * Du.T @ Du)
            + k2 * (np.outer(fvv, fvv) + max(G[1, 1], 0) * Dv.T @ Dv)
            + k1 * (np.outer(fuu, fvv) + max(G[0, 0], 0) * Dv.T @ Dv + np.outer(fvv, fuu) + max(G[1, 1], 0) * Du.T @ Du)
            + 2 * k3 * np.outer(fuv, fuv)
        )
        grad = k0 * G[0, 0] * fuu + k2 * G[1, 1] * fvv + k1 * (G[0, 0] * fvv + G[1, 1] * fuu) + 2 * k3 * G[0, 1] * fuv
        out.append((area[f].item() * grad, area[f].item() * hess))
    return torch.tensor(np.stack([g for g, _ in out])), torch.tensor(np.stack([h for _, h in out]))


@pytest.mark.parametrize("case", range(len(DEFORMATIONS)))
def test_membrane_matches_arcsim_matrix_formulas(case):
    uv, faces = grid(4)
    Dm_inv, area = rest_state(uv, faces)
    x = deformed(uv, case, **DEFORMATIONS[case])
    _, grad, hess = membrane_forces(x, faces, Dm_inv, area, smooth_stiffness)
    k = smooth_stiffness(membrane_strain(x, faces, Dm_inv))
    ref_grad, ref_hess = _arcsim_reference_hessian(x, faces, Dm_inv, area, k)
    assert rel_err(grad, ref_grad) < 1e-12
    assert rel_err(hess, ref_hess) < 1e-12


def test_membrane_stiffness_parameter_gradient_flows():
    uv, faces = grid(4)
    Dm_inv, area = rest_state(uv, faces)
    x = deformed(uv, 2, **DEFORMATIONS[2])

    def total(scale: torch.Tensor) -> torch.Tensor:
        energy, grad, hess = membrane_forces(x, faces, Dm_inv, area, lambda G: scale * smooth_stiffness(G))
        return energy.sum() + 0.1 * grad.square().sum() + 1e-3 * hess.sum()

    s = torch.tensor(1.3, dtype=F64, requires_grad=True)
    (auto,) = torch.autograd.grad(total(s), s)
    eps = 1e-6
    with torch.no_grad():
        fd = (total(s + eps) - total(s - eps)) / (2 * eps)
    assert auto.item() == pytest.approx(fd.item(), rel=1e-6)


def test_membrane_outputs_differentiable_in_positions():
    """Autograd through membrane_forces' energy includes dk/dG (k from a smooth stiffness_fn)."""
    uv, faces = grid(3)
    Dm_inv, area = rest_state(uv, faces)
    x = deformed(uv, 1, **DEFORMATIONS[1]).requires_grad_(True)
    (auto,) = torch.autograd.grad(membrane_forces(x, faces, Dm_inv, area, smooth_stiffness)[0].sum(), x)

    def energy(y):
        return (area * 0.5 * _density(membrane_strain(y, faces, Dm_inv))).sum()

    def _density(G):
        k = smooth_stiffness(G)
        Guu, Gvv, Guv = G.unbind(1)
        return k[:, 0] * Guu**2 + 2 * k[:, 1] * Guu * Gvv + k[:, 2] * Gvv**2 + 2 * k[:, 3] * Guv**2

    fd = central_difference(energy, x.detach(), 1e-6).reshape(-1, 3)
    assert rel_err(auto, fd) < 1e-6


# --------------------------------------------------------------------------- bending


def two_triangle_hinge(height: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    x = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.5, -1.0, height]], dtype=F64)
    faces = torch.tensor([[0, 1, 2], [1, 0, 3]])
    return x, faces, build_hinges(faces)


def test_dihedral_angle_sign_convention():
    """ARCSim: e = unit(x0 - x1); raising the second wing towards +n0 gives +atan(h)."""
    x, _, hinges = two_triangle_hinge(0.0)
    assert hinges.tolist() == [[0, 1, 2, 3]]
    assert dihedral_angle(x, hinges).item() == 0.0
    for h in (0.3, 1.0, -0.7):
        x, _, hinges = two_triangle_hinge(h)
        assert dihedral_angle(x, hinges).item() == pytest.approx(math.atan(h), abs=1e-14)
    # a folded grid: vertices with u > mid lifted along +n -> positive angles on the fold line only
    uv, faces = grid(5, 0.4)
    hinges = build_hinges(faces)
    x = torch.cat([uv, torch.zeros(uv.shape[0], 1, dtype=F64)], dim=1)
    assert dihedral_angle(x, hinges).abs().max() == 0.0
    lift = (uv[:, 0] - 0.2).clamp_min(0.0)
    theta = dihedral_angle(x + torch.stack([0 * lift, 0 * lift, lift], 1), hinges)
    on_fold = (uv[hinges[:, 0], 0] == 0.2) & (uv[hinges[:, 1], 0] == 0.2)
    assert torch.allclose(theta[on_fold], torch.full_like(theta[on_fold], math.pi / 4))
    assert theta[~on_fold].abs().max() < 1e-12


def test_dihedral_angle_unwraps_against_reference():
    x, _, hinges = two_triangle_hinge(0.0)
    x[3] = torch.tensor([0.5, 0.3, 0.05], dtype=F64)  # wing folded almost onto face 0
    assert dihedral_angle(x, hinges).item() == pytest.approx(math.pi - math.atan2(0.05, 0.3), abs=1e-12)
    x[3, 2] = -0.05  # folded past pi: the raw angle wraps to near -pi
    raw = dihedral_angle(x, hinges)
    assert raw.item() == pytest.approx(-math.pi + math.atan2(0.05, 0.3), abs=1e-12)
    ref = torch.tensor([3.0], dtype=F64)
    assert dihedral_angle(x, hinges, ref).item() == pytest.approx(raw.item() + 2 * math.pi, abs=1e-12)
    rest = raw + 2 * math.pi  # a rest shape folded past pi
    args = (hinges, rest, torch.ones(1, dtype=F64), torch.ones(1, 2, dtype=F64), const_bending)
    assert bending_forces(x, *args)[0].item() > 1e-5  # without unwrapping: 2 pi away from rest
    for xin in (x, x.clone().requires_grad_(True)):  # numba and torch paths
        energy, grad, _ = bending_forces(xin, *args, reference_theta=ref)
        assert energy.item() < 1e-25 and grad.abs().max() < 1e-12


def _bending_case(case: int):
    uv, faces = grid(4)
    hinges = build_hinges(faces)
    data = hinge_rest_data(None, uv, faces, hinges)
    x = deformed(uv, case, **DEFORMATIONS[case])
    x = x + torch.stack([0 * uv[:, 0], 0 * uv[:, 0], 0.05 * torch.cos(9 * uv[:, 0] - 4 * uv[:, 1])], 1)
    rest = 0.1 * torch.sin(torch.arange(hinges.shape[0], dtype=F64))
    return x, hinges, rest, data


@pytest.mark.parametrize("case", range(len(DEFORMATIONS)))
@pytest.mark.parametrize("stiffness_fn", [const_bending, smooth_bending])
def test_bending_gradient_matches_finite_differences(case, stiffness_fn):
    x, hinges, rest, data = _bending_case(case)
    area_sum, edge_dir = data["area_sum"], data["edge_dir_uv"]
    energy, grad, hess = bending_forces(x, hinges, rest, area_sum, edge_dir, stiffness_fn)
    theta = dihedral_angle(x, hinges)
    l0 = (x[hinges[:, 1]] - x[hinges[:, 0]]).norm(dim=1)
    ke = stiffness_fn(theta * l0 / (2 * area_sum), edge_dir)
    assert torch.allclose(energy, bending_energy(x, hinges, rest, area_sum, ke), rtol=1e-13, atol=0)

    def frozen(y):  # ke and l held constant, as ARCSim's force
        return (ke * l0**2 * (dihedral_angle(y, hinges) - rest) ** 2 / (8 * area_sum)).sum()

    n = x.shape[0]
    fd = central_difference(frozen, x, 1e-7).reshape(n, 3)
    assert rel_err(scatter_grad(grad, hinges, n), fd) < 1e-6
    # Gauss-Newton Hessian == ke l^2 / (4 (A0 + A1)) * outer(dtheta, dtheta), dtheta from autograd
    dtheta = torch.autograd.functional.jacobian(lambda y: dihedral_angle(y, hinges), x)  # [H, n, 3]
    dtheta = torch.stack([dtheta[h, hinges[h]].reshape(12) for h in range(hinges.shape[0])])
    coeff = ke * l0**2 / (4 * area_sum)
    assert rel_err(grad, coeff[:, None] * (theta - rest)[:, None] * dtheta) < 1e-10
    assert rel_err(hess, coeff[:, None, None] * dtheta[:, :, None] * dtheta[:, None, :]) < 1e-10
    assert_psd(hess)


@pytest.mark.parametrize("case", range(len(DEFORMATIONS)))
def test_bending_numba_and_torch_paths_agree(case):
    x, hinges, rest, data = _bending_case(case)
    args = (hinges, rest, data["area_sum"], data["edge_dir_uv"], smooth_bending)
    fast = bending_forces(x, *args)
    slow = bending_forces(x.clone().requires_grad_(True), *args)
    for a, b in zip(fast, slow):
        assert rel_err(a, b.detach()) < 1e-12
    buf = torch.empty_like(fast[2])
    again = bending_forces(x, *args, hess_out=buf)
    assert again[2] is buf and torch.equal(buf, fast[2])


@pytest.mark.parametrize("case", range(len(DEFORMATIONS)))
def test_bending_hessians_added_from_their_rank_one_factors_are_the_written_ones(case):
    """The assembly adds c dtheta dtheta^T into the blocks from its factors: the same bits
    as writing every hinge's 12x12 Hessian and adding that."""
    from tryon.sim.forces.bending import bending_forces_rank_one
    from tryon.sim.linear import BlockPattern, scatter_element_blocks, scatter_rank_one_blocks

    x, hinges, rest, data = _bending_case(case)
    args = (hinges, rest, data["area_sum"], data["edge_dir_uv"], smooth_bending)
    energy, grad, hess = bending_forces(x, *args)
    energy1, grad1, coeff, dtheta = bending_forces_rank_one(x, *args)
    assert np.array_equal(energy.numpy(), energy1) and np.array_equal(grad.numpy(), grad1)
    h = hinges.numpy()
    pattern = BlockPattern(x.shape[0], [h])
    written, factored = pattern.zeros(), pattern.zeros()
    scatter_element_blocks(written, pattern.element_maps[0], np.ascontiguousarray(hess.numpy()), 4)
    scatter_rank_one_blocks(factored, pattern.element_maps[0], coeff, dtheta, 4)
    assert np.abs(written).max() > 0 and np.array_equal(written, factored)
    with pytest.raises(ValueError, match="no_grad"):
        bending_forces_rank_one(x.clone().requires_grad_(True), *args)
    with pytest.raises(ValueError, match="CPU float64"):
        bending_forces_rank_one(x.float(), *args)


def test_bending_stiffness_sees_signed_alpha_and_rest_shape_is_unstressed():
    x, _, hinges = two_triangle_hinge(1.0)
    uv = x[:, :2].clone()
    faces = torch.tensor([[0, 1, 2], [1, 0, 3]])
    data = hinge_rest_data(None, uv, faces, hinges)
    seen = {}

    def recording(alpha, edge_dir_uv):
        seen["alpha"], seen["dir"] = alpha.clone(), edge_dir_uv.clone()
        return torch.full_like(alpha, 1e-4)

    bending_forces(x, hinges, data["rest_theta"], data["area_sum"], data["edge_dir_uv"], recording)
    # theta = pi/4, l = 1, A0 + A1 = 0.5 + 0.5 (uv areas)
    assert seen["alpha"].item() == pytest.approx((math.pi / 4) * 1.0 / 2.0, rel=1e-12)
    assert seen["dir"].tolist() == [[1.0, 0.0]]
    x_down, _, _ = two_triangle_hinge(-1.0)
    bending_forces(x_down, hinges, data["rest_theta"], data["area_sum"], data["edge_dir_uv"], recording)
    assert seen["alpha"].item() < 0
    rest = hinge_rest_data(x, uv, faces, hinges)
    energy, grad, _ = bending_forces(x, hinges, rest["rest_theta"], rest["area_sum"], rest["edge_dir_uv"], recording)
    assert energy.abs().max() < 1e-20 and grad.abs().max() < 1e-16


def test_bending_stiffness_parameter_gradient_flows():
    x, hinges, rest, data = _bending_case(2)

    def total(scale):
        e, g, h = bending_forces(x, hinges, rest, data["area_sum"], data["edge_dir_uv"],
                                 lambda a, d: scale * smooth_bending(a, d))
        return e.sum() + 1e3 * g.square().sum() + h.sum()

    s = torch.tensor(0.8, dtype=F64, requires_grad=True)
    (auto,) = torch.autograd.grad(total(s), s)
    with torch.no_grad():
        fd = (total(s + 1e-6) - total(s - 1e-6)) / 2e-6
    assert auto.item() == pytest.approx(fd.item(), rel=1e-6)


# --------------------------------------------------------------------------- wind


def test_wind_force_single_triangle_matches_formula():
    x = torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.5]], dtype=F64)
    v = torch.tensor([[0.1, 0.0, 0.2], [0.0, -0.3, 0.1], [0.2, 0.1, 0.0]], dtype=F64)
    faces = torch.tensor([[0, 1, 2]])
    area = torch.tensor([0.8], dtype=F64)  # material area, not the world area
    wind, rho, drag = torch.tensor([3.0, -1.0, 2.0], dtype=F64), 1.2, 0.4
    xs, vs = x.numpy(), v.numpy()
    n = np.cross(xs[1] - xs[0], xs[2] - xs[0])
    n /= np.linalg.norm(n)
    rel = wind.numpy() - vs.mean(axis=0)
    vn = rel @ n
    expected = (rho * 0.8 * abs(vn) * vn * n + drag * 0.8 * (rel - vn * n)) / 3.0
    for xin in (x, x.clone().requires_grad_(True)):  # numba and torch paths
        force, _ = wind_forces(xin, v, faces, area, wind, rho, drag)
        assert np.allclose(force.detach().numpy(), np.tile(expected, (3, 1)), rtol=1e-14, atol=1e-15)


def test_wind_damping_is_minus_velocity_jacobian_and_psd():
    uv, faces = grid(4)
    _, area = rest_state(uv, faces)
    x = deformed(uv, 3, **DEFORMATIONS[3])
    v = 0.5 * torch.randn(x.shape, generator=torch.Generator().manual_seed(0), dtype=F64)
    wind, rho, drag = torch.tensor([2.0, 0.5, -1.5], dtype=F64), 1.2, 0.3
    force, damping = wind_forces(x, v, faces, area, wind, rho, drag)
    n = x.shape[0]
    fd = central_difference(lambda w: wind_forces(x, w, faces, area, wind, rho, drag, False)[0].reshape(-1), v, 1e-6)
    assert rel_err(-assemble(damping, faces, n), fd) < 1e-7
    assert_psd(damping)
    force_t, damping_t = wind_forces(x, v.clone().requires_grad_(True), faces, area, wind, rho, drag)
    assert rel_err(force, force_t.detach()) < 1e-13 and rel_err(damping, damping_t.detach()) < 1e-13


def test_wind_rejects_bad_parameters():
    uv, faces = grid(3)
    _, area = rest_state(uv, faces)
    x = torch.cat([uv, torch.zeros(uv.shape[0], 1, dtype=F64)], 1)
    with pytest.raises(SceneError, match="air density"):
        wind_forces(x, x, faces, area, torch.zeros(3, dtype=F64), -1.0, 0.0)
    with pytest.raises(SceneError, match="wind velocity"):
        wind_forces(x, x, faces, area, torch.zeros(2, dtype=F64), 1.0, 0.0)


# --------------------------------------------------------------------------- fabric integration


def test_forces_with_measured_gray_interlock():
    fabric_module = pytest.importorskip("tryon.fabric")
    fabric = fabric_module.WangFabric.from_preset("gray-interlock")
    uv, faces = grid(5, 0.2)
    Dm_inv, area = rest_state(uv, faces)
    hinges = build_hinges(faces)
    data = hinge_rest_data(None, uv, faces, hinges)
    x = deformed(uv, 2, **DEFORMATIONS[2])
    energy, grad, hess = membrane_forces(x, faces, Dm_inv, area, fabric.stretching_stiffness)
    k = fabric.stretching_stiffness(membrane_strain(x, faces, Dm_inv))
    xg = x.clone().requires_grad_(True)
    (auto,) = torch.autograd.grad(membrane_energy(xg, faces, Dm_inv, area, k.detach()).sum(), xg)
    assert rel_err(scatter_grad(grad, faces, x.shape[0]), auto) < 1e-12
    assert_psd(hess)
    e_b, g_b, h_b = bending_forces(x, hinges, data["rest_theta"], data["area_sum"], data["edge_dir_uv"],
                                   fabric.bending_stiffness)
    assert bool(torch.isfinite(g_b).all()) and e_b.sum() > 0
    assert_psd(h_b)
