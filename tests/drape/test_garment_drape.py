"""Garments end to end at a coarse edge length (every draft dressed, draped to rest and
written out), the trouser draft's proportions and placement, the issue's trouser cases,
and the drape's guards: a garment starting through itself or the body is refused, a drape
stuck in the fail-safe stops with a diagnosis, and cloth flung implausibly fast is redone."""

import json

import numpy as np
import pytest
import torch

from tryon.body.fit import Measurements
from tryon.body.measure import drafting_measurements
from tryon.body.pose import BodyPose, posed_body
from tryon.drape import DrapeRequest, drape
from tryon.drape import pipeline
from tryon.dataset.drapes import size_pattern
from tryon.drape.fit_metrics import penetration
from tryon.drape.outputs import write_outputs
from tryon.errors import SimulationError, TryonError
from tryon.fabric import load_fabric
from tryon.garment.drafts import WAISTBAND_STRETCH, Ease, draft, size_too_small, trouser_dims
from tryon.garment.sizes import size_measurements
from tryon.drape.dress import SEAMS_CLOSED, DressedGarment, dress_pattern, place_pattern
from tryon.garment.triangulate import merge_stitched, triangulate_pattern
from tryon.sim import collision as col
from tryon.sim import geometry as geo
from tryon.sim.geometry import edge_face_intersections

pytestmark = [pytest.mark.anny, pytest.mark.slow]

COARSE = 0.03


def _edges(faces):
    return np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1), axis=0)


@pytest.fixture(scope="module")
def fit_model(size_m_man):
    shape, meas = size_m_man
    return shape, meas, posed_body(shape, "a", meas["crotch_height"])


def test_trouser_draft_has_standard_proportions(fit_model):
    _, m, _ = fit_model
    d = trouser_dims(m, Ease())
    stature = m["stature"]
    # inside leg to the ankle bone and body rise (crotch to natural waist) of a regular man
    assert 0.40 * stature < d["inseam"] < 0.46 * stature, d["inseam"] / stature
    assert 0.14 * stature < d["rise"] < 0.19 * stature, d["rise"] / stature
    assert m["ankle_height"] < d["hem_z"] < m["ankle_height"] + 0.03
    # a straight leg: knee about 0.47 and hem about 0.43 of the seat, narrower than the thigh with ease
    seat = m["hip_girth"]
    assert 0.42 * seat < d["knee"] < 0.52 * seat and 0.38 * seat < d["hem"] < 0.48 * seat
    assert d["hem"] < d["knee"] < m["thigh_girth"] + 0.06
    p = draft("trousers", m, size="M")
    front, back = p.panel("front_L"), p.panel("back_L")
    fw = np.ptp(front.outline()[:, 0])
    bw = np.ptp(back.outline()[:, 0])
    assert bw > fw + 0.03  # the back panel: wider seat and a longer crotch extension
    hem = front.edge("hem").length() + back.edge("hem").length()
    assert abs(hem - d["hem"]) < 1e-6


def test_trousers_start_closed_and_uncrossed_and_dress_side_seams_start_closed(fit_model):
    _, m, body = fit_model
    p = draft("trousers", m, size="M")
    mesh = triangulate_pattern(p, COARSE)
    x = place_pattern(mesh, body)
    gaps = np.linalg.norm(x[mesh.stitches[:, 0]] - x[mesh.stitches[:, 1]], axis=1)
    assert gaps.max() < SEAMS_CLOSED
    pos, faces, _, _ = merge_stitched(mesh, x)
    assert geo.count_intersections(pos, faces, _edges(faces), np.zeros((0, 3)), np.zeros((0, 3), np.int64),
                                   np.zeros((0, 2), np.int64))[0] == 0
    # the two legs meet only at the crotch seams, on the midline
    for k, panel in enumerate(p.panels):
        sign = 1.0 if panel.placement["limb"] == "L" else -1.0
        assert (sign * x[mesh.panel_of_vertex == k, 0]).min() > -1e-9, panel.name
    g = dress_pattern(p, body, load_fabric("gray-interlock"), edge_length=COARSE, progress=False)
    assert g.stats["sew_steps"] == 0 and g.stats["relax_steps"] >= 5 and g.stats["self_intersections"] == 0
    # a shaped dress: only the shoulder seams start open, the side seams (waist and hips) closed
    dress = draft("dress", m, size="M")
    mesh = triangulate_pattern(dress, COARSE)
    x = place_pattern(mesh, body)
    pairs = []
    for seam in dress.seams:
        if "side" in seam.a[1]:
            va, vb = mesh.edge_vertices[seam.a], mesh.edge_vertices[seam.b]
            pairs.append(np.stack([va, vb[::-1] if seam.reverse else vb], 1))
    st = np.concatenate(pairs)
    assert len(st) > 10 and np.linalg.norm(x[st[:, 0]] - x[st[:, 1]], axis=1).max() < 0.005


