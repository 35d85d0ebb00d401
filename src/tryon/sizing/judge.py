"""Whether one size fits, from its drape, and which of several sizes to recommend.

Each garment region (its pattern panels) is scored by ease (mean distance from the skin,
cm), strain (area-weighted mean, and the share of area stretched beyond `OVERSTRAIN`) and
contact pressure. A size fits when less than `MAX_OVERSTRAINED_PCT` of its area is
overstretched and no region clings tighter than `MIN_EASE_CM`; among the sizes that fit,
the one whose deciding ease is nearest a regular fit's is recommended. If none fits, the
largest is named, with the reason.

The deciding ease is where the garment's sizes are chosen (`DEFINING_GIRTH`): the torso
(front and back panels) of tops and dresses, against `TARGET_EASE_CM`; the band round the
hip line of skirts and trousers, against `TARGET_HIP_EASE_CM`, with the waistband's ease
reported beside it (`fit_bands`)."""

from __future__ import annotations

import math

import numpy as np

from tryon.garment.drafts import Ease, trouser_inseam

OVERSTRAIN = 0.10
MAX_OVERSTRAINED_PCT = 10.0
MIN_EASE_CM = 0.5
# A regular fit: the draft's own chest ease (10 cm of girth) spread round the body, about
# 1.6 cm off the skin; the fit a size has on the body it was drafted for.
TARGET_EASE_CM = 100.0 * Ease().chest / (2.0 * math.pi)
TORSO = ("front", "back")
# Skirts and trousers: the hip band's ease each size has on the body it was drafted for
# (median over the twelve trouser and six skirt sizes on their fit models, `data/drapes-v3`
# references: 1.33 and 0.91 cm). The skirt's is the draft's 6 cm of hip ease spread round
# the body (0.95 cm); trousers add the seat the crotch extension takes.
TARGET_HIP_EASE_CM = {"skirt": 0.9, "trousers": 1.35}
WAIST_BAND_M = 0.04  # the top of each panel (its waistband), in the panel's material
HIP_BAND_M = 0.05    # the band round the hip line, in the panel's material
LOWER_BODY = ("skirt", "trousers")
LENGTH_NOTE_CM = 2.0  # trouser legs this much longer or shorter than the body's are named in the reasons


def fit_bands(garment) -> dict[str, np.ndarray] | None:
    """Vertex ids of a skirt's or trousers' waistband and of the band round its hip line
    (None for other garments, or a pattern that does not record its fit model's heights).
    Found in each panel's material coordinates: u runs up the grain from the hem, the top
    is the waist, and the hip line lies the fit model's waist-to-hip depth below it."""
    meta = garment.pattern.meta if garment.pattern is not None else {}
    m = meta.get("body_measurements_cm") or {}
    if meta.get("garment") not in LOWER_BODY or "waist_height" not in m or "hip_height" not in m:
        return None
    depth = (m["waist_height"] - m["hip_height"]) / 100.0
    waist, hip = [], []
    for k, panel in enumerate(garment.pattern.panels):
        if tuple(panel.grain) != (0.0, 1.0):  # u is the height up the panel only along a straight grain
            return None
        v = np.unique(garment.faces[garment.face_panel == k])
        u = garment.uv[v, 0]
        top = u.max()
        waist.append(v[u >= top - WAIST_BAND_M])
        hip.append(v[np.abs(u - (top - depth)) <= HIP_BAND_M / 2])
    return {"waist": np.unique(np.concatenate(waist)), "hip": np.unique(np.concatenate(hip))}  # seams: once


def deciding_ease(garment, skin_distance: np.ndarray, regions: dict) -> dict:
    """Where the size is judged (`decided_by`), its ease (`ease_cm`) and a regular fit's
    (`target_ease_cm`); the torso ease (NaN without front and back panels); for skirts and
    trousers the waistband's and the hip band's ease."""
    torso = [regions[r] for r in TORSO if r in regions]
    torso_ease = float(np.mean([r["ease_cm"] for r in torso])) if torso else float("nan")
    bands = fit_bands(garment)
    if bands is None or not len(bands["hip"]):
        return {"decided_by": "torso", "ease_cm": torso_ease, "target_ease_cm": TARGET_EASE_CM,
                "torso_ease_cm": torso_ease}
    band_ease = {k: float(100 * skin_distance[v].mean()) if len(v) else float("nan") for k, v in bands.items()}
    target = TARGET_HIP_EASE_CM[garment.pattern.meta["garment"]]
    return {"decided_by": "hip", "ease_cm": band_ease["hip"], "target_ease_cm": target,
            "torso_ease_cm": torso_ease, "waist_ease_cm": band_ease["waist"], "hip_ease_cm": band_ease["hip"]}


