"""Two-level cloth hierarchies: subdivision and coarsening operators, restriction,
tracking projection, garment coarsening, and detail recovery (Algorithm 3)."""

import numpy as np
import pytest
import scipy.sparse as sp
import torch

from tryon.errors import SceneError, TryonError
from tryon.parallel.coarse import CoarseRun
from tryon.parallel.curvature import hinge_curvature, relative_curvature_error
from tryon.parallel.hierarchy import (
    build_hierarchy,
    coarsen_garment,
    embedding_operator,
    subdivide_mesh,
    subdivide_stitches,
)
from tryon.parallel.recovery import RecoveryOptions, iteration_limit, recover_details, stiffness_norm, upsampled_state
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.mesh import ClothMesh, grid_mesh
from tryon.sim.scene import example_scene


def _linear_field(uv: np.ndarray) -> np.ndarray:
    A = np.array([[0.3, -1.2, 2.0], [0.7, 0.4, -0.5]])
    return uv @ A + np.array([0.1, -0.2, 0.3])


def test_subdivision_reproduces_linear_fields_and_refines_the_rest_shape():
    coarse = grid_mesh((5, 4), (1.0, 0.6))
    fine, U = subdivide_mesh(coarse)
    assert fine.num_faces == 4 * coarse.num_faces
    assert fine.num_vertices == coarse.num_vertices + coarse.edges.shape[0]
    assert np.allclose(np.asarray(U.sum(1)).ravel(), 1.0)
    uv_c, uv_f = coarse.uv.numpy(), fine.uv.numpy()
    assert np.allclose(U @ _linear_field(uv_c), _linear_field(uv_f), atol=1e-12)
    assert np.allclose(U @ coarse.x.numpy(), fine.x.numpy())

    def area(m: ClothMesh) -> float:
        c = m.corner_uv().numpy()
        d1, d2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
        return float(0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).sum())

    assert area(fine) == pytest.approx(area(coarse))
    # orientation kept: every fine face's material normal points the same way
    c = fine.corner_uv().numpy()
    cross = (c[:, 1, 0] - c[:, 0, 0]) * (c[:, 2, 1] - c[:, 0, 1]) - (c[:, 1, 1] - c[:, 0, 1]) * (c[:, 2, 0] - c[:, 0, 0])
    assert np.all(np.sign(cross) == np.sign(cross[0]))


def test_subdivided_stitches_pair_the_midpoints_of_stitched_edges():
    # two triangles (0,1,2) and (3,4,5) whose edges 0-1 and 3-4 are sewn together
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1), axis=0)
    st = subdivide_stitches(np.array([[0, 3], [1, 4]]), edges, 6)
    e01 = int(np.nonzero((edges == [0, 1]).all(1))[0][0])
    e34 = int(np.nonzero((edges == [3, 4]).all(1))[0][0])
    assert st.tolist()[:2] == [[0, 3], [1, 4]]
    assert sorted(st[2].tolist()) == sorted([6 + e01, 6 + e34]) and len(st) == 3


def test_coarsened_grid_embedding_is_exact_for_linear_fields():
    scene = example_scene("hanging", 17)
    h = build_hierarchy(scene, "coarsen", factor=2.0)
    assert h.fine is scene and h.coarse.model.num_vertices == 81
    U = h.U
    assert U.shape == (289, 81)
    assert np.allclose(np.asarray(U.sum(1)).ravel(), 1.0) and U.min() >= 0
    assert np.diff(U.indptr).max() <= 3
    uv_c, uv_f = h.coarse.model.mesh.uv.numpy(), scene.model.mesh.uv.numpy()
    assert np.allclose(U @ _linear_field(uv_c), _linear_field(uv_f), atol=1e-12)
    assert np.allclose(h.upsample(h.coarse.model.mesh.x.numpy()), scene.model.mesh.x.numpy())
    # pins by corner name land on the same corners
    assert np.allclose(h.coarse.model.pin_targets(0.0).numpy(), scene.model.pin_targets(0.0).numpy())


def test_restriction_inverts_upsampling_and_tracking_hits_its_target():
    h = build_hierarchy(example_scene("sphere-drop", 13), "coarsen")
    rng = np.random.default_rng(0)
    Xc = rng.normal(size=(h.coarse.model.num_vertices, 3))
    assert np.allclose(h.restrict(h.upsample(Xc)), Xc)
    x = rng.normal(size=(h.fine.model.num_vertices, 3))
    target = rng.normal(size=Xc.shape)
    tracked = h.track(x, target)
    assert np.allclose(h.restrict(tracked), target)
    # the projection is mass-orthogonal: the fine detail it leaves is untouched
    detail = x - h.upsample(h.restrict(x))
    assert np.allclose(tracked - h.upsample(target), detail)


def test_subdivide_hierarchy_and_bad_requests():
    scene = example_scene("sphere-drop", 9)
    h = build_hierarchy(scene, "subdivide", dt_ratio=2)
    assert h.coarse.model is scene.model and h.fine.model.num_vertices > scene.model.num_vertices
    assert h.coarse.dt == pytest.approx(2 * h.fine.dt)
    with pytest.raises(SceneError, match="whole multiple"):
        build_hierarchy(scene, dt_ratio=0)
    with pytest.raises(SceneError, match="unknown hierarchy"):
        build_hierarchy(scene, "sideways")
    with pytest.raises(SceneError, match="too small"):
        build_hierarchy(example_scene("hanging", 3), "coarsen")
    other = grid_mesh((4, 4), (1.0, 1.0))
    far = grid_mesh((4, 4), (3.0, 3.0))
    with pytest.raises(SceneError, match="same pattern"):
        embedding_operator(other, far)


