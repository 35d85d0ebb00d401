"""Collision detection and response (tryon.sim.collision) against brute-force references,
dense time sampling and known answers."""

import numpy as np
import pytest
import torch
import trimesh

from tryon.errors import MeshError
from tryon.sim import collision as col
from tryon.sim import geometry as geo
from tryon.sim.collision import ccd
from tryon.sim.geometry import primitives as prim, threads as geometry_threads
from tryon.sim.geometry import BVH, overlapping_pairs

H = 0.005


# --------------------------------------------------------------------------- meshes
def edges_of(faces):
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, 1), axis=0)


def sheet(n, size=1.0, z=0.0, shift=(0.0, 0.0)):
    s = np.linspace(-size / 2, size / 2, n)
    X, Y = np.meshgrid(s + shift[0], s + shift[1], indexing="xy")
    x = np.stack([X.ravel(), Y.ravel(), np.full(n * n, float(z))], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int64)
    return x, faces, edges_of(faces)


def merge(*meshes):
    xs, fs, off = [], [], 0
    for x, f, _ in meshes:
        xs.append(x)
        fs.append(f + off)
        off += len(x)
    f = np.concatenate(fs)
    return np.concatenate(xs), f, edges_of(f)


def ground(size=2.0, z=0.0):
    x, f, e = sheet(5, size, z)
    return x, f, e  # counter-clockwise seen from +z: outward normal up


def ball(center, radius, subdivisions=2):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    f = np.asarray(m.faces, np.int64)
    return np.asarray(m.vertices) + np.asarray(center, float), f, edges_of(f)


def no_obstacle():
    return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64)


# --------------------------------------------------------------------------- primitives
def test_point_triangle_distance_matches_dense_sampling():
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.linspace(0, 1, 301), np.linspace(0, 1, 301))
    keep = u + v <= 1
    u, v = u[keep], v[keep]
    for _ in range(20):
        a, b, c = rng.normal(size=(3, 3))
        p = rng.normal(size=3) * 1.5
        samples = a + u[:, None] * (b - a) + v[:, None] * (c - a)
        ref = np.linalg.norm(samples - p, axis=1).min()
        d, b0, b1, b2 = prim.point_triangle_distance(tuple(p), tuple(a), tuple(b), tuple(c))
        assert d <= ref + 1e-12
        assert d == pytest.approx(ref, abs=2e-2 * np.linalg.norm(b - a) / 30 + 1e-3)
        q = b0 * a + b1 * b + b2 * c
        assert np.linalg.norm(p - q) == pytest.approx(d, abs=1e-12)
        assert min(b0, b1, b2) >= 0 and b0 + b1 + b2 == pytest.approx(1.0)


def test_point_triangle_known_answers():
    a, b, c = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
    assert prim.point_triangle_distance((0.2, 0.3, 0.5), a, b, c)[0] == pytest.approx(0.5)
    assert prim.point_triangle_distance((-1.0, -1.0, 0.0), a, b, c)[0] == pytest.approx(np.sqrt(2))
    d, b0, b1, b2 = prim.point_triangle_distance((1.0, 1.0, 0.0), a, b, c)
    assert d == pytest.approx(np.sqrt(0.5)) and (b1, b2) == pytest.approx((0.5, 0.5))


def test_segment_distance_matches_dense_sampling():
    rng = np.random.default_rng(1)
    s = np.linspace(0, 1, 2001)
    for _ in range(30):
        p0, p1, q0, q1 = rng.normal(size=(4, 3))
        if rng.random() < 0.2:  # parallel segments
            q1 = q0 + (p1 - p0) * rng.uniform(0.3, 2)
        P = p0 + s[:, None] * (p1 - p0)
        Q = q0 + s[:, None] * (q1 - q0)
        ref = np.sqrt(((P[:, None] - Q[None]) ** 2).sum(-1).min())
        d, a, b = prim.segment_distance(tuple(p0), tuple(p1), tuple(q0), tuple(q1))
        assert d <= ref + 1e-12
        assert d == pytest.approx(ref, abs=5e-3)
        pa, pb = p0 + a * (p1 - p0), q0 + b * (q1 - q0)
        assert np.linalg.norm(pa - pb) == pytest.approx(d, abs=1e-12)
    d, a, b = prim.segment_distance((0, 0, 0), (1, 0, 0), (0.5, -1, 2), (0.5, 1, 2))
    assert (d, a, b) == pytest.approx((2.0, 0.5, 0.5))