def rest_face_areas(garment) -> np.ndarray:
    """The rest (material) area of each face of a dressed garment (m^2)."""
    e1, e2 = garment.corner_uv[:, 1] - garment.corner_uv[:, 0], garment.corner_uv[:, 2] - garment.corner_uv[:, 0]
    return np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) / 2


def region_scores(garment, skin_distance: np.ndarray, strain: np.ndarray,
                  pressure: np.ndarray | None) -> dict[str, dict[str, float]]:
    """Per panel: ease (cm), mean strain (%), overstrained area (%) and, when the contact
    pressure per vertex (Pa) is known, its mean (kPa). `skin_distance` (m) per vertex."""
    names = [p.name for p in garment.pattern.panels]
    area = rest_face_areas(garment)
    out = {}
    for k, name in enumerate(names):
        f = garment.face_panel == k
        v = np.unique(garment.faces[f])
        a = area[f]
        out[name] = {"ease_cm": float(100 * skin_distance[v].mean()),
                     "mean_strain_pct": float(100 * (strain[f] * a).sum() / a.sum()),
                     "overstrained_area_pct": float(100 * a[strain[f] > OVERSTRAIN].sum() / a.sum())}
        if pressure is not None:
            out[name]["mean_pressure_kpa"] = float(pressure[v].mean() / 1000.0)
    return out


def inseam_excess_cm(garment, body_m: dict | None) -> dict:
    """For trousers and the wearer's drafting measurements `body_m` (m): how much longer
    (cm; negative: shorter) the legs' inseam is than the one drafted for this body."""
    meta = garment.pattern.meta if garment.pattern is not None else {}
    drafted = meta.get("body_measurements_cm") or {}
    if meta.get("garment") != "trousers" or body_m is None or not {"crotch_height", "ankle_height"} <= set(drafted):
        return {}
    own = trouser_inseam({k: drafted[k] / 100.0 for k in ("crotch_height", "ankle_height")})
    return {"inseam_excess_cm": 100.0 * (own - trouser_inseam(body_m))}


def judge(size: str, garment, skin_distance: np.ndarray, strain: np.ndarray, pressure: np.ndarray | None = None,
          strain_reliable: bool = True, body_m: dict | None = None) -> dict:
    """Whether `size` fits, from its drape's distance to the skin per vertex (m), strain
    per face and contact pressure per vertex (Pa; None when not known). A network's
    prediction (`strain_reliable` False) is judged by its ease alone: millimetres of noise
    in its vertices read as several % of strain, so its overstretched area says nothing
    until refinement. `body_m`: the wearer's drafting measurements (m), for the trousers'
    leg length."""
    regions = region_scores(garment, skin_distance, strain, pressure)
    area = rest_face_areas(garment)
    over = 100.0 * float(area[strain > OVERSTRAIN].sum() / area.sum())
    tight = [name for name, r in regions.items() if r["ease_cm"] < MIN_EASE_CM]
    why = []
    if strain_reliable and over >= MAX_OVERSTRAINED_PCT:
        why.append(f"{over:.0f} % of its area is stretched beyond {100 * OVERSTRAIN:.0f} %")
    if tight:
        why.append(f"it clings to the skin at the {', '.join(tight)} (ease under {MIN_EASE_CM} cm)")
    return {"size": size, "fits": not why, "why_not": why, **deciding_ease(garment, skin_distance, regions),
            "overstrained_area_pct": over, "max_strain_pct": 100 * float(strain.max()),
            "penetration_pct": 100.0 * float((skin_distance < 0).mean()), "regions": regions,
            **inseam_excess_cm(garment, body_m)}


