"""The coarse level's decimated obstacle proxy and detail recovery measured on its own
(from the serial run's exact coarse-scale states)."""

import numpy as np
import pytest

from tryon.errors import SceneError
from tryon.parallel.curvature import relative_curvature_error
from tryon.parallel.proxy import cluster_decimate, coarse_obstacles, crop_obstacle, excess_outside, proxy_obstacle
from tryon.parallel.recovery import oracle_recovery_errors
from tryon.parallel.hierarchy import build_hierarchy
from tryon.sim.geometry import nearest_surface_points
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.obstacles import Motion, sphere
from tryon.sim.scene import example_scene


def _moving_sphere():
    ob = sphere([0.0, 0.0, 0.0], 0.3, subdivisions=5)
    frames = np.stack([ob.rest_vertices + [0.05 * k, 0.0, 0.02 * k] for k in range(4)])
    ob.motion = Motion(keyframes=frames, keyframe_times=np.arange(4) * 0.1)
    return ob


def test_cluster_decimation_drops_collapsed_triangles():
    ob = sphere([0, 0, 0], 0.3, subdivisions=4)
    C, faces = cluster_decimate(ob.rest_vertices, ob.faces, 0.06)
    assert C.shape[1] == len(ob.rest_vertices) and C.shape[0] < len(ob.rest_vertices) / 4
    assert np.allclose(np.asarray(C.sum(1)).ravel(), 1.0)
    assert faces.max() < C.shape[0] and np.all(faces[:, 0] != faces[:, 1]) and np.all(faces[:, 1] != faces[:, 2])
    with pytest.raises(SceneError):
        cluster_decimate(ob.rest_vertices, ob.faces, 0.0)


def test_proxy_encloses_the_moving_obstacle_and_stays_near_it():
    ob = _moving_sphere()
    proxy, info = proxy_obstacle(ob, 0.05)
    assert info["faces"] < len(ob.faces) / 8 and 0 < info["offset_m"] < 0.05
    for k, t in enumerate((0.0, 0.15, 0.3)):
        body, p = ob.vertices_at(t), proxy.vertices_at(t)
        d = excess_outside(p[None], proxy.faces, body[None])
        assert np.mean(d <= 0) >= 0.995 and d.max() < 2e-3  # the body lies inside the proxy
        centre = body.mean(0)
        r = np.linalg.norm(p - centre, axis=1)
        assert r.min() > 0.3 - 1e-3 and r.max() < 0.3 + info["offset_m"] + 1e-3
        # a point just outside the proxy is outside the real sphere
        ds, _, _ = nearest_surface_points(p + 0.001 * (p - centre) / r[:, None], body, ob.faces)
        assert ds.min() > 0
    small = sphere([0, 0, 0], 0.1, subdivisions=1)
    kept, infos = coarse_obstacles([small, ob], 0.05)
    assert kept[0] is small and kept[1].name == "sphere-proxy" and len(infos) == 1


def test_crop_keeps_the_obstacle_near_the_cloth_unchanged_at_every_keyframe():
    ob = _moving_sphere()
    cloth = np.array([[0.0, 0.0, 0.35], [0.1, 0.0, 0.34], [0.0, 0.1, 0.34]])  # above the top of the sphere
    near, info = crop_obstacle(ob, cloth, reach=0.15)
    assert 0 < info["faces"] < len(ob.faces) / 4 and info["cropped"]
    for t in (0.0, 0.15, 0.3):
        full, part = ob.vertices_at(t), near.vertices_at(t)
        tri = part[near.faces]
        # every kept triangle is one of the obstacle's, where it is at that time
        keys = {tuple(np.round(full[f].mean(0), 9)) for f in ob.faces}
        assert all(tuple(np.round(c, 9)) in keys for c in tri.mean(1))
    d, _, _ = nearest_surface_points(cloth, ob.vertices_at(0.0), ob.faces)
    dn, _, _ = nearest_surface_points(cloth, near.vertices_at(0.0), near.faces)
    assert np.allclose(d, dn)  # the cloth's collisions see the same surface
    kept, infos = coarse_obstacles([ob], "crop", near=cloth)
    assert kept[0].name == "sphere-near" and infos[0]["faces"] < len(ob.faces)  # CROP_REACH
    with pytest.raises(SceneError, match="no part of it lies within"):
        crop_obstacle(ob, cloth + 5.0)


def test_recovery_restores_fine_detail_from_exact_coarse_states():
    scene = example_scene("sphere-drop", 13, duration=1.0)
    h = build_hierarchy(scene, "coarsen")
    solver = ImplicitEulerSolver(h.fine.model, h.fine.options)
    state = h.fine.model.initial_state()
    xs = [state.x.numpy()]
    for _ in range(26):
        state, _ = solver.step(state, h.fine.dt)
        xs.append(state.x.numpy())
    errs = oracle_recovery_errors(solver, h, np.stack(xs), 25)
    assert errs["after"] < 0.8 * errs["before"]
    assert errs["before"] == pytest.approx(relative_curvature_error(h.fine.model, h.upsample(h.restrict(xs[25])), xs[25]),
                                           rel=0.3)


def test_recovery_moves_are_collision_handled():
    """`collision_free_move`, which recovery uses for its tracking projections: a patch of
    a folded cloth's upper layer poked through the lower one, and the cloth pushed into
    the sphere, end with neither layer nor body passed through."""
    from tryon.parallel.recovery import collision_free_move, obstacle_crossings, self_intersecting_vertices

    h = build_hierarchy(example_scene("sphere-drop", 13, duration=0.1), "coarsen")
    solver = ImplicitEulerSolver(h.fine.model, h.fine.options)
    flat = h.fine.model.initial_state().x.numpy()  # 1 m square at z = 0.3 over a sphere of radius 0.25
    upper = flat[:, 0] > 1e-9
    folded = flat.copy()  # folded over along x = 0, the upper layer 6 cm above the lower one
    folded[upper, 0] = -flat[upper, 0]
    folded[upper, 2] += 0.06 * np.minimum(1.0, flat[upper, 0] / 0.15)
    assert len(self_intersecting_vertices(h, folded)) == 0
    patch = upper & (flat[:, 0] > 0.2) & (flat[:, 0] < 0.4) & (np.abs(flat[:, 1]) < 0.15)
    poked = folded.copy()
    poked[patch, 2] -= 0.08
    assert len(self_intersecting_vertices(h, poked)) > 0
    moved = collision_free_move(solver, folded, poked, 0.0, 0.0)
    assert moved is not None and len(self_intersecting_vertices(h, moved)) == 0
    below = np.array([np.argmin(np.linalg.norm(flat[:, :2] - folded[i, :2], axis=1)) for i in np.flatnonzero(patch)])
    assert np.all(moved[patch, 2] > moved[below, 2])  # the patch still lies on top of the lower layer
    pushed = flat - [0.0, 0.0, 0.06]
    assert obstacle_crossings(h, pushed, 0.0) > 0
    moved = collision_free_move(solver, flat, pushed, 0.0, 0.0)
    assert moved is not None and obstacle_crossings(h, moved, 0.0) == 0
