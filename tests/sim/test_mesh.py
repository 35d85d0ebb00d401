import numpy as np
import pytest
import torch

from tryon.errors import MeshError
from tryon.sim.mesh import ClothMesh, grid_corner, grid_mesh, mesh_from_obj


def test_grid_shapes_and_material_coords():
    m = grid_mesh((5, 4), size=(1.0, 0.6))
    assert m.num_vertices == 20
    assert m.num_faces == 2 * 4 * 3
    assert torch.allclose(m.uv.max(0).values, torch.tensor([1.0, 0.6], dtype=torch.float64))
    # horizontal grid: world x,y equal material u,v
    assert torch.allclose(m.x[:, :2], m.uv)
    # Euler characteristic of a disc: V - E + F = 1
    assert m.num_vertices - len(m.edges) + m.num_faces == 1


def test_grid_corners():
    m = grid_mesh((4, 3), size=(1.0, 1.0))
    assert torch.allclose(m.uv[grid_corner((4, 3), "top-left")], torch.tensor([0.0, 1.0], dtype=torch.float64))
    assert torch.allclose(m.uv[grid_corner((4, 3), "top-right")], torch.tensor([1.0, 1.0], dtype=torch.float64))
    with pytest.raises(MeshError, match="unknown grid corner"):
        grid_corner((4, 3), "middle")


def test_rejects_nan():
    m = grid_mesh((3, 3))
    x = m.x.clone()
    x[4, 2] = float("nan")
    with pytest.raises(MeshError, match="vertex 4"):
        ClothMesh(x, m.uv, m.faces)


def test_rejects_zero_area_face():
    x = torch.tensor([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]], dtype=torch.float64)
    uv = torch.tensor([[0, 0], [1, 0], [0, 1.0]], dtype=torch.float64)
    with pytest.raises(MeshError, match="zero world area"):
        ClothMesh(x, uv, torch.tensor([[0, 1, 2]]))
    uv_bad = torch.tensor([[0, 0], [1, 0], [2, 0.0]], dtype=torch.float64)
    x_ok = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]], dtype=torch.float64)
    with pytest.raises(MeshError, match="zero material"):
        ClothMesh(x_ok, uv_bad, torch.tensor([[0, 1, 2]]))


def test_rejects_non_manifold_edge():
    x = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1.0]], dtype=torch.float64)
    uv = x[:, :2] + torch.tensor([0.0, 0.0]) + x[:, 2:3] * torch.tensor([0.3, 0.7], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(MeshError, match="non-manifold"):
        ClothMesh(x, uv, faces)


def test_rejects_missing_uv():
    m = grid_mesh((3, 3))
    with pytest.raises(MeshError, match="material coordinates"):
        ClothMesh(m.x, m.uv[:-1], m.faces)


def test_obj_without_vt_is_refused(tmp_path):
    p = tmp_path / "novt.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match="no 'vt'"):
        mesh_from_obj(p)


def test_obj_with_vt_loads(tmp_path):
    p = tmp_path / "tri.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    m = mesh_from_obj(p)
    assert m.num_faces == 1
    np.testing.assert_allclose(m.uv.numpy(), [[0, 0], [1, 0], [0, 1]])