def test_the_largest_womens_trousers_ease_the_back_inseam_and_start_closed():
    fit, m, p = size_pattern("trousers", "female", "XXL")
    front, back = p.panel("front_L").edge("inseam").length(), p.panel("back_L").edge("inseam").length()
    assert 0.02 < back / front - 1.0 < 0.05  # the back's longer crotch extension, eased in
    body = posed_body(fit.shape, "a", m["crotch_height"])
    mesh = triangulate_pattern(p, COARSE)
    x = place_pattern(mesh, body)
    assert np.linalg.norm(x[mesh.stitches[:, 0]] - x[mesh.stitches[:, 1]], axis=1).max() < SEAMS_CLOSED
    pos, faces, _, _ = merge_stitched(mesh, x)
    assert geo.count_intersections(pos, faces, _edges(faces), np.zeros((0, 3)), np.zeros((0, 3), np.int64),
                                   np.zeros((0, 2), np.int64))[0] == 0


@pytest.mark.parametrize("gender,size", [("female", "L"), ("male", "L")])
def test_large_tops_sew_without_crossing_themselves(gender, size):
    # the size's own fit model at the default edge length: sleeve caps sewn with
    # self-collision off used to cross the bodice at the underarm (10-14 edge-triangle
    # pairs in these two sizes, up to 162 in women's XXL), and such a drape is refused
    from tryon.body.fit import fit_body
    from tryon.garment.sizes import size_measurements

    s = size_measurements(size, gender)
    fit = fit_body(Measurements(height_cm=s["height_cm"], gender=gender, chest_cm=s["chest_cm"], waist_cm=s["waist_cm"],
                                hip_cm=s["hip_cm"]), prior=False)  # as tryon drape fits a size's fit model
    m = drafting_measurements(fit.shape)
    body = posed_body(fit.shape, "a", m["crotch_height"])
    g = dress_pattern(draft("tshirt", m, size=size), body, load_fabric("gray-interlock"), edge_length=0.012, progress=False)
    assert g.stats["self_intersections"] == 0
    assert 0.0 < g.stats["sleeve_shift_m"] <= 0.15 and g.stats["sew_gap_end_m"] < 0.01
    assert penetration(g.vertices, body.vertices, body.faces)["vertices_inside"] == 0


def test_a_fold_in_the_trouser_placement_is_smoothed_out_before_welding():
    # men's S at the default edge length: where the front panels turn from leg to torso
    # above the crotch, a row folded through itself (12 edge-triangle pairs, welded in)
    fit, m, p = size_pattern("trousers", "male", "S")
    body = posed_body(fit.shape, "a", m["crotch_height"])
    mesh = triangulate_pattern(p, 0.012)
    x = place_pattern(mesh, body)
    e = _edges(mesh.faces)
    hits = edge_face_intersections(x, e, x, mesh.faces, True)
    same_panel = mesh.panel_of_vertex[e[hits[:, 0], 0]] == mesh.panel_of_vertex[mesh.faces[hits[:, 1], 0]]
    folded = hits[same_panel & (x[e[hits[:, 0], 0], 1] < -0.05)]  # in front, within one panel: the fold
    assert len(folded) > 0
    g = dress_pattern(p, body, load_fabric("gray-interlock"), progress=False)
    assert g.stats["sew_steps"] == 0 and g.stats["self_intersections"] == 0
    assert g.stats["unfolded_crossings"] >= len(folded)