# --------------------------------------------------------------------------- CCD
def test_ccd_vertex_through_triangle_known_time():
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    tri_f = np.array([[0, 1, 2]])
    # a vertical cloth triangle whose lowest vertex drops from z=0.3 to z=-0.1
    x0 = np.array([[0.2, 0.2, 0.3], [0.2, 0.2, 0.5], [0.25, 0.2, 0.5]])
    x1 = x0 - [0.0, 0.0, 0.4]
    f = np.array([[0, 1, 2]])
    imp = col.find_impacts(x0, x1, f, edges_of(f), tri, tri, tri_f, edges_of(tri_f), H)
    assert len(imp) == 1 and imp.kind[0] == col.VF_OBSTACLE
    assert imp.idx[0].tolist() == [0, -1, -2, -3]
    assert imp.time[0] == pytest.approx(0.75, abs=1e-12)
    assert imp.n[0] == pytest.approx([0, 0, 1])  # towards the side the vertex came from
    assert imp.w[0] == pytest.approx([1, -0.6, -0.2, -0.2])
    assert abs(imp.d[0]) < 1e-9
    # the same motion 0.9 m to the side of the triangle is no impact
    assert len(col.find_impacts(x0 + [0.9, 0, 0], x1 + [0.9, 0, 0], f, edges_of(f), tri, tri, tri_f, edges_of(tri_f), H)) == 0


def test_ccd_edge_crossing_edge_known_time():
    a = np.array([[-1.0, 0, 0], [1, 0, 0], [0, 0, -1]])  # static, top edge along x at z=0
    b0 = np.array([[0.3, -1, 1], [0.3, 1, 1], [0.3, 0.1, 2]])  # bottom edge along y at z=1
    x0 = np.concatenate([a, b0])
    x1 = x0.copy()
    x1[3:, 2] -= 4.0  # the bottom edge of b crosses the top edge of a at t = 1/4
    f = np.array([[0, 1, 2], [3, 4, 5]])
    imp = col.find_impacts(x0, x1, f, edges_of(f), *no_obstacle()[:1], *no_obstacle(), H)
    pair = [k for k in range(len(imp)) if sorted(imp.idx[k].tolist()) == [0, 1, 3, 4]]
    assert len(pair) == 1
    k = pair[0]
    assert imp.kind[k] == col.EE_SELF and imp.time[k] == pytest.approx(0.25, abs=1e-12)
    w = dict(zip(imp.idx[k].tolist(), imp.w[k].tolist()))
    assert [w[0], w[1], w[3], w[4]] == pytest.approx([0.35, 0.65, -0.5, -0.5]) or [w[3], w[4], w[0], w[1]] == pytest.approx([0.5, 0.5, -0.35, -0.65])
    assert imp.select(np.array([k])).gaps(x0)[0] > 0  # oriented so that the start gap is positive
    assert imp.select(np.array([k])).gaps(x1)[0] < 0
    assert imp.time.min() == pytest.approx(0.25, abs=1e-12)  # nothing earlier


def _dense_first_crossing(p0, p1, a0, a1, b0, b1, c0, c1, samples):
    """Earliest sampled time when the vertex crosses the triangle's plane inside it
    (barycentrics > 1e-3), from a dense sampling of the signed volume."""
    t = samples[:, None]
    p, a, b, c = (u0 + t * (u1 - u0) for u0, u1 in ((p0, p1), (a0, a1), (b0, b1), (c0, c1)))
    n = np.cross(b - a, c - a)
    vol = np.sum(n * (p - a), 1)
    change = np.flatnonzero(np.sign(vol[:-1]) * np.sign(vol[1:]) < 0)
    for k in change:
        s = vol[k] / (vol[k] - vol[k + 1])
        tm = samples[k] + s * (samples[k + 1] - samples[k])
        pa, aa, ba, ca = (u0 + tm * (u1 - u0) for u0, u1 in ((p0, p1), (a0, a1), (b0, b1), (c0, c1)))
        nn = np.cross(ba - aa, ca - aa)
        area2 = np.linalg.norm(nn)
        w1 = np.dot(np.cross(pa - aa, ca - aa), nn) / area2**2
        w2 = np.dot(np.cross(ba - aa, pa - aa), nn) / area2**2
        if min(w1, w2, 1 - w1 - w2) > 1e-3:
            return samples[k + 1]
    return None