def test_garment_coarsening_welds_seams_and_embeds_per_pattern_piece():
    from tryon.garment.pattern import Edge, Panel, Pattern, Seam
    from tryon.garment.triangulate import merge_stitched, remesh_pattern, triangulate_pattern

    def panel(name: str) -> Panel:  # a 0.5 x 0.6 m panel with a curved hem
        return Panel(name, [Edge("side_l", [[0, 0.6], [0, 0]]), Edge("hem", [[0, 0], [0.2, -0.05], [0.3, -0.05], [0.5, 0]], "bezier"),
                            Edge("side_r", [[0.5, 0], [0.5, 0.6]]), Edge("top", [[0.5, 0.6], [0, 0.6]])])

    pattern = Pattern("tube", [panel("front"), panel("back")],
                      [Seam(("front", "side_r"), ("back", "side_l"), reverse=True),
                       Seam(("back", "side_r"), ("front", "side_l"), reverse=True)])
    gm = triangulate_pattern(pattern, 0.04)
    back = gm.panel_of_vertex == 1  # an envelope: the back folded behind the front, sides sewn
    u, v = gm.points2d[:, 0], gm.points2d[:, 1]
    placed = np.stack([np.where(back, 0.5 - u, u), np.where(back, 0.05, 0.0), v], 1)
    pos, faces, corner_uv, _ = merge_stitched(gm, placed)
    uv = np.zeros((len(pos), 2))
    uv[faces.reshape(-1)] = corner_uv.reshape(-1, 2)
    panel = gm.panel_of_vertex[gm.faces[:, 0]]
    fine = ClothMesh(torch.from_numpy(pos), torch.from_numpy(uv), torch.from_numpy(faces), "skirt",
                     face_uv=torch.from_numpy(corner_uv))
    coarse, coarse_panel = coarsen_garment(fine, panel, remesh_pattern(pattern, 0.08))
    assert coarse.num_vertices < fine.num_vertices / 2.5
    U = embedding_operator(coarse, fine, coarse_panel, panel)
    assert np.allclose(np.asarray(U.sum(1)).ravel(), 1.0)
    # coarse vertices sit on the fine garment; upsampling them gives it back to a coarse edge
    err = np.linalg.norm(U @ coarse.x.numpy() - fine.x.numpy(), axis=1)
    assert err.max() < 0.03 and np.median(err) < 1e-6
    # every coarse vertex drives some fine vertex: the restriction exists
    assert np.all(np.asarray((U != 0).sum(0)).ravel() > 0)
    assert sp.linalg.norm(U.T @ U - (U.T @ U).T) < 1e-12


def test_iteration_limit_is_c0_sqrt_m_over_xi_over_dt():
    scene = example_scene("hanging", 9)
    fab = scene.model.fabric
    n = iteration_limit(fab, 0.01, 10.0)
    assert n == int(np.ceil(10.0 * np.sqrt(float(fab.density) / stiffness_norm(fab)) / 0.01))
    assert iteration_limit(fab, 0.005, 10.0) >= 2 * n - 1
    with pytest.raises(TryonError):
        RecoveryOptions(c0=-1.0).validate()


def _boundary_states(name: str, res: int, step: int):
    scene = example_scene(name, res, duration=1.0)
    h = build_hierarchy(scene, "coarsen")
    coarse = CoarseRun(h)
    while coarse.position < step + 1:
        coarse.advance()
    solver = ImplicitEulerSolver(h.fine.model, h.fine.options)
    state = h.fine.model.initial_state()
    for _ in range(step):
        state, _ = solver.step(state, h.fine.dt)
    return h, solver, coarse.start_pair(step), state.x.numpy()


def test_detail_recovery_converges_keeps_the_coarse_shape_and_reduces_popping():
    step = 40
    h, solver, (start, nxt), x_serial = _boundary_states("hanging", 17, step)
    t = step * h.fine.dt
    before = upsampled_state(h, *start, t).x.numpy()
    state, report = recover_details(solver, h, start, nxt, t, h.fine.dt)
    assert report.converged and 1 <= report.iterations < report.limit
    assert report.changes[-1] < 1e-3 * h.fine.model.mesh.size()
    x = state.x.numpy()
    # the coarse-scale shape stays on the coarse trajectory (to the pinned corners' correction)
    assert np.abs(h.restrict(x) - start[0]).max() < 5e-3
    assert not np.allclose(x, before)
    e_before = relative_curvature_error(h.fine.model, before, x_serial)
    e_after = relative_curvature_error(h.fine.model, x, x_serial)
    assert e_after < 0.85 * e_before
    disabled, rep0 = recover_details(solver, h, start, nxt, t, h.fine.dt, RecoveryOptions(enabled=False))
    assert rep0.iterations == 0 and np.allclose(disabled.x.numpy(), before)


def test_curvature_error_is_zero_for_identical_states_and_positive_otherwise():
    scene = example_scene("hanging", 9)
    m = scene.model
    rng = np.random.default_rng(1)
    x = m.mesh.x.numpy() + rng.normal(scale=0.01, size=(m.num_vertices, 3))
    assert relative_curvature_error(m, x, x) == 0.0
    assert relative_curvature_error(m, m.mesh.x.numpy() + 0.5 * (x - m.mesh.x.numpy()), x) > 0.1
    assert hinge_curvature(m, m.mesh.x.numpy()) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(TryonError, match="flat"):
        relative_curvature_error(m, x, m.mesh.x.numpy())
