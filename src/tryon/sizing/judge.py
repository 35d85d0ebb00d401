"""Whether one size fits, from its drape, and which of several sizes to recommend.

Each garment region (its pattern panels) is scored by ease (mean distance from the skin,
cm), strain (area-weighted mean, and the share of area stretched beyond `OVERSTRAIN`) and
contact pressure. A size fits when less than `MAX_OVERSTRAINED_PCT` of its area is
overstretched and no region clings tighter than `MIN_EASE_CM`; among the sizes that fit,
the one whose torso ease is nearest `TARGET_EASE_CM` (a regular fit) is recommended. If
none fits, the largest is named, with the reason."""

from __future__ import annotations

import math

import numpy as np

from tryon.garment.drafts import Ease

OVERSTRAIN = 0.10
MAX_OVERSTRAINED_PCT = 10.0
MIN_EASE_CM = 0.5
# A regular fit: the draft's own chest ease (10 cm of girth) spread round the body, about
# 1.6 cm off the skin; the fit a size has on the body it was drafted for.
TARGET_EASE_CM = 100.0 * Ease().chest / (2.0 * math.pi)
TORSO = ("front", "back")


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


def judge(size: str, garment, skin_distance: np.ndarray, strain: np.ndarray, pressure: np.ndarray | None = None,
          strain_reliable: bool = True) -> dict:
    """Whether `size` fits, from its drape's distance to the skin per vertex (m), strain
    per face and contact pressure per vertex (Pa; None when not known). A network's
    prediction (`strain_reliable` False) is judged by its ease alone: millimetres of noise
    in its vertices read as several % of strain, so its overstretched area says nothing
    until refinement."""
    regions = region_scores(garment, skin_distance, strain, pressure)
    torso = [regions[r] for r in TORSO if r in regions]
    ease = float(np.mean([r["ease_cm"] for r in torso])) if torso else float("nan")
    area = rest_face_areas(garment)
    over = 100.0 * float(area[strain > OVERSTRAIN].sum() / area.sum())
    tight = [name for name, r in regions.items() if r["ease_cm"] < MIN_EASE_CM]
    why = []
    if strain_reliable and over >= MAX_OVERSTRAINED_PCT:
        why.append(f"{over:.0f} % of its area is stretched beyond {100 * OVERSTRAIN:.0f} %")
    if tight:
        why.append(f"it clings to the skin at the {', '.join(tight)} (ease under {MIN_EASE_CM} cm)")
    return {"size": size, "fits": not why, "why_not": why, "torso_ease_cm": ease, "overstrained_area_pct": over,
            "max_strain_pct": 100 * float(strain.max()), "penetration_pct": 100.0 * float((skin_distance < 0).mean()),
            "regions": regions}


def judge_size(size: str, result, strain_reliable: bool = True) -> dict:
    """`judge` of a drape (`tryon.drape.DrapeResult`, its strain and pressure measured)."""
    from tryon.sim.geometry import nearest_surface_points

    d, _, _ = nearest_surface_points(result.x, result.body_vertices, result.body_faces)
    return dict(judge(size, result.garment, d, np.asarray(result.strain), np.asarray(result.pressure), strain_reliable),
                timings=result.timings)


def undrapeable(size: str, reason: str) -> dict:
    """The judgement of a size the simulator could not drape on the body."""
    nan = float("nan")
    return {"size": size, "fits": False, "why_not": [f"the simulator could not drape it ({reason.split(';')[0]})"],
            "torso_ease_cm": nan, "overstrained_area_pct": nan, "max_strain_pct": nan, "penetration_pct": nan,
            "regions": {}, "timings": {}}


def recommend(judged: list[dict]) -> tuple[str, list[str]]:
    """(the recommended size, the reasons). Sizes judged on the refined or simulated drape
    are the candidates; sizes judged on a prediction only count when nothing was refined."""
    settled = [j for j in judged if j.get("judged_on") != "prediction"] or judged
    fitting = [j for j in settled if j["fits"]]
    if not fitting:
        last = settled[-1]
        return last["size"], [f"no size fits: even {last['size']} does not, since " + "; ".join(last["why_not"])]
    best = min(fitting, key=lambda j: abs(j["torso_ease_cm"] - TARGET_EASE_CM))
    stretch = ("strain judged after refinement" if best.get("judged_on") == "prediction"
               else f"{best['overstrained_area_pct']:.0f} % of the area overstretched")
    reasons = [f"{best['size']}: torso ease {best['torso_ease_cm']:.1f} cm (a regular fit is about {TARGET_EASE_CM:.1f} cm), "
               f"{stretch}"]
    for j in judged:
        if j is best:
            continue
        if j.get("not_refined"):  # predicted only, beside where refinement stopped
            verdict = "does not fit (" + "; ".join(j["why_not"]) + ")" if j["why_not"] else "fits"
            reasons.append(f"{j['size']} was not refined ({j['not_refined']}); its prediction {verdict}, "
                           f"torso ease {j['torso_ease_cm']:.1f} cm")
        elif j["fits"]:
            reasons.append(f"{j['size']} also fits, {'looser' if j['torso_ease_cm'] > best['torso_ease_cm'] else 'closer'}: "
                           f"torso ease {j['torso_ease_cm']:.1f} cm")
        else:
            reasons.append(f"{j['size']} does not fit: " + "; ".join(j["why_not"]))
    return best["size"], reasons