def test_ccd_misses_nothing_on_random_motions():
    rng = np.random.default_rng(2)
    samples = np.linspace(0, 1, 4001)
    ts = np.empty(8)
    crossings = 0
    for _ in range(400):  # reference loop over random test cases
        tri0 = rng.uniform(-1, 1, size=(3, 3))
        tri1 = tri0 + rng.normal(scale=0.6, size=(3, 3)) * (rng.random() < 0.6)
        p0 = tri0.mean(0) + rng.normal(scale=0.8, size=3)
        p1 = tri1.mean(0) + rng.normal(scale=0.8, size=3)
        pts = (p0, p1, tri0[0], tri1[0], tri0[1], tri1[1], tri0[2], tri1[2])
        ok, t, n, u0, u1, u2, d = ccd.vf_impact(*(tuple(p) for p in pts), 1e-6, ts)
        ref = _dense_first_crossing(*pts, samples)
        if ref is not None:
            crossings += 1
            assert ok and t <= ref + 1e-9, f"sampled crossing at t={ref} missed"
        if ok:  # every reported impact really touches at its time
            p = p0 + t * (p1 - p0)
            a, b, c = tri0 + t * (tri1 - tri0)
            assert prim.point_triangle_distance(tuple(p), tuple(a), tuple(b), tuple(c))[0] < 1e-6
            assert abs(d) < 1e-6
    assert crossings > 40


def test_ccd_edge_edge_misses_nothing_on_random_motions():
    rng = np.random.default_rng(12)
    samples = np.linspace(0, 1, 4001)[:, None]
    ts = np.empty(8)
    crossings = 0
    for _ in range(300):
        start = rng.uniform(-1, 1, size=(4, 3))
        end = start + rng.normal(scale=0.8, size=(4, 3))
        pos = start[None] + samples[..., None] * (end - start)[None]  # [T,4,3]
        d1, d2, r = pos[:, 1] - pos[:, 0], pos[:, 3] - pos[:, 2], pos[:, 2] - pos[:, 0]
        vol = np.sum(np.cross(d1, d2) * r, 1)
        ok, t, n, a, b, d = ccd.ee_impact(*(tuple(p) for k in range(4) for p in (start[k], end[k])), 1e-6, ts)
        for k in np.flatnonzero(np.sign(vol[:-1]) * np.sign(vol[1:]) < 0):  # sampled crossings
            p0, p1, q0, q1 = pos[k + 1]
            dist, _, _ = prim.segment_distance(tuple(p0), tuple(p1), tuple(q0), tuple(q1))
            e0, e1, f0, f1 = pos[k]
            dist0, _, _ = prim.segment_distance(tuple(e0), tuple(e1), tuple(f0), tuple(f1))
            if max(dist, dist0) < 2e-3 and min(np.linalg.norm(p1 - p0), np.linalg.norm(q1 - q0)) > 0.05:
                crossings += 1
                assert ok and t <= samples[k + 1, 0] + 1e-9
                break
        if ok:
            p, rr, q, s = (start[k] + t * (end[k] - start[k]) for k in range(4))
            assert prim.segment_distance(tuple(p), tuple(rr), tuple(q), tuple(s))[0] < 1e-6
    assert crossings > 10