def judge_size(size: str, result, strain_reliable: bool = True) -> dict:
    """`judge` of a drape (`tryon.drape.DrapeResult`, its strain and pressure measured)."""
    from tryon.sim.geometry import nearest_surface_points

    d, _, _ = nearest_surface_points(result.x, result.body_vertices, result.body_faces)
    body_m = None
    pattern = result.garment.pattern
    if pattern is not None and pattern.meta.get("garment") == "trousers" and result.person is not None:
        from tryon.body.measure import drafting_measurements

        body_m = drafting_measurements(result.person.shape)
    return dict(judge(size, result.garment, d, np.asarray(result.strain), np.asarray(result.pressure), strain_reliable,
                      body_m), timings=result.timings)


def undrapeable(size: str, reason: str, garment: str = "tshirt") -> dict:
    """The judgement of a size of `garment` the simulator could not drape on the body."""
    nan = float("nan")
    lower = garment in LOWER_BODY
    return {"size": size, "fits": False, "why_not": [f"the simulator could not drape it ({reason.split(';')[0]})"],
            "decided_by": "hip" if lower else "torso", "ease_cm": nan,
            "target_ease_cm": TARGET_HIP_EASE_CM[garment] if lower else TARGET_EASE_CM,
            "torso_ease_cm": nan, "overstrained_area_pct": nan, "max_strain_pct": nan, "penetration_pct": nan,
            "regions": {}, "timings": {}}


def ease_of(j: dict) -> float:
    """A judgement's deciding ease (cm; the torso's in judgements kept from before)."""
    return j.get("ease_cm", j.get("torso_ease_cm", float("nan")))


def target_of(j: dict) -> float:
    return j.get("target_ease_cm", TARGET_EASE_CM)


def ease_words(j: dict) -> str:
    return f"{j.get('decided_by', 'torso')} ease {ease_of(j):.1f} cm"


def length_words(j: dict) -> str:
    """Trouser legs noticeably longer or shorter than the wearer's, in words ('' otherwise)."""
    excess = j.get("inseam_excess_cm")
    if excess is None or not math.isfinite(excess) or abs(excess) < LENGTH_NOTE_CM:
        return ""
    return (f"; its legs are {excess:.1f} cm longer than this body's inseam (hem them up)" if excess > 0
            else f"; its legs are {-excess:.1f} cm shorter than this body's inseam")


def recommend(judged: list[dict]) -> tuple[str, list[str]]:
    """(the recommended size, the reasons). Sizes judged on the refined or simulated drape
    are the candidates; sizes judged on a prediction only count when nothing was refined."""
    settled = [j for j in judged if j.get("judged_on") != "prediction"] or judged
    fitting = [j for j in settled if j["fits"]]
    if not fitting:
        last = settled[-1]
        return last["size"], [f"no size fits: even {last['size']} does not, since " + "; ".join(last["why_not"])]
    best = min(fitting, key=lambda j: abs(ease_of(j) - target_of(j)))
    stretch = ("strain judged after refinement" if best.get("judged_on") == "prediction"
               else f"{best['overstrained_area_pct']:.0f} % of the area overstretched")
    waist = f", waistband ease {best['waist_ease_cm']:.1f} cm" if "waist_ease_cm" in best else ""
    reasons = [f"{best['size']}: {ease_words(best)} (a regular fit is about {target_of(best):.1f} cm){waist}, {stretch}"
               + length_words(best)]
    for j in judged:
        if j is best:
            continue
        if j.get("not_refined"):  # predicted only, beside where refinement stopped
            verdict = "does not fit (" + "; ".join(j["why_not"]) + ")" if j["why_not"] else "fits"
            reasons.append(f"{j['size']} was not refined ({j['not_refined']}); its prediction {verdict}, {ease_words(j)}")
        elif j["fits"]:
            reasons.append(f"{j['size']} also fits, {'looser' if ease_of(j) > ease_of(best) else 'closer'}: "
                           f"{ease_words(j)}")
        else:
            reasons.append(f"{j['size']} does not fit: " + "; ".join(j["why_not"]))
    return best["size"], reasons
