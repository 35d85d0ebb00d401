"""Garments from sewing patterns: drafts in real sizes, JSON/SVG, seam-matched triangulation, dressing."""

import json

import numpy as np
import pytest

from tryon.body.pose import posed_body
from tryon.drape.fit_metrics import penetration
from tryon.fabric import load_fabric
from tryon.garment.drafts import GARMENTS, draft
from tryon.drape.dress import SEAMS_CLOSED, dress_pattern
from tryon.garment.pattern import Edge, Panel, Pattern, PatternError, Seam
from tryon.garment.sizes import SIZES, size_chart, size_measurements
from tryon.sizing.chart import size_for_chest
from tryon.garment.triangulate import merge_stitched, triangulate_pattern
from tryon.errors import TryonError

pytestmark = [pytest.mark.anny]

# boundary loops a closed garment keeps open: its openings
OPENINGS = {"tshirt": 4, "longsleeve": 4, "dress": 4, "skirt": 2, "trousers": 3}


@pytest.fixture(scope="module")
def model_body(size_m_man):
    return size_m_man


def test_size_chart_is_ordered_and_cited():
    chart = size_chart()
    assert "EN 13402" in json.dumps(chart)
    for gender in ("male", "female"):
        chests = [size_measurements(s, gender)["chest_cm"] for s in SIZES]
        assert chests == sorted(chests) and len(set(chests)) == len(chests)
        assert size_for_chest(size_measurements("L", gender)["chest_cm"], gender) == "L"
    with pytest.raises(TryonError, match="unknown size"):
        size_measurements("XXXXL", "male")


@pytest.mark.parametrize("garment", GARMENTS)
def test_drafts_have_matching_seams_and_round_trip(model_body, garment, tmp_path):
    _, meas = model_body
    p = draft(garment, meas, size="M")
    assert p.area() > 0.3  # m^2: a real garment, not a swatch
    for s in p.seams:
        a, b = p.seam_edges(s)
        assert abs(a.length() - b.length()) < 0.02 * max(a.length(), b.length()) + 0.003, (garment, s)
    back = Pattern.load(p.save(tmp_path / "p.json"))
    assert back.to_dict() == p.to_dict()
    svg = p.to_svg(tmp_path / "p.svg").read_text()
    assert svg.count("<polygon") == len(p.panels)


def test_bigger_size_gives_a_bigger_tshirt(model_body):
    shape, meas = model_body
    small = draft("tshirt", meas, size="S")
    from tryon.garment.drafts import Ease

    loose = draft("tshirt", meas, ease=Ease(chest=0.20))
    assert loose.area() > small.area()


@pytest.mark.parametrize("garment", ["tshirt", "trousers"])
def test_triangulation_matches_seam_vertices(model_body, garment):
    _, meas = model_body
    p = draft(garment, meas, size="M")
    mesh = triangulate_pattern(p, 0.03)
    for s in p.seams:
        assert len(mesh.edge_vertices[s.a]) == len(mesh.edge_vertices[s.b])
    # material coordinates are the panels' own 2D coordinates (lengths preserved)
    e = mesh.faces[:, [0, 1]]
    d2 = np.linalg.norm(mesh.points2d[e[:, 0]] - mesh.points2d[e[:, 1]], axis=1)
    duv = np.linalg.norm(mesh.uv[e[:, 0]] - mesh.uv[e[:, 1]], axis=1)
    np.testing.assert_allclose(d2, duv, atol=1e-9)
    assert 0.015 < np.median(d2) < 0.045
    # welding the stitches leaves exactly the garment's openings
    x = np.concatenate([mesh.points2d, np.zeros((mesh.num_vertices, 1))], 1)
    _, faces, _, _ = merge_stitched(mesh, x)
    assert _boundary_loops(faces) == OPENINGS[garment]


def _boundary_loops(faces: np.ndarray) -> int:
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    assert count.max() <= 2, "non-manifold seam"
    b = uniq[count == 1]
    n = int(faces.max()) + 1
    g = sp.coo_matrix((np.ones(len(b)), (b[:, 0], b[:, 1])), shape=(n, n))
    k, labels = connected_components(g, directed=False)
    return len(np.unique(labels[np.unique(b)]))