# --------------------------------------------------------------------------- proximity
def _brute_proximities(x, faces, edges, ob, ob_faces, ob_edges, h):
    """O(n^2) numpy reference with the same criteria: {(kind, ids): gap}."""
    out = {}

    def vf(pts, tri_pts, vids, fids, kind, skip_shared, obstacle_face):
        a, b, c = tri_pts[fids[:, 0]], tri_pts[fids[:, 1]], tri_pts[fids[:, 2]]
        nn = np.cross(b - a, c - a)
        area2 = np.linalg.norm(nn, axis=1)
        n = nn / area2[:, None]
        for vi, p in enumerate(pts):
            hgt = np.sum((p - a) * n, 1)
            b1 = np.sum(np.cross(p - a, c - a) * n, 1) / area2
            b2 = np.sum(np.cross(b - a, p - a) * n, 1) / area2
            ok = (np.abs(hgt) < h) & (b1 >= -1e-6) & (b2 >= -1e-6) & (1 - b1 - b2 >= -1e-6)
            if skip_shared:
                ok &= ~np.any(fids == vi, 1)
            for f in np.flatnonzero(ok):
                gap = hgt[f] if obstacle_face else abs(hgt[f])
                out[(kind, vids[vi]) + tuple((-fids[f] - 1 if kind == 2 else fids[f]).tolist())] = gap

    vf(x, x, list(range(len(x))), faces, 0, True, False)
    vf(x, ob, list(range(len(x))), ob_faces, 2, False, True)
    vf(ob, x, [-i - 1 for i in range(len(ob))], faces, 3, False, False)
    for e, (i, j) in enumerate(edges):
        for g, (k, l) in enumerate(edges):
            if g <= e or len({i, j, k, l}) < 4:
                continue
            _ee(out, x[i], x[j], x[k], x[l], (1, i, j, k, l), h, None)
    fn = np.cross(ob[ob_faces[:, 1]] - ob[ob_faces[:, 0]], ob[ob_faces[:, 2]] - ob[ob_faces[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    edge_normal = {}
    for face, n in zip(ob_faces.tolist(), fn):
        for k in range(3):
            key = tuple(sorted((face[k], face[(k + 1) % 3])))
            edge_normal[key] = edge_normal.get(key, 0.0) + n
    for i, j in edges:
        for k, l in ob_edges:
            _ee(out, x[i], x[j], ob[k], ob[l], (4, i, j, -k - 1, -l - 1), h, edge_normal[(k, l)])
    return out


def _ee(out, p0, p1, q0, q1, key, h, obstacle):
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, b = d1 @ d1, d2 @ d2, d1 @ d2
    den = a * e - b * b
    if den <= 1e-6 * a * e:
        return
    s = (b * (d2 @ r) - (d1 @ r) * e) / den
    t = (a * (d2 @ r) - b * (d1 @ r)) / den
    if not (-1e-6 <= s <= 1 + 1e-6 and -1e-6 <= t <= 1 + 1e-6):
        return
    s, t = np.clip(s, 0, 1), np.clip(t, 0, 1)
    n = np.cross(d1, d2)
    gap = n @ ((p0 + s * d1) - (q0 + t * d2)) / np.linalg.norm(n)
    if abs(gap) < h:  # obstacle: the gap is positive on the side the edge pseudonormal points to
        out[key] = abs(gap) if obstacle is None else gap * np.sign(n @ obstacle)


def _crumpled_two_layers(n=9, seed=3):
    rng = np.random.default_rng(seed)
    lower = sheet(n, 0.1, 0.0)
    upper = sheet(n, 0.1, 0.004, shift=(0.004, 0.003))
    x, f, e = merge(lower, upper)
    x = x + rng.normal(scale=[0.0005, 0.0005, 0.0015], size=x.shape)
    return x, f, e


def test_proximity_matches_brute_force():
    x, faces, edges = _crumpled_two_layers()
    ob, ob_faces, ob_edges = ball([0.01, 0.0, -0.053], 0.05, subdivisions=2)
    c = col.find_proximities(torch.from_numpy(x), torch.from_numpy(faces), edges, ob, ob_faces, ob_edges, H)
    ref = _brute_proximities(x, faces, edges, ob, ob_faces, ob_edges, H)
    got = {}
    for k, ids, d in zip(c.kind.tolist(), c.idx.tolist(), c.d.tolist()):
        if k == col.EE_SELF:  # unordered pair: lower edge first, as in the reference
            e0, e1 = tuple(ids[:2]), tuple(ids[2:])
            ids = list(min(e0, e1)) + list(max(e0, e1))
        got[(k,) + tuple(ids)] = abs(d) if k == col.FV_OBSTACLE else d
    assert len(ref) > 100 and {k[0] for k in ref} == {0, 1, 2, 3, 4}
    assert set(got) == set(ref)
    for key, gap in ref.items():
        assert got[key] == pytest.approx(gap, abs=1e-12)
    # gaps recomputed from the contact representation equal d, weights sum to zero
    assert c.gaps(x, ob) == pytest.approx(c.d, abs=1e-12)
    assert np.abs(c.w.sum(1)).max() < 1e-12
    assert np.allclose(np.linalg.norm(c.n, axis=1), 1)
    # obstacle vertex / cloth face contacts agree with a direct check
    fv = c.select(c.kind == col.FV_OBSTACLE)
    assert len(fv) > 0 and np.all(np.abs(fv.d) < H)


def test_obstacle_normals_near_faces_equal_the_whole_obstacles_there():
    from tryon.sim.geometry.normals import obstacle_normals, obstacle_normals_near

    ob, ob_faces, ob_edges = ball([0.0, 0.0, 0.0], 0.3, subdivisions=3)
    ob = ob * [1.0, 0.7, 1.3]  # not a sphere: normals differ from the radial direction
    vn, en = obstacle_normals(ob, ob_faces, ob_edges)
    picked = np.random.default_rng(0).choice(len(ob_faces), 8, replace=False)
    near_vn, near_en = obstacle_normals_near(ob, ob_faces, ob_edges, np.concatenate([picked, picked[:3]]))
    verts = np.unique(ob_faces[picked])
    lookup = {tuple(e): i for i, e in enumerate(ob_edges.tolist())}
    used = [lookup[tuple(sorted(p))] for f in ob_faces[picked] for p in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))]
    assert np.allclose(near_vn[verts], vn[verts], atol=1e-12) and np.allclose(near_en[used], en[used], atol=1e-12)
    assert np.abs(near_vn).sum(1).astype(bool).sum() < len(ob) / 2  # the rest of the obstacle was not visited
    empty_vn, _ = obstacle_normals_near(ob, ob_faces, ob_edges, np.zeros(0, np.int64))
    assert not empty_vn.any()


def test_proximity_flat_sheet_has_no_self_contacts_and_obstacle_normals_point_out():
    x, f, e = sheet(30, 0.1, 0.0)  # spacing 3.4 mm < thickness: in-plane neighbours are no contacts
    gx, gf, ge = ground(z=-0.002)
    c = col.find_proximities(x, f, e, gx, gf, ge, H)
    assert c.counts()["vf_self"] == 0 and c.counts()["ee_self"] == 0
    vf = c.select(c.kind == col.VF_OBSTACLE)
    assert len(vf) >= len(x) and np.allclose(vf.n, [0, 0, 1]) and np.allclose(vf.d, 0.002)


def test_bvh_pairs_match_brute_force():
    rng = np.random.default_rng(4)
    for n_a, n_b in ((300, 200), (257, 1)):
        lo_a = rng.uniform(0, 1, (n_a, 3))
        hi_a = lo_a + rng.uniform(0, 0.08, (n_a, 3))
        lo_b = rng.uniform(0, 1, (n_b, 3))
        hi_b = lo_b + rng.uniform(0, 0.08, (n_b, 3))
        ov = np.all((lo_a[:, None] <= hi_b[None]) & (lo_b[None] <= hi_a[:, None]), -1)
        got = overlapping_pairs(BVH.build(lo_a, hi_a), BVH.build(lo_b, hi_b))
        assert set(map(tuple, got.tolist())) == set(zip(*np.nonzero(ov)))
        ov_self = np.all((lo_a[:, None] <= hi_a[None]) & (lo_a[None] <= hi_a[:, None]), -1)
        got = overlapping_pairs(BVH.build(lo_a, hi_a))
        assert {tuple(sorted(p)) for p in got.tolist()} == set(zip(*np.nonzero(np.triu(ov_self, 1))))
        assert len(got) == int(np.triu(ov_self, 1).sum())


def _contacts_equal(a, b):
    return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("idx", "w", "n", "d", "kind", "time"))


