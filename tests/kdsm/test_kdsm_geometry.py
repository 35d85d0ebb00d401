"""The KDSM's geometry: the volume covers the air around the body and is closed, its
skinning is a proper blend of the body's, embedding a posed garment and reconstructing it
round-trips to round-off, the BVH finds exactly the parents brute force finds, and the
baseline's body-surface offsets invert exactly and do not change under rigid motion."""

import json
from pathlib import Path

import numpy as np
import pytest

from tryon.kdsm import SurfaceBinding, build_volume, embed, find_parents, pose_quality, reconstruct, skin_volume
from tryon.kdsm.embed import find_parents_brute, smooth_offsets, tet_barycentric
from tryon.kdsm.volume import CUBE_TETS, tet_volumes

pytestmark = [pytest.mark.anny]

DATA = Path(__file__).resolve().parents[2] / "data" / "tshirt-v1"


@pytest.fixture(scope="module")
def scene():
    from tryon.body.anny_model import ShapeParams, body_model
    from tryon.body.pose import named_pose, posed_body
    from tryon.drape.dress import DressedGarment
    from tryon.kdsm.skinning import bone_transforms_np

    params = ShapeParams.from_dict(json.loads((DATA / "references" / "references.json").read_text())["female-M"]["params"])
    shape = body_model().rest_shape(params).detached()
    body = posed_body(shape, "a")
    garment = DressedGarment.load(DATA / "references" / "female-M.npz")
    x = garment.vertices
    volume = build_volume(body.vertices, body.faces, cell=0.025, inner=0.01, outer=0.1,
                          bounds=(x.min(0) - 0.05, x.max(0) + 0.05))
    G_a = bone_transforms_np(shape, named_pose(shape, "a"))
    skin = skin_volume(volume, body.vertices, body.faces, shape.weight_index, shape.weight, G_a)
    return {"shape": shape, "body": body, "garment": garment, "volume": volume, "skin": skin, "G_a": G_a,
            "G_t": bone_transforms_np(shape, named_pose(shape, "t"))}


def test_kuhn_cubes_fill_the_cube_with_six_positive_tets():
    corners = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], float)
    vol = tet_volumes(corners, CUBE_TETS)
    assert np.allclose(np.abs(vol), 1 / 6) and np.abs(vol).sum() == pytest.approx(1.0)


def test_the_volume_covers_the_band_around_the_body_and_is_closed(scene):
    from tryon.sim.geometry import signed_obstacle_distance

    volume, body, x = scene["volume"], scene["body"], scene["garment"].vertices
    assert (volume.signed_volumes() > 0).all()
    # every point of the band [-inner, outer] within the bounds lies in a tet
    rng = np.random.default_rng(0)
    lo, hi = x.min(0) - 0.05, x.max(0) + 0.05
    pts = rng.uniform(lo, hi, (20000, 3))
    d = signed_obstacle_distance(pts, body.vertices, body.faces)
    band = pts[(d >= -0.01) & (d <= 0.1)]
    assert len(band) > 2000
    assert (find_parents(band, volume.vertices, volume.tets).count(len(band)) >= 1).all()
    # so does the garment, with one parent each in the rest pose (tets do not overlap there)
    assert (find_parents(x, volume.vertices, volume.tets).count(len(x)) >= 1).all()
    # closed: every face of the tet mesh is shared by two tets or lies on a boundary surface
    # whose every edge is shared by exactly two boundary triangles
    faces = np.sort(np.concatenate([volume.tets[:, [a, b, c]] for a, b, c in ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3))]), 1)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    assert count.max() == 2
    boundary = uniq[count == 1]
    edges = np.sort(np.concatenate([boundary[:, [0, 1]], boundary[:, [1, 2]], boundary[:, [0, 2]]]), 1)
    _, edge_count = np.unique(edges, axis=0, return_counts=True)
    assert (edge_count % 2 == 0).all()


def test_volume_skinning_blends_the_bodys_weights(scene):
    from tryon.sim.geometry import nearest_surface_locations

    volume, skin, shape, body = scene["volume"], scene["skin"], scene["shape"], scene["body"]
    assert np.allclose(skin.weight.sum(1), 1.0) and (skin.weight >= 0).all()
    # in its own pose the volume does not move
    assert np.abs(skin.pose(volume.vertices, scene["G_a"]) - volume.vertices).max() < 1e-9
    # one rigid motion of every bone moves the volume rigidly
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, (0.1, -0.2, 0.3)
    moved = skin.pose(volume.vertices, M[None] @ scene["G_a"])
    assert np.abs(moved - (volume.vertices @ R.T + M[:3, 3])).max() < 1e-9
    # at the skin the weights are the body's own at the nearest skin point
    near = np.flatnonzero(np.abs(volume.distance) < 0.002)[:200]
    _, face, bary = nearest_surface_locations(volume.vertices[near], body.vertices, body.faces)
    J = len(shape.bone_labels)
    dense_body = np.zeros((len(shape.weight), J))
    np.put_along_axis(dense_body, shape.weight_index, shape.weight, 1)
    expect = np.einsum("nk,nkj->nj", bary, dense_body[body.faces[face]])
    got = np.zeros((len(near), J))
    np.put_along_axis(got, skin.index[near], skin.weight[near], 1)
    assert np.abs(got - expect).sum(1).max() < 0.05   # top-8 truncation only
    # raising the arms to a T keeps almost every tet the right way out
    q = pose_quality(volume, skin.pose(volume.vertices, scene["G_t"]), skin, shape)
    assert q["inverted_pct"] < 0.5 and q["median_volume_ratio"] == pytest.approx(1.0, abs=0.02)
    # arms out, their air stays clear of the torso's; arms straight down at the sides (45
    # degrees further in than the volume's A-pose), it runs into it
    from tryon.body.pose import arm_pose
    from tryon.kdsm.quality import tet_regions
    from tryon.kdsm.skinning import bone_transforms_np

    assert q["arm_tets"] > 1000 and q["arm_torso_overlap_pct"] < 0.5
    down = pose_quality(volume, skin.pose(volume.vertices, bone_transforms_np(shape, arm_pose(shape, 0.0))), skin, shape)
    assert down["arm_torso_overlap_pct"] > 5 * max(q["arm_torso_overlap_pct"], 0.2)
    region = tet_regions(volume, skin, shape)
    assert (region == 2).sum() > (region == 1).sum() > 0


