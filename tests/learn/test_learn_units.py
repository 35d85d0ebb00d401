"""The draping network's parts on small inputs: losses, graph convolution, skin prior."""

import numpy as np
import torch

from tryon.learn.features import SkinPrior
from tryon.sim.geometry import area_vertex_normals
from tryon.learn.losses import closest_split, deformation_gradients, uniform_laplacian
from tryon.learn.network import GraphConv


def test_closest_split_picks_the_nearest_candidate():
    rng = np.random.default_rng(0)
    body = torch.from_numpy(rng.normal(size=(1, 50, 3)).astype(np.float32))
    normals = torch.nn.functional.normalize(body, dim=-1)
    x = torch.from_numpy(rng.normal(size=(1, 7, 3)).astype(np.float32))
    cand = torch.from_numpy(np.tile(np.arange(50), (1, 7, 1)))
    c, d, n = closest_split(x, body, normals, cand)
    brute = torch.cdist(x[0], body[0]).argmin(1)
    assert torch.equal(c[0], body[0, brute]) and torch.allclose(c + d, x) and torch.equal(n[0], normals[0, brute])


def test_rest_shape_has_identity_deformation_and_a_plane_no_laplacian():
    uv = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], float)
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    dm = np.stack([uv[faces[:, 1]] - uv[faces[:, 0]], uv[faces[:, 2]] - uv[faces[:, 0]]], -1)
    x = torch.from_numpy(np.c_[uv, np.zeros(4)])[None]
    F = deformation_gradients(x, torch.from_numpy(faces), torch.from_numpy(np.linalg.inv(dm)))
    assert torch.allclose(F, torch.tensor([[1.0, 0], [0, 1], [0, 0]], dtype=F.dtype).expand_as(F))
    edges = torch.tensor([[0, 1], [1, 2], [0, 2], [1, 3], [2, 3]])
    lap = uniform_laplacian(x, edges, 4)
    assert torch.allclose(lap[..., 2], torch.zeros(1, 4, dtype=lap.dtype))


def test_graph_convolution_sees_only_mesh_neighbours():
    edges = np.array([[0, 1], [1, 2], [2, 3]])
    conv = GraphConv(edges, 4, 2, 3)
    x = torch.zeros(1, 4, 2, requires_grad=True)
    conv(x)[0, 0].sum().backward()  # vertex 0 reads itself and vertex 1 only
    touched = x.grad[0].abs().sum(1) > 0
    assert touched.tolist() == [True, True, False, False]


def test_skin_prior_follows_the_skin():
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    x = np.array([[0.25, 0.25, 0.1], [0.7, 0.8, 0.05]])
    prior = SkinPrior.bind(x, verts, faces)
    assert np.allclose(prior.carry(verts), x)
    moved = verts + np.array([0.0, 0.0, 0.3])
    assert np.allclose(prior.carry(moved), x + [0, 0, 0.3])
    n = area_vertex_normals(verts, faces)
    assert np.allclose(np.abs(n[:, 2]), 1.0)