def test_collision_queries_on_threads_equal_one_pass(monkeypatch, on_numba_threads):
    """Pairs and contacts found in chunks on two threads equal those of one pass, in order."""
    x, faces, edges = _crumpled_two_layers(n=15)
    ob, ob_faces, ob_edges = ball([0.01, 0.0, -0.053], 0.05, subdivisions=3)
    x1 = x + np.random.default_rng(5).normal(scale=0.002, size=x.shape)
    tree = BVH.build(x[faces].min(1) - H, x[faces].max(1) + H)

    def queries(threads):
        if threads == 2:
            monkeypatch.setattr(geometry_threads, "CHUNK", 64)  # many chunks even on this small scene
        return (overlapping_pairs(tree), col.find_proximities(x, faces, edges, ob, ob_faces, ob_edges, H),
                col.find_impacts(x, x1, faces, edges, ob, ob + 0.001, ob_faces, ob_edges, H))

    (pairs1, prox1, imp1), (pairs2, prox2, imp2) = on_numba_threads(queries)
    assert len(pairs1) > 10 * 64 and len(prox1) > 100 and len(imp1) > 10
    assert np.array_equal(pairs1, pairs2)
    assert _contacts_equal(prox1, prox2) and _contacts_equal(imp1, imp2)


# --------------------------------------------------------------------------- intersections
def test_count_intersections_known_crossing_and_flat_sheet():
    x, f, e = sheet(10, 1.0, 0.0)
    gx, gf, ge = ground(z=-0.5)
    assert geo.count_intersections(x, f, e, gx, gf, ge) == (0, 0)
    # a single obstacle triangle piercing the sheet: two of its edges cross cloth faces
    tri = np.array([[0.01, 0.02, -0.3], [0.03, 0.01, 0.3], [0.2, 0.3, 0.3]])
    n_self, n_ob = geo.count_intersections(x, f, e, tri, np.array([[0, 1, 2]]), edges_of(np.array([[0, 1, 2]])))
    assert n_self == 0 and n_ob >= 2
    # self: a second sheet tilted through the first
    y, g, _ = sheet(6, 0.4, 0.0)
    y = y[:, [0, 2, 1]] + [0.013, 0.017, 0.0]  # vertical sheet crossing z=0
    xx, ff, ee = merge((x, f, e), (y, g, None))
    n_self, n_ob = geo.count_intersections(xx, ff, ee, *no_obstacle())
    assert n_self > 0 and n_ob == 0
    assert geo.count_intersections(xx, ff, ee, *no_obstacle(), self_collision=False) == (0, 0)


