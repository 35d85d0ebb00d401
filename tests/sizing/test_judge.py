"""Where a size is judged: the torso of tops, the band round the hip line of skirts and
trousers (with the waistband's ease beside it), found in the panels' material."""

from types import SimpleNamespace

import numpy as np
import pytest

from tryon.garment.drafts import draft
from tryon.garment.triangulate import triangulate_pattern
from tryon.sizing.judge import HIP_BAND_M, TARGET_EASE_CM, TARGET_HIP_EASE_CM, WAIST_BAND_M, fit_bands, judge, recommend

# a woman's body (m): what the drafts read
BODY = {"stature": 1.68, "chest_girth": 1.025, "chest_height": 1.206, "waist_girth": 0.865, "waist_height": 1.087,
        "hip_girth": 1.105, "hip_height": 0.824, "neck_height": 1.424, "neck_girth": 0.46, "shoulder_height": 1.405,
        "shoulder_width": 0.364, "arm_length": 0.476, "bicep_girth": 0.297, "wrist_girth": 0.179,
        "crotch_height": 0.737, "thigh_girth": 0.59, "knee_height": 0.495, "ankle_height": 0.08, "chest_depth": 0.262}


def _garment(name: str):
    mesh = triangulate_pattern(draft(name, BODY, size="L"), 0.02)
    return SimpleNamespace(pattern=mesh.pattern, faces=mesh.faces, uv=mesh.uv, corner_uv=mesh.corner_uv,
                           face_panel=mesh.panel_of_vertex[mesh.faces[:, 0]])


@pytest.mark.parametrize("name", ["skirt", "trousers"])
def test_the_hip_band_and_the_waistband_lie_where_the_draft_puts_them(name):
    g = _garment(name)
    bands = fit_bands(g)
    depth = BODY["waist_height"] - BODY["hip_height"]
    for k in range(len(g.pattern.panels)):
        v = np.unique(g.faces[g.face_panel == k])
        top = g.uv[v, 0].max()
        waist, hip = np.intersect1d(v, bands["waist"]), np.intersect1d(v, bands["hip"])
        assert len(waist) and len(hip)
        assert (g.uv[waist, 0] >= top - WAIST_BAND_M - 1e-9).all()
        assert np.abs(g.uv[hip, 0] - (top - depth)).max() <= HIP_BAND_M / 2 + 1e-9
        if name == "trousers":  # the hip line is where the draft turns the outseam toward the waist
            panel = g.pattern.panels[k]
            ends = panel.edge("outseam_hip").points[[0, -1], 1]  # the hip end is the lower one
            corner = ends.min() - panel.edge("hem").points[0][1]
            assert top - depth == pytest.approx(corner, abs=0.005)


def test_a_skirt_or_trousers_is_judged_by_the_hip_band_and_reports_the_waistband():
    g = _garment("trousers")
    bands = fit_bands(g)
    d = np.full(len(g.uv), 0.03)       # 3 cm off the skin on the legs
    d[bands["hip"]] = 0.012            # 1.2 cm round the hip line
    d[bands["waist"]] = 0.004          # the waistband close
    j = judge("L", g, d, np.zeros(len(g.faces)))
    assert j["decided_by"] == "hip" and j["ease_cm"] == pytest.approx(1.2) and j["hip_ease_cm"] == pytest.approx(1.2)
    assert j["waist_ease_cm"] == pytest.approx(0.4) and j["target_ease_cm"] == TARGET_HIP_EASE_CM["trousers"]
    assert np.isnan(j["torso_ease_cm"]) and j["fits"]
    # of three sizes that fit, the one nearest a regular fit at the hip, with the words saying so
    sizes = [dict(j, size=s, ease_cm=e, overstrained_area_pct=0.0) for s, e in (("M", 0.3), ("L", 1.3), ("XL", 2.6))]
    best, reasons = recommend(sizes)
    assert best == "L" and "hip ease 1.3 cm" in reasons[0] and "waistband ease 0.4 cm" in reasons[0]
    assert any(r.startswith("XL also fits, looser: hip ease 2.6 cm") for r in reasons)


def test_tops_are_judged_by_the_torso_as_before():
    g = _garment("tshirt")
    assert fit_bands(g) is None
    d = np.full(len(g.uv), 0.02)
    j = judge("L", g, d, np.zeros(len(g.faces)))
    assert j["decided_by"] == "torso" and j["ease_cm"] == j["torso_ease_cm"] == pytest.approx(2.0)
    assert j["target_ease_cm"] == TARGET_EASE_CM and "waist_ease_cm" not in j


def test_a_size_the_simulator_could_not_drape_is_judged_where_its_garment_is():
    from tryon.sizing.judge import undrapeable

    assert undrapeable("S", "no progress", "trousers")["decided_by"] == "hip"
    assert undrapeable("S", "no progress", "trousers")["target_ease_cm"] == TARGET_HIP_EASE_CM["trousers"]
    assert undrapeable("S", "no progress")["decided_by"] == "torso" and not undrapeable("S", "x")["fits"]


def test_trouser_legs_longer_or_shorter_than_the_wearers_are_named():
    g = _garment("trousers")
    d = np.full(len(g.uv), 0.012)
    strain = np.zeros(len(g.faces))
    assert judge("L", g, d, strain, body_m=BODY)["inseam_excess_cm"] == pytest.approx(0.0, abs=0.15)  # drafted for her
    shorter_legs = dict(BODY, crotch_height=BODY["crotch_height"] - 0.05)
    long = judge("L", g, d, strain, body_m=shorter_legs)
    assert long["inseam_excess_cm"] == pytest.approx(5.0, abs=0.15)
    best, reasons = recommend([dict(long, size="L")])
    assert best == "L" and "legs are 5.0 cm longer than this body's inseam" in reasons[0]
    short = judge("L", g, d, strain, body_m=dict(BODY, crotch_height=BODY["crotch_height"] + 0.03))
    assert "3.0 cm shorter" in recommend([dict(short, size="L")])[1][0]
    assert "legs" not in recommend([dict(judge("L", g, d, strain, body_m=BODY), size="L")])[1][0]
    assert "inseam_excess_cm" not in judge("L", g, d, strain)  # the wearer not known: nothing said
    assert "inseam_excess_cm" not in judge("L", _garment("skirt"), np.full(len(_garment("skirt").uv), 0.01),
                                           np.zeros(len(_garment("skirt").faces)), body_m=BODY)