def test_method1_embedding_round_trips_to_round_off(scene):
    volume, skin, x0 = scene["volume"], scene["skin"], scene["garment"].vertices
    x_t = reconstruct(x0, volume, skin, scene["G_t"])      # the drape carried to the T-pose by the volume
    posed = skin.pose(volume.vertices, scene["G_t"])
    e = embed(x_t, posed, volume, "method1")
    assert (e.parents >= 1).all()
    single = e.parents == 1
    assert np.abs(e.material[single] - x0[single]).max() < 1e-9      # one parent: the material point is unique
    back = reconstruct(e.material, volume, skin, scene["G_t"])
    assert np.abs(back - x_t).max() < 1e-9                            # any parent: the position comes back


def test_hybrid_and_method2_use_the_surface_offsets(scene):
    volume, skin, x0, body = scene["volume"], scene["skin"], scene["garment"].vertices, scene["body"]
    binding = SurfaceBinding.bind(x0, body.vertices, body.faces)
    posed = skin.pose(volume.vertices, scene["G_a"])
    # in the rest pose every method gives the rest drape's own material points
    m2 = binding.positions(binding.offsets(x0, body.vertices, body.faces), body.vertices, body.faces)
    assert np.abs(m2 - x0).max() < 1e-9
    for method in ("method1", "method2", "hybrid"):
        e = embed(x0, posed, volume, method, surface_material=m2)
        assert np.abs(e.material - x0).max() < 1e-6, method
    with pytest.raises(ValueError, match="unknown embedding"):
        embed(x0, posed, volume, "method3")


def test_bvh_parents_equal_brute_force(scene):
    volume = scene["volume"]
    rng = np.random.default_rng(3)
    centroid = volume.vertices[volume.tets].mean(1)
    near = np.argsort(np.linalg.norm(centroid - centroid[rng.integers(len(centroid))], axis=1))[:600]
    tets = volume.tets[near[rng.permutation(600)[:400]]]              # a cluster with holes
    lo, hi = volume.vertices[tets].reshape(-1, 3).min(0), volume.vertices[tets].reshape(-1, 3).max(0)
    pts = rng.uniform(lo, hi, (1500, 3))
    pts[:50] = volume.vertices[tets[:50, 0]]                          # on corners: several parents
    a = find_parents(pts, volume.vertices, tets)
    b = find_parents_brute(pts, volume.vertices, tets)
    assert len(a.point) > 100
    key = lambda p: set(zip(p.point.tolist(), p.tet.tolist()))      # noqa: E731
    assert key(a) == key(b)
    order_b = np.lexsort((b.tet, b.point))
    assert np.allclose(a.bary, b.bary[order_b])


def test_barycentric_coordinates_rebuild_the_point():
    rng = np.random.default_rng(1)
    corners = rng.standard_normal((50, 4, 3))
    w = rng.dirichlet(np.ones(4), 50)
    p = np.einsum("nk,nkd->nd", w, corners)
    assert np.allclose(tet_barycentric(p, corners), w)


def test_surface_offsets_invert_and_ignore_rigid_motion(scene):
    body, x0 = scene["body"], scene["garment"].vertices
    b = SurfaceBinding.bind(x0, body.vertices, body.faces)
    o = b.offsets(x0, body.vertices, body.faces)
    assert np.abs(b.positions(o, body.vertices, body.faces) - x0).max() < 1e-12
    assert np.median(o[:, 2]) > 0.0 and np.abs(o[:, :2]).max() < 0.1   # mostly along the normal, outside
    th = 0.7
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1.0]])
    t = np.array([0.3, -0.1, 0.2])
    o2 = b.offsets(x0 @ R.T + t, body.vertices @ R.T + t, body.faces)
    assert np.abs(o2 - o).max() < 1e-9


def test_screened_poisson_smoothing_keeps_constants_and_damps_noise():
    from tryon.sim.mesh import grid_mesh

    mesh = grid_mesh((20, 20), (1.0, 1.0))
    faces = mesh.faces.numpy()
    n = mesh.num_vertices
    const = np.tile([0.1, -0.2, 0.3], (n, 1))
    assert np.allclose(smooth_offsets(const, faces, 2.0), const)
    noise = np.random.default_rng(0).standard_normal((n, 3))
    assert smooth_offsets(noise, faces, 2.0).std() < 0.5 * noise.std()