def test_obstacle_distances_on_a_sphere():
    rng = np.random.default_rng(5)
    ob, obf, _ = ball([0.1, -0.2, 0.3], 0.5, subdivisions=3)
    pts = rng.normal(size=(300, 3))
    pts = pts / np.linalg.norm(pts, axis=1, keepdims=True) * rng.uniform(0.1, 0.9, (300, 1)) + [0.1, -0.2, 0.3]
    sd = geo.signed_obstacle_distance(pts, ob, obf)
    exact = np.linalg.norm(pts - [0.1, -0.2, 0.3], axis=1) - 0.5  # the mesh is inscribed: within ~1 %
    clear = np.abs(exact) > 0.02  # the inscribed mesh is within 1 cm of the sphere
    assert np.all(np.sign(sd[clear]) == np.sign(exact[clear]))
    assert np.abs(sd - exact).max() < 0.01
    # unsigned minimum against a brute-force minimum over all faces
    a, b, c = ob[obf[:, 0]], ob[obf[:, 1]], ob[obf[:, 2]]
    ref = min(prim.point_triangle_distance(tuple(p), tuple(a[k]), tuple(b[k]), tuple(c[k]))[0] for p in pts[:20] for k in range(len(obf)))
    assert geo.min_obstacle_distance(pts[:20], ob, obf) == pytest.approx(ref, abs=1e-12)
    assert geo.min_obstacle_distance(pts, *no_obstacle()[:2]) == float("inf")


# --------------------------------------------------------------------------- response
def _check_resolved(x0, res, faces, edges, ob0, ob1, obf, obe, report, target):
    assert report.success
    assert geo.count_intersections(res, faces, edges, ob1, obf, obe) == (0, 0)
    assert len(col.find_impacts(x0, res, faces, edges, ob0, ob1, obf, obe, H)) == 0
    assert report.max_violation < 1e-9
    gaps = report.constraints.gaps(res, ob1)
    assert gaps.min() >= target - 1e-9