def test_trousers_made_to_measure_for_a_very_heavy_man_keep_every_triangle():
    # 200 cm, 180 kg on Anny's average shape: pushing the placed trousers out of his skin put
    # all three corners of a triangle on one point (a zero-area face the simulator refuses);
    # they are spread again. (The ANSUR II prior's body of these numbers has thighs that
    # meet through each other; dressing it leaves crossings: docs/BODY.md, still weak.)
    from tryon.body.fit import fit_body

    fit = fit_body(Measurements(height_cm=200, weight_kg=180, gender="male"), prior=False)
    m = drafting_measurements(fit.shape)
    p = draft("trousers", m, size="made-to-measure")
    body = posed_body(fit.shape, "a", m["crotch_height"])
    g = dress_pattern(p, body, load_fabric("gray-interlock"), progress=False)
    tri = g.vertices[g.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert area.min() > 1e-6 and g.stats["self_intersections"] == 0


def test_a_weld_through_a_fold_at_the_armpit_is_smoothed_out():
    # men's XL long sleeve on its fit model in the A-pose: the seams sewn 1.6 mm open and
    # uncrossed; welding them put the armhole seam through the bodice folded under it
    fit, m, p = size_pattern("longsleeve", "male", "XL")
    body = posed_body(fit.shape, "a", m["crotch_height"])
    g = dress_pattern(p, body, load_fabric("gray-interlock"), progress=False)
    assert g.stats["sew_gap_end_m"] > 0.0 and g.stats["unfolded_crossings"] > 0 and g.stats["self_intersections"] == 0
    assert penetration(g.vertices, body.vertices, body.faces)["vertices_inside"] == 0


@pytest.mark.parametrize("garment,size", [("tshirt", "S"), ("longsleeve", "S"), ("skirt", "S"), ("trousers", "S"), ("dress", "S")])
def test_every_garment_drapes_to_rest_and_is_written_out(garment, size, tmp_path):
    req = DrapeRequest(Measurements(height_cm=165, weight_kg=60, gender="female"), garment=garment, size=size,
                       fabric="gray-interlock", edge_length=COARSE)
    result = drape(req, progress=False)
    rep = write_outputs(result, tmp_path)
    assert rep["penetration_pct"] == 0.0 and rep["self_intersections"] == 0 and rep["body_intersections"] == 0
    assert rep["failsafe_steps"] <= 3 and len(rep["speed_recoveries"]) <= 1  # rare, and never a crawl
    assert 0.0 < rep["max_strain"] < 0.35 and rep["mean_strain"] < 0.08
    for name in ("render_front.png", "render_side.png", "render_back.png", "fit_map.png", "pressure_map.png", "tryon.glb"):
        assert (tmp_path / name).stat().st_size > 1000, name
    assert json.loads((tmp_path / "report.json").read_text())["settled"] == rep["settled"]
    assert rep["settled"] and rep["final_rest_speed"] < req.rest_speed, (rep["final_rest_speed"], rep["final_max_speed"])
    # nothing flung on the way (the morph moves cloth at up to ~1 m/s; a flung step, redone, is > 5 m/s)
    assert rep["final_max_speed"] <= rep["max_speed"] < 3.0
    if garment == "trousers":
        pm = drafting_measurements(result.person.shape)
        z = result.x[:, 2]
        # ankle length: the hems end around the ankle, above the floor; the waist stays up
        assert 0.02 < z.min() < pm["ankle_height"] + 0.05, (z.min(), pm["ankle_height"])
        assert z.max() > pm["waist_height"] - 0.06, (z.max(), pm["waist_height"])


@pytest.mark.parametrize("height,weight,size,fabric,prior", [
    (176, 75, "L", "11oz-black-denim", True),
    # on the ANSUR II prior's body (fuller thighs) this case settles with 2 crossings at the
    # crotch (docs/BODY.md, still weak): kept on Anny's average shape, as it was filed
    (180, 80, "L", "gray-interlock", False),
    (180, 80, "M", "11oz-black-denim", True),
    (172, 84, "M", "gray-interlock", True),
])
def test_trousers_on_men_drape_to_rest(height, weight, size, fabric, prior):
    """The issue's cases (no progress, explosions, steps of a minute) at a coarse edge length."""
    from tryon.body.fit import fit_body

    req = DrapeRequest(Measurements(height_cm=height, weight_kg=weight, gender="male"), garment="trousers", size=size,
                       fabric=fabric, edge_length=COARSE)
    result = drape(req, progress=False, person=fit_body(req.body, prior=prior))
    m = result.metrics
    assert m["settled"] and m["penetration_pct"] == 0.0 and m["self_intersections"] == 0
    assert m["failsafe_steps"] <= 2 and len(m["speed_recoveries"]) <= 1 and m["final_max_speed"] < 1.0
    assert m["simulated_s"] < m["morph_s"] + req.max_settle_time - 1e-6  # at rest before the settling time ran out
    assert m["max_strain"] < 0.4


# --------------------------------------------------------------------------- guards, on a small scene
def _sphere(radius=0.1, centre=(0.0, 0.0, 1.0), n=16):
    th, ph = np.meshgrid(np.linspace(0, np.pi, n + 1)[1:-1], np.linspace(0, 2 * np.pi, 2 * n, endpoint=False), indexing="ij")
    v = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    v = np.vstack([[0, 0, 1], v, [0, 0, -1]]) * radius + np.asarray(centre)
    rows, cols = n - 1, 2 * n
    idx = lambda r, c: 1 + r * cols + (c % cols)  # noqa: E731
    f = [[0, idx(0, c), idx(0, c + 1)] for c in range(cols)]
    for r in range(rows - 1):
        for c in range(cols):
            f += [[idx(r, c), idx(r + 1, c), idx(r + 1, c + 1)], [idx(r, c), idx(r + 1, c + 1), idx(r, c + 1)]]
    last = len(v) - 1
    f += [[last, idx(rows - 1, c + 1), idx(rows - 1, c)] for c in range(cols)]
    return BodyPose(v, np.array(f, np.int64), np.zeros(len(v), np.int64), {})


def _patch(z, size=0.16, n=8):
    g = np.linspace(-size / 2, size / 2, n)
    X, Y = np.meshgrid(g, g, indexing="ij")
    uv = np.stack([X.ravel() + size / 2, Y.ravel() + size / 2], 1)
    x = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            f += [[a, b, c], [a, c, d]]
    faces = np.array(f, np.int64)
    return DressedGarment(x, faces, uv, uv[faces], np.zeros(len(faces), np.int64), None, np.zeros(0, np.int64),
                          {"source": "patch.obj"})


def _request():
    return DrapeRequest(Measurements(height_cm=170, weight_kg=65, gender="female"), garment="patch.obj", size=None,
                        edge_length=0.02, morph_time=0.02, max_settle_time=0.08)


def test_a_garment_starting_through_itself_is_refused_with_its_vertices():
    body = _sphere()
    g = _patch(1.2)
    # a second sheet of the same garment stabbed through the first one
    stab = _patch(1.2)
    stab.vertices = stab.vertices[:, [2, 1, 0]] + np.array([-1.2, 0.0, 1.2])
    n = len(g.vertices)
    both = DressedGarment(np.vstack([g.vertices, stab.vertices]), np.vstack([g.faces, stab.faces + n]),
                          np.vstack([g.uv, stab.uv]), np.vstack([g.corner_uv, stab.corner_uv]),
                          np.zeros(2 * len(g.faces), np.int64), None, np.zeros(0, np.int64), {"source": "two.obj"})
    with pytest.raises(SimulationError, match=r"starts crossing itself at [1-9]\d* edge-triangle pairs \(\d+ vertices, e\.g\. \d+ at"):
        pipeline.simulate_drape(_request(), both, body, body, progress=False)


def test_a_drape_stuck_in_the_fail_safe_stops_with_a_diagnosis(monkeypatch):
    from tryon.sim.integrator import ImplicitEulerSolver, StepStats

    def frozen(self, state, dt, control=None):  # every step ends in the rigid fail-safe, nothing moves
        self.last_collision = col.CollisionReport(constraints=col.Contacts(
            idx=np.array([[3, 4, 5, -1]]), w=np.array([[1.0, -0.5, -0.5, 0.0]]), n=np.array([[0.0, 0.0, 1.0]]),
            kind=np.array([col.VF_OBSTACLE])), zones=1)
        return type(state)(state.x, torch.zeros_like(state.v), state.t + dt), StepStats(substeps=3, fallback=True)

    monkeypatch.setattr(ImplicitEulerSolver, "step", frozen)
    body = _sphere()
    with pytest.raises(SimulationError, match=rf"makes no progress.*{pipeline.FAILSAFE_STREAK} steps in a row.*1 impacts \(1 vf_obstacle\).*most involved: \d+ at"):
        pipeline.simulate_drape(_request(), _patch(1.15), body, body, progress=False)


def test_a_drape_that_keeps_needing_the_fail_safe_stops_within_its_budget(monkeypatch):
    from tryon.sim.integrator import ImplicitEulerSolver, StepStats

    def crawling(self, state, dt, control=None):  # every step needs the fail-safe, the cloth creeps on
        self.last_collision = col.CollisionReport(constraints=col.Contacts(
            idx=np.array([[3, 4, 5, -1]]), w=np.array([[1.0, -0.5, -0.5, 0.0]]), n=np.array([[0.0, 0.0, 1.0]]),
            kind=np.array([col.VF_OBSTACLE])), zones=1)
        v = torch.zeros_like(state.v)
        v[:, 2] = -0.01
        return type(state)(state.x + dt * v, v, state.t + dt), StepStats(substeps=3, fallback=True)

    monkeypatch.setattr(ImplicitEulerSolver, "step", crawling)
    body = _sphere()
    with pytest.raises(SimulationError, match=rf"makes no progress.*failed in {pipeline.MAX_FAILSAFE_STEPS} steps.*1 impacts"):
        pipeline.simulate_drape(_request(), _patch(1.15), body, body, progress=False)


def test_a_drape_past_its_time_limit_stops_with_where_it_is(monkeypatch):
    import time as _time

    from tryon.sim.integrator import ImplicitEulerSolver

    real = ImplicitEulerSolver.step

    def slow(self, state, dt, control=None):  # every step as slow as a crawling collision response
        _time.sleep(0.05)
        return real(self, state, dt, control)

    monkeypatch.setattr(ImplicitEulerSolver, "step", slow)
    body = _sphere()
    req = _request()
    req.time_limit_s = 0.12
    with pytest.raises(SimulationError, match=r"ran past its time limit of 0.12 s at t=0\.\d+s after \d+ steps.*fastest "
                                              r"\d+\.\d+ m/s at \d+ at.*0 fail-safe and 0 retried steps, slowest step"):
        pipeline.simulate_drape(req, _patch(1.15), body, body, progress=False)
    with pytest.raises(TryonError, match="time limit"):
        DrapeRequest(Measurements(height_cm=170, weight_kg=65, gender="female"), time_limit_s=0.0).validate()


def test_cloth_flung_implausibly_fast_is_redone_and_reported(monkeypatch):
    from tryon.sim.integrator import ImplicitEulerSolver

    real = ImplicitEulerSolver.step
    calls = {"n": 0}

    def flinging(self, state, dt, control=None):
        out, st = real(self, state, dt, control)
        calls["n"] += 1
        if calls["n"] == 3:  # one step's response throws a vertex away at 80 m/s
            v = out.v.clone()
            v[7] = torch.tensor([80.0, 0.0, 0.0], dtype=v.dtype)
            out = type(out)(out.x, v, out.t)
        return out, st

    monkeypatch.setattr(ImplicitEulerSolver, "step", flinging)
    body = _sphere()
    x, _, _, stats, _ = pipeline.simulate_drape(_request(), _patch(1.15), body, body, progress=False)
    rec = stats["speed_recoveries"]
    assert len(rec) == 1 and rec[0]["speed_m_s"] == 80.0 and rec[0]["vertices"][0] == 7
    assert rec[0]["recovered_speed_m_s"] < pipeline.PLAUSIBLE_SPEED
    assert np.isfinite(x).all() and np.abs(x[:, :2]).max() < 0.2  # nothing left flying


def test_a_thin_man_in_a_loose_size_drapes_without_his_bodys_drop():
    """A 171 cm, 53 kg man in the T-shirt S (its fit model is 9 cm away at the shoulders):
    a 0.4 s morph of that change flung the sleeves (6.9 m/s) and stopped the drape. Most of
    it is the body under the T-shirt dropping 7 cm as a whole, which the morph leaves out
    (and the garment gets back): the rest drapes at MORPH_SPEED in the shortest morph."""
    req = DrapeRequest(Measurements(height_cm=170.8, weight_kg=52.9, gender="male"), garment="tshirt", size="S",
                       edge_length=COARSE)
    result = drape(req, progress=False)
    m = result.metrics
    assert -0.09 < m["body_shift_m"][2] < -0.05 and max(abs(m["body_shift_m"][0]), abs(m["body_shift_m"][1])) < 0.01
    assert m["morph_s"] < 0.6
    assert m["settled"] and m["penetration_pct"] == 0.0 and m["self_intersections"] == 0
    assert len(m["speed_recoveries"]) <= 1 and m["max_strain"] < 0.4
    # the garment is on the person, not where the morphed body was simulated
    assert np.abs(result.frames[-1] - result.x).max() < 1e-9
    assert 0.0 < m["min_skin_distance_mm"] < 8.0 and m["mean_skin_distance_mm"] < 35.0


def test_the_morph_lasts_as_long_as_the_body_change_needs():
    start = np.zeros((4, 3))
    assert pipeline.morph_duration(start, start) == pipeline.MIN_MORPH_TIME
    far = start + np.array([0.0, 0.0, 0.09])
    assert pipeline.morph_duration(start, far) == pytest.approx(0.09 / pipeline.MORPH_SPEED)
    assert pipeline.morph_duration(start, start + 5.0) == pipeline.MAX_MORPH_TIME
    assert pipeline.morph_duration(start, far, requested=0.3) == 0.3
    # only the body under the garment paces it: a foot far below a T-shirt does not
    feet = start.copy()
    feet[3] = [0.0, 0.0, 0.15]
    near = pipeline.body_near_garment(start + np.array([[0.0, 0.0, 1.0]] * 3 + [[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.02]]))
    assert near.tolist() == [True, True, True, False]
    assert pipeline.morph_duration(start, feet, near=near) == pipeline.MIN_MORPH_TIME
    assert pipeline.morph_duration(start, feet) == pytest.approx(0.15 / pipeline.MORPH_SPEED)


def test_a_top_that_sews_through_itself_is_dressed_again_with_the_arms_further_out(monkeypatch, size_m_man):
    shape, m = size_m_man
    calls, bodies = [], []

    class Dressed:
        def __init__(self, crossings):
            self.stats = {"self_intersections": crossings}

    def fake_dress(pattern, body, fabric, edge_length, progress=True):
        d = body.heads["wrist.L"] - body.heads["upperarm01.L"]
        bodies.append(body)
        calls.append(np.degrees(np.arctan2(abs(d[0]), -d[2])))
        return Dressed(38 if len(calls) == 1 else 0)

    monkeypatch.setattr(pipeline, "dress_cached", fake_dress)
    start, garment = pipeline.dress_on_fit_model(draft("tshirt", m, size="M"), shape, m["crotch_height"], None, COARSE)
    assert len(calls) == 2 and garment.stats["self_intersections"] == 0
    assert abs(calls[0] - 45.0) < 2.0 and abs(calls[1] - pipeline.DRESS_ARM_ANGLES[1]) < 2.0
    assert garment.stats["dress_arm_angle_deg"] == pipeline.DRESS_ARM_ANGLES[1] and start is bodies[-1]
    # a garment without sleeves is not dressed again: wider arms cannot untangle it
    calls.clear()
    pipeline.dress_on_fit_model(draft("skirt", m, size="M"), shape, m["crotch_height"], None, COARSE)
    assert len(calls) == 1


def test_a_size_far_too_small_for_the_body_is_refused_with_the_girths():
    req = DrapeRequest(Measurements(height_cm=165, bmi=36, gender="female"), garment="tshirt", size="S")
    with pytest.raises(TryonError, match=r"size S is too small.*bust / chest.*try size X?X?L.*--allow-tight"):
        drape(req, progress=False)
    # the drape matrix drapes such a body made to measure and records why
    from tryon.sizing.chart import MADE_TO_MEASURE, chart_size, too_small_for

    size, why = chart_size("trousers", {"chest_cm": 145, "waist_cm": 146, "hip_cm": 148}, "male")
    assert size == MADE_TO_MEASURE and "hip" in why
    assert chart_size("tshirt", {"chest_cm": 120, "waist_cm": 108, "hip_cm": 127}, "female") == ("XXL", None)
    # a chest beyond the chart's largest size (men's XXL: up to 129 cm) is made to measure
    size, why = chart_size("tshirt", {"chest_cm": 143.8, "waist_cm": 139.7, "hip_cm": 139.8}, "male")
    assert size == MADE_TO_MEASURE and "beyond the size chart" in why and "up to 129 cm" in why
    # a T-shirt whose chest would stretch over this man but whose hem would not go over his hip
    size, why = chart_size("tshirt", {"chest_cm": 128, "waist_cm": 140, "hip_cm": 148}, "male")
    assert size == MADE_TO_MEASURE and "hip is 148 cm" in why and "chest with ease" in why
    # a skirt whose hip would stretch over this body but whose waistband would not close:
    # the next size up; a waist beyond the chart's largest (women's XXL: 115 cm) made to measure
    body = {"chest_cm": 96, "waist_cm": 95, "hip_cm": 100}
    assert chart_size("skirt", body, "female") == ("L", None)
    assert "waist is 95 cm" in too_small_for("skirt", "M", "female", body)
    size, why = chart_size("skirt", {"chest_cm": 130, "waist_cm": 132, "hip_cm": 138}, "female")
    assert size == MADE_TO_MEASURE and "waist, 132 cm, is beyond the size chart" in why
    # a belly fuller than the skirt between its waist and hip, though band and seat close;
    # without the navel girth it is XXL
    full = {"chest_cm": 128, "waist_cm": 114, "hip_cm": 138.5}
    assert chart_size("skirt", full, "female") == ("XXL", None)
    size, why = chart_size("skirt", {**full, "waist_navel_cm": 137}, "female")
    assert size == MADE_TO_MEASURE and "belly at the navel" in why and "137 cm" in why
    assert chart_size("tshirt", {**full, "waist_navel_cm": 137}, "female")[0] == "XXL"  # straight, 139 cm
    # the demo man (172 cm, 84 kg) on Anny's average shape, in the trouser cases' size M: its
    # band 14 % under his waist still closes (the ANSUR II prior's body has a 94 cm waist, 8 %)
    from tryon.body.fit import fit_body

    demo = fit_body(Measurements(height_cm=172, weight_kg=84, gender="male"), prior=False).achieved
    made = 100 * Ease().waistband + size_measurements("M", "male")["waist_cm"]
    assert 1.10 < demo["waist_cm"] / made < 1.0 + WAISTBAND_STRETCH - 0.005
    assert size_too_small("trousers", "M", size_measurements("M", "male"), demo) is None


def _relax_verdicts(speeds: list[float], until_slowing_stops: bool = True, fallback_at: int = 0) -> int | None:
    """The step (1-based) at which RelaxTest stops a relaxation whose fastest vertex moves
    at `speeds` (the step `fallback_at` fell back: its contacts unresolved), or None."""
    from types import SimpleNamespace

    from tryon.drape.dress import RelaxTest
    from tryon.sim.integrator import StepStats

    test = RelaxTest(rest_speed=0.02, until_slowing_stops=until_slowing_stops)
    for k, s in enumerate(speeds, 1):
        v = torch.tensor([[s, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
        if test(SimpleNamespace(state=SimpleNamespace(v=v), stats=StepStats(fallback=k == fallback_at))):
            assert test.stuck == (k == fallback_at)
            return k
    return None


def test_relaxation_stops_on_drift_but_not_while_the_garment_is_still_fast():
    drift = [0.9, 0.5, 0.3, 0.2, 0.17] + [0.15] * 30
    assert _relax_verdicts(drift) == 11  # 0.15 m/s five steps running: stopped slowing, and slow (drift, jitter)
    assert _relax_verdicts(drift, until_slowing_stops=False) is None  # closed placements relax to rest
    fast = [1.0] * 5 + [0.97] * 30
    assert _relax_verdicts(fast) is None  # still spending strain at ~1 m/s: keep relaxing
    assert _relax_verdicts([0.5, 0.2, 0.1, 0.05, 0.01]) == 5  # at rest
    assert _relax_verdicts([0.5, 0.0, 0.0, 0.0, 0.0], fallback_at=2) == 2  # stuck in a contact: no use going on


def test_welded_trousers_between_full_thighs_leave_the_skin_without_crossing_themselves():
    """Made-to-measure trousers for a 175 cm, 138 kg woman, thighs 2 cm apart: pushed out
    of the skin to the placement clearance, the two inner legs pass through each other
    below the crotch; pushed out only `TIGHT_CLEARANCE`, they do not."""
    from tryon.body.fit import fit_body
    from tryon.body.measure import made_to_measure_measurements
    from tryon.drape.dress import TIGHT_CLEARANCE, _welded_clear_of_skin, clear_of_skin

    person = fit_body(Measurements(height_cm=175, weight_kg=137.8, gender="female"))
    m = made_to_measure_measurements(person.shape)
    body = posed_body(person.shape, pipeline.drape_pose(person.shape, "trousers"), m["crotch_height"])
    mesh = triangulate_pattern(draft("trousers", m, size="made-to-measure", meta={"gender": "female"}), 0.012)
    x = place_pattern(mesh, body, 0.012)
    pos, faces, _, _ = merge_stitched(mesh, x)
    edges = geo.mesh_edges(faces)

    def crossings(p):
        return len(geo.edge_face_intersections(p, edges, p, faces, True))

    assert crossings(pos) == 0
    assert crossings(clear_of_skin(pos, body, 0.012)[0]) > 10
    out, pushed, used = _welded_clear_of_skin(pos, faces, edges, body, 0.012)
    assert used == TIGHT_CLEARANCE and pushed > 0 and crossings(out) == 0
    d, _, _ = geo.nearest_surface_points(out, body.vertices, body.faces)
    assert d.min() > 0.0  # out of the skin


def test_a_seam_end_the_skin_holds_open_is_told_from_an_open_seam():
    """`held_open_by_skin`: the stitches still open must all lie on the skin at both ends
    (then sewing may weld them), and every other stitch must be shut."""
    import trimesh

    from tryon.drape.dress import DRESSING_THICKNESS, held_open_by_skin

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    body = BodyPose(np.asarray(sphere.vertices), np.asarray(sphere.faces, np.int64), np.zeros(len(sphere.vertices), np.int64), {})

    def on_skin(theta, lift=DRESSING_THICKNESS):
        return (0.1 + lift) * np.array([np.cos(theta), np.sin(theta), 0.0])

    held = np.stack([on_skin(0.0), on_skin(0.12),  # a 1.2 cm gap over the skin
                     on_skin(1.0), on_skin(1.0) + [0, 0, 0.001]])  # a shut stitch
    stitches = np.array([[0, 1], [2, 3]])
    assert held_open_by_skin(held, stitches, body, shut=0.003)
    lifted = held.copy()
    lifted[1] = on_skin(0.12, lift=0.02)  # one end 2 cm off the skin: the cloth holds it open
    assert not held_open_by_skin(lifted, stitches, body, shut=0.003)
    other_open = held.copy()
    other_open[3] = on_skin(1.0, lift=0.02)  # another seam still open off the skin
    assert not held_open_by_skin(other_open, stitches, body, shut=0.003)


def test_trousers_whose_panels_smoothing_tears_apart_are_welded_as_placed():
    """A 192 cm, 148 kg man's made-to-measure trousers: smoothing each panel's folds at the
    crotch on its own tears the crotch seams 4 cm apart (at 2 cm edges; 7 cm at 1.2), and
    sewing them from there took a minute a step. They are welded as placed and the welded
    garment is smoothed instead."""
    from tryon.body.fit import fit_body
    from tryon.body.measure import made_to_measure_measurements
    from tryon.drape.dress import _unfold, stitch_gap
    from tryon.sim.geometry import mesh_edges

    shape = fit_body(Measurements(height_cm=192, weight_kg=147.5, gender="male")).shape
    m = made_to_measure_measurements(shape)
    body = posed_body(shape, pipeline.drape_pose(shape, "trousers"), m["crotch_height"])
    pattern = draft("trousers", m, size="made-to-measure", meta={"gender": "male"})
    mesh = triangulate_pattern(pattern, 0.02)
    placed = place_pattern(mesh, body, 0.012)
    torn, _ = _unfold(placed, mesh.faces, mesh_edges(mesh.faces), mesh.panel_of_vertex, body, 0.012)
    assert stitch_gap(placed, mesh.stitches) <= SEAMS_CLOSED < stitch_gap(torn, mesh.stitches)  # the case
    garment = dress_pattern(pattern, body, load_fabric("gray-interlock"), 0.02, progress=False, mesh=mesh)
    assert garment.stats["sew_steps"] == 0 and garment.stats["self_intersections"] == 0
    assert penetration(garment.vertices, body.vertices, body.faces)["penetration_pct"] == 0.0


def test_panels_laid_along_the_surface_reach_less_far_down_over_a_slope():
    """`_z_along_surface`: a column down a front that leans out by `a` per metre covers
    sqrt(1 + a^2) metres of cloth per metre of height; a column at the side, where the
    half width does not change, runs straight down."""
    from tryon.drape.dress import _z_along_surface

    class Tube:
        def at(self, z, what):
            z = np.asarray(z, float)
            return {"half": np.full_like(z, 0.15), "yc": np.zeros_like(z), "front": 0.10 + 0.5 * (1.5 - z)}[what]

    s = np.array([0.1, 0.3, 0.5, 0.3])
    frac = np.array([0.0, 0.0, 0.0, 1.0])
    z = _z_along_surface(s, frac, 1.5, Tube(), "front")
    np.testing.assert_allclose(z[:3], 1.5 - s[:3] / np.sqrt(1.25), atol=1e-9)
    assert z[3] == pytest.approx(1.2, abs=1e-9)
