"""One garment topology for every size: a triangulation laid on another size's panels."""

import numpy as np
import pytest

from tryon.errors import MeshError
from tryon.garment.drafts import draft
from tryon.garment.triangulate import merge_stitched, transfer_mesh, triangulate_pattern

pytestmark = [pytest.mark.anny]

GIRTHS = ("chest_girth", "waist_girth", "hip_girth", "bicep_girth", "neck_girth", "thigh_girth", "wrist_girth")


def _bigger(meas: dict, girth: float = 1.10, length: float = 1.03) -> dict:
    return {k: v * (girth if k in GIRTHS else length) for k, v in meas.items()}


def _polyline_distance(points, poly):
    a, b = poly[:-1], poly[1:]
    ab = b - a
    t = np.clip(((points[:, None] - a[None]) * ab[None]).sum(-1) / (ab * ab).sum(-1)[None], 0, 1)
    return np.linalg.norm(points[:, None] - (a[None] + t[..., None] * ab[None]), axis=-1).min(1)


@pytest.mark.parametrize("garment", ["tshirt", "trousers"])
def test_a_mesh_carried_to_a_bigger_size_keeps_its_triangles_and_seams(size_m_man, garment):
    _, meas = size_m_man
    small, big = draft(garment, meas, size="M"), draft(garment, _bigger(meas), size="L")
    ref = triangulate_pattern(small, 0.02)
    out = transfer_mesh(ref, big)
    assert np.array_equal(out.faces, ref.faces) and np.array_equal(out.stitches, ref.stitches)
    assert out.pattern is big
    # outline vertices lie on the bigger pattern's edges, at the same share of each edge's length
    for (panel, edge), idx in ref.edge_vertices.items():
        e = big.panel(panel).edge(edge)
        assert _polyline_distance(out.points2d[idx], e.polyline(400)).max() < 1e-5
        assert np.allclose(out.points2d[idx], e.sample(len(idx) - 1), atol=1e-9)
    # every triangle keeps its orientation; the garment grows with the pattern
    p = out.points2d[out.faces]
    area = 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    assert (area > 0).all()
    assert area.sum() == pytest.approx(big.area(), rel=0.01)
    # stitched partners stay on partner edges: the welded garment is the same mesh
    _, faces_ref, _, _ = merge_stitched(ref, np.zeros((ref.num_vertices, 3)))
    _, faces_out, _, _ = merge_stitched(out, np.zeros((out.num_vertices, 3)))
    assert np.array_equal(faces_ref, faces_out)
    # material coordinates are the panel coordinates in the grain frame (a rotation)
    e = out.faces[:, :2]
    assert np.allclose(np.linalg.norm(out.uv[e[:, 0]] - out.uv[e[:, 1]], axis=1),
                       np.linalg.norm(out.points2d[e[:, 0]] - out.points2d[e[:, 1]], axis=1))


def test_a_mesh_is_not_carried_to_another_garment(size_m_man):
    _, meas = size_m_man
    with pytest.raises(MeshError, match="panels"):
        transfer_mesh(triangulate_pattern(draft("tshirt", meas), 0.03), draft("skirt", meas))


@pytest.mark.parametrize("gender", ["female", "male"])
def test_tops_draft_in_every_size(gender):
    """The short sleeve of a deep armhole (male XL, female XXL) widens until its cap
    matches the armhole; before, these sizes could not be drafted at all."""
    from tryon.body.fit import Measurements, fit_body
    from tryon.body.measure import drafting_measurements
    from tryon.garment.sizes import SIZES, size_measurements

    for size in SIZES:
        s = size_measurements(size, gender)
        fit = fit_body(Measurements(height_cm=s["height_cm"], gender=gender, chest_cm=s["chest_cm"],
                                    waist_cm=s["waist_cm"], hip_cm=s["hip_cm"]), prior=False)  # the size's fit model
        m = drafting_measurements(fit.shape)
        for garment in ("tshirt", "longsleeve"):
            p = draft(garment, m, size=size)
            for seam in p.seams:
                a, b = p.seam_edges(seam)
                assert abs(a.length() - b.length()) < 0.005, (gender, size, garment, seam)