def test_cloth_falling_fast_through_a_plane_ends_above_it():
    rng = np.random.default_rng(6)
    x0, f, e = sheet(12, 0.5, 0.01)
    x1 = x0 + [0.0, 0.0, -0.06] + rng.normal(scale=0.003, size=x0.shape)
    gx, gf, ge = ground(z=0.0)
    assert x1[:, 2].max() < 0  # tunnelled right through: only CCD can see it
    assert len(col.find_impacts(x0, x1, f, e, gx, gx, gf, ge, H)) >= len(x0)
    m = np.full(len(x0), 1e-3)
    res, rep = col.resolve_collisions(col.CollisionScene.of(f, e, m, gf, ge, H), x0, x1, gx, gx)
    _check_resolved(x0, res, f, e, gx, gx, gf, ge, rep, 0.1 * H)
    assert res[:, 2].min() >= 0.1 * H - 1e-9
    assert rep.impacts_found > 0 and rep.zones >= 1
    safe = col.rigid_impact_zone_fallback(col.CollisionScene.of(f, e, m, gf, ge, H), x0, x1, gx, gx)
    assert geo.count_intersections(safe, f, e, gx, gf, ge) == (0, 0)
    assert len(col.find_impacts(x0, safe, f, e, gx, gx, gf, ge, H)) == 0


def _squeezed_layers():
    lower = sheet(9, 0.2, 0.0)
    upper = sheet(9, 0.2, 0.004, shift=(0.0125, 0.0125))
    x0, f, e = merge(lower, upper)
    x1 = x0.copy()
    top = np.arange(81, 162)
    centre = top[np.linalg.norm(x0[top, :2] - [0.0125, 0.0125], axis=1) < 0.06]
    x1[centre, 2] = -0.012  # pushed down through the lower sheet
    x1[np.arange(81), 2] += 0.002
    pinned = np.zeros(len(x0), bool)
    pinned[[0, 8, 72, 80]] = True  # lower sheet's corners
    return x0, x1, f, e, pinned


def test_vertex_driven_through_another_layer_is_stopped_and_pins_hold():
    x0, x1, f, e, pinned = _squeezed_layers()
    assert geo.count_intersections(x1, f, e, *no_obstacle())[0] > 0
    masses = torch.full((len(x0),), 2e-4, dtype=torch.float64)
    res, rep = col.resolve_collisions(col.CollisionScene.of(f, e, masses, thickness=H, pinned_mask=pinned), torch.from_numpy(x0), x1)
    _check_resolved(x0, res, f, e, *no_obstacle()[:1], *no_obstacle(), rep, 0.1 * H)
    assert np.array_equal(res[pinned], x1[pinned])
    # KKT of the projection: z - x1 = M^-1 A^T lambda, lambda >= 0, complementary slackness
    c, lam = rep.constraints, rep.multipliers
    assert lam.min() >= 0
    disp = np.zeros_like(x0)
    for k in range(4):
        np.add.at(disp, c.idx[:, k], (lam * c.w[:, k])[:, None] * c.n)
    disp[pinned] = 0.0
    assert np.abs(res - x1 - disp / 2e-4).max() < 1e-9
    slack = c.gaps(res) - rep.target_gap
    assert np.abs(lam * slack).max() < 1e-9 * max(lam.max(), 1.0)
    safe = col.rigid_impact_zone_fallback(col.CollisionScene.of(f, e, masses, thickness=H, pinned_mask=pinned), x0, x1)
    assert geo.count_intersections(safe, f, e, *no_obstacle()) == (0, 0)
    assert len(col.find_impacts(x0, safe, f, e, *no_obstacle()[:1], *no_obstacle(), H)) == 0
    assert np.array_equal(safe[pinned], x1[pinned])


def test_moving_obstacle_pushes_cloth():
    x0, f, e = sheet(12, 0.4, 0.0)
    ob0, obf, obe = ball([0.0, 0.0, -0.21], 0.2, subdivisions=2)
    ob1 = ob0 + [0.0, 0.0, 0.05]  # rises 5 cm through the resting cloth
    m = np.full(len(x0), 1e-3)
    res, rep = col.resolve_collisions(col.CollisionScene.of(f, e, m, obf, obe, H), x0, x0.copy(), ob0, ob1)
    _check_resolved(x0, res, f, e, ob0, ob1, obf, obe, rep, 0.1 * H)
    assert geo.signed_obstacle_distance(res, ob1, obf).min() > 0
    assert res[:, 2].max() > 0.03
    safe = col.rigid_impact_zone_fallback(col.CollisionScene.of(f, e, m, obf, obe, H), x0, x0.copy(), ob0, ob1)
    assert geo.count_intersections(safe, f, e, ob1, obf, obe) == (0, 0)
    assert len(col.find_impacts(x0, safe, f, e, ob0, ob1, obf, obe, H)) == 0


