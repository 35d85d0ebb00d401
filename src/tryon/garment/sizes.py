"""Standard sizes XS-XXL: body measurements a size is drafted for.

Chest / bust girth intervals are EN 13402-3's letter codes (data/size_chart.json cites
the source); waist, hip and stature for each letter follow a documented regular-figure
assumption, since the letter-code table gives only the chest. A size's "fit model" is
the Anny body fitted to these measurements: garments are drafted and dressed on it.
"""

from __future__ import annotations

import json
from functools import lru_cache
from importlib import resources

from tryon.errors import TryonError

SIZES = ("XS", "S", "M", "L", "XL", "XXL")


@lru_cache(maxsize=1)
def size_chart() -> dict:
    return json.loads(resources.files("tryon.garment").joinpath("data/size_chart.json").read_text())


def size_measurements(size: str, gender: str) -> dict[str, float]:
    """Body measurements (cm) of a standard size: chest (interval midpoint), waist, hip, height."""
    chart = size_chart()
    if gender not in ("male", "female"):
        raise TryonError(f"gender must be 'male' or 'female' for a standard size, got {gender!r}")
    key = size.upper()
    if key not in chart[gender]:
        raise TryonError(f"unknown size {size!r}; standard sizes: {', '.join(SIZES)}")
    lo, hi = chart[gender][key]["chest_cm"]
    chest = 0.5 * (lo + hi)
    sec = chart["secondary"][gender]
    return {
        "chest_cm": chest,
        "waist_cm": chest + sec["waist_minus_chest"],
        "hip_cm": chest + sec["hip_minus_chest"],
        "height_cm": float(sec["height_cm"]),
    }




def largest_girth(gender: str, girth: str) -> float:
    """The largest chest, waist or hip (cm) the chart's largest size is for: the top of
    its EN 13402-3 chest interval, moved by the regular figure's waist or hip offset."""
    chart = size_chart()
    if gender not in ("male", "female"):
        raise TryonError(f"gender must be 'male' or 'female' for a standard size, got {gender!r}")
    top = float(chart[gender][SIZES[-1]]["chest_cm"][1])
    return top if girth == "chest" else top + chart["secondary"][gender][f"{girth}_minus_chest"]