def test_dressing_sews_a_closed_tshirt_outside_the_body(model_body, monkeypatch):
    from tryon.drape.dress import DRESSING_LINEAR_SOLVER
    from tryon.sim.linear import LinearSolver, auto_solver_pinned

    kinds, init = [], LinearSolver.__init__

    def recording(self, *args, **kwargs):
        init(self, *args, **kwargs)
        kinds.append(self.kind)

    monkeypatch.setattr(LinearSolver, "__init__", recording)
    shape, meas = model_body
    body = posed_body(shape, "a", meas["crotch_height"])
    with auto_solver_pinned("splu"):  # whatever 'auto' means, the dressing cache's garments come from one solve
        g = dress_pattern(draft("tshirt", meas, size="M"), body, load_fabric("gray-interlock"), edge_length=0.03,
                          progress=False)
    assert kinds and set(kinds) == {DRESSING_LINEAR_SOLVER}
    assert g.stats["sew_gap_end_m"] < SEAMS_CLOSED  # shut, or a coarse neckline's last millimetres that stopped closing
    assert _boundary_loops(g.faces) == OPENINGS["tshirt"]
    pen = penetration(g.vertices, body.vertices, body.faces)
    assert pen["vertices_inside"] == 0
    # it hangs on the torso: between the hips and the neck, around the body's axis
    z = g.vertices[:, 2]
    assert meas["hip_height"] - 0.15 < z.min() and z.max() < meas["neck_height"] + 0.08
    assert abs(g.vertices[:, 0].mean()) < 0.03


def test_a_seam_eases_in_no_more_than_it_allows(tmp_path):
    def pattern(ease):
        a = Panel("a", [Edge("s", [[0, 0], [1, 0]]), Edge("t", [[1, 0], [1, 1]]), Edge("u", [[1, 1], [0, 0]])])
        b = Panel("b", [Edge("s", [[0, 0], [1.04, 0]]), Edge("t", [[1.04, 0], [1.04, 1]]), Edge("u", [[1.04, 1], [0, 0]])])
        return Pattern("p", [a, b], [Seam(("a", "s"), ("b", "s"), ease=ease)])

    with pytest.raises(PatternError, match="different lengths"):
        pattern(0.03)  # 4 % longer: over the default
    p = pattern(0.05)
    assert Pattern.load(p.save(tmp_path / "p.json")).seams[0].ease == 0.05


def test_bad_patterns_are_refused():
    sq = [Edge("a", [[0, 0], [1, 0]]), Edge("b", [[1, 0], [1, 1]]), Edge("c", [[1, 1], [0, 0]])]
    p = Panel("p", sq)
    with pytest.raises(PatternError, match="no edge"):
        Pattern("x", [p], [Seam(("p", "a"), ("p", "zz"))])
    with pytest.raises(PatternError, match="at least 3 edges"):
        Panel("q", sq[:2])
    with pytest.raises(PatternError, match="counter-clockwise"):
        Panel("r", [Edge("a", [[0, 0], [0, 1]]), Edge("b", [[0, 1], [1, 1]]), Edge("c", [[1, 1], [0, 0]])])
    with pytest.raises(PatternError, match="points must be numbers"):
        Edge("e", [["x", 0], [1, 0]])
    with pytest.raises(PatternError, match="bezier needs 4"):
        Edge("e", [[0, 0], [1, 0]], "bezier")
    with pytest.raises(PatternError, match="not a tryon pattern"):
        Pattern.from_dict({"panels": 3})
    with pytest.raises(TryonError, match="unknown garment"):
        draft("kimono", {}, size="M")


def test_a_made_to_measure_dress_is_let_down_over_the_belly_with_its_side_seams_unchanged(model_body):
    """A belly 20 cm forward, peaking 30 cm below the neck: the front's centre must run
    hypot(31, 20) cm from the top of the panel to the peak where the side runs 31 cm, and
    hangs straight below it; the flat back needs nothing more."""
    from tryon.garment.drafts import BodyCover

    _, meas = model_body
    top, peak = meas["neck_height"] + 0.01, meas["neck_height"] - 0.30
    h = meas["neck_height"] + 0.05 - 0.01 * np.arange(int((meas["neck_height"] - 0.15) / 0.01))
    front = -0.12 - 0.20 * np.clip(1.0 - np.abs(h - peak) / 0.30, 0.0, None)
    cover = BodyCover(h, np.zeros(len(h)), h, front, np.full(len(h), 0.12))
    excess = np.hypot(top - peak, 0.20) - (top - peak)
    assert cover.centre_excess("front", top, 0.4) == pytest.approx(excess, abs=0.002)
    assert cover.centre_excess("back", top, 0.4) == pytest.approx(0.0, abs=1e-9)

    plain = draft("dress", meas, size="made-to-measure")
    fitted = draft("dress", meas, size="made-to-measure", cover=cover)
    by_name = {p.name: p for p in fitted.panels}
    assert by_name["front"].bounds()[0][1] == pytest.approx(-excess, abs=0.003)  # the hem dips at the centre
    assert by_name["back"].bounds()[0][1] == pytest.approx(0.0, abs=1e-9)
    for seam in fitted.seams:  # the side seams as they were, and still matching
        a, b = fitted.seam_edges(seam)
        assert a.length() == pytest.approx(plain.seam_edges(seam)[0].length(), abs=1e-9)
        assert abs(a.length() - b.length()) < 0.003
    assert all(p.placement.get("along_surface") for p in fitted.panels)
    assert not any(p.placement.get("along_surface") for p in plain.panels)