def test_sharp_obstacle_tip_is_caught_by_vertex_face_contacts():
    x0, f, e = sheet(5, 0.4, 0.0)  # coarse: the tip falls inside one cloth face
    tip = np.array([[0.03, 0.02, -0.02], [-0.1, -0.1, -0.2], [0.1, -0.1, -0.2], [0.0, 0.12, -0.2]])
    tf = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 3], [1, 2, 3]])
    tip1 = tip + [0, 0, 0.05]
    res, rep = col.resolve_collisions(col.CollisionScene.of(f, e, np.full(len(x0), 1e-3), tf, edges_of(tf), H), x0, x0.copy(), tip, tip1)
    _check_resolved(x0, res, f, e, tip, tip1, tf, edges_of(tf), rep, 0.1 * H)
    assert col.FV_OBSTACLE in set(rep.constraints.kind.tolist())


def test_bad_input_raises_mesh_error():
    x, f, e = sheet(3)
    with pytest.raises(MeshError, match="cloth faces"):
        col.find_proximities(x, f + 100, e, *no_obstacle(), H)
    with pytest.raises(MeshError, match="positions"):
        col.find_proximities(x[:, :2], f, e, *no_obstacle(), H)
    with pytest.raises(MeshError, match="masses"):
        col.resolve_collisions(col.CollisionScene.of(f, e, np.zeros(len(x)), thickness=H), x, x)


def test_stitched_vertices_are_one_vertex_to_contact_handling():
    # a vertical sheet standing 1 mm above a horizontal one, two of its bottom vertices
    # stitched to the vertices below them: contacts joining stitched vertices are dropped,
    # the other two bottom vertices keep theirs
    a = sheet(4, size=0.03)
    v, f, _ = sheet(4, size=0.03)
    b = (np.stack([np.full(len(v), 0.005), v[:, 1], v[:, 0] + 0.016], 1), f, None)
    x, faces, edges = merge(a, b)
    bottom = 16 + np.nonzero(np.isclose(x[16:, 2], 0.001))[0]
    below = np.array([int(np.argmin(np.linalg.norm(x[:16] - x[i] + [0, 0, 0.001], axis=1))) for i in bottom])
    stitches = np.stack([bottom[:2], below[:2]], 1)
    alias = col.stitch_alias(stitches, len(x))
    assert np.all(alias[stitches[:, 0]] == alias[stitches[:, 1]]) and len(np.unique(alias)) == 30
    assert col.stitch_alias(np.zeros((0, 2), np.int64), 4) is None
    plain = col.find_proximities(x, faces, edges, None, None, None, H)
    joined = col.find_proximities(x, faces, edges, None, None, None, H, alias=alias)
    assert 0 < len(joined) < len(plain)
    kept = {tuple(r) for r in joined.idx}
    for row, kind in zip(plain.idx, plain.kind):
        k = 1 if kind == col.VF_SELF else 2  # the vertex, or the first edge
        joins = np.isin(alias[row[:k]], alias[row[k:]]).any()
        assert joins != (tuple(row) in kept)  # dropped exactly when it joins stitched vertices
    assert np.isin(joined.idx, bottom[2:]).any()
    # lowering the sheet through the other: only the unstitched vertices' impacts remain
    x1 = x.copy()
    x1[16:, 2] -= 0.002
    hit = col.find_impacts(x, x1, faces, edges, None, None, None, None, H, alias=alias)
    assert len(hit) > 0 and not np.isin(alias[hit.idx], alias[stitches[:, 0]]).all(axis=1).any()
    n_plain, _ = geo.count_intersections(x1, faces, edges, *no_obstacle())
    n_joined, _ = geo.count_intersections(x1, faces, edges, *no_obstacle(), alias=alias)
    assert 0 < n_joined < n_plain
