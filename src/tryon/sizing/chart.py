"""The size a body's girths point to on the size chart, before anything is draped: the
size `tryon drape` is told to refuse (a waistband that cannot close), the larger sizes
that close instead, and the chart's size for a chest girth."""

from __future__ import annotations

from tryon.garment.drafts import DEFINING_GIRTH, WAISTBAND_GARMENTS, size_too_small
from tryon.garment.sizes import SIZES, largest_girth, size_chart, size_measurements

MADE_TO_MEASURE = "MTM"


def chart_size(garment: str, girths: dict, gender: str) -> tuple[str, str | None]:
    """The standard size whose chest (tops) or hip (bottoms) is nearest the body's, or the
    next larger one when that is too small for the body (`tryon drape` refuses it: a
    waistband that cannot close), or made to measure (`MADE_TO_MEASURE`, drafted on the
    body) when every larger size is too, or when that girth (or, for skirts and trousers,
    the waist) is beyond the chart's largest size (`largest_girth`: a 200 cm, 180 kg man's
    144 cm chest in a men's XXL, for up to 129 cm, clung to his front and back with 0.4 cm
    of ease; a 192 cm, 148 kg man's 126 cm waist strained XXL trousers, for up to 117 cm,
    by half); the second item says why."""
    key = f"{DEFINING_GIRTH[garment]}_cm"
    for girth in (DEFINING_GIRTH[garment], *(("waist",) if garment in WAISTBAND_GARMENTS else ())):
        top = largest_girth(gender, girth)
        if girths[f"{girth}_cm"] > top:
            return MADE_TO_MEASURE, (f"this body's {girth}, {girths[f'{girth}_cm']:.0f} cm, is beyond the size chart: its "
                                     f"largest size, {SIZES[-1]}, is for a {girth} of up to {top:.0f} cm")
    nearest = min(SIZES, key=lambda s: abs(size_measurements(s, gender)[key] - girths[key]))
    why = None
    for size in SIZES[SIZES.index(nearest):]:
        too_small = size_too_small(garment, size, size_measurements(size, gender), girths)
        if too_small is None:
            return size, None
        why = why or too_small
    return MADE_TO_MEASURE, why


def too_small_for(garment: str, size: str, gender: str, girths: dict) -> str | None:
    """Why `size` cannot be worn by a body of `girths` (None when it can)."""
    return size_too_small(garment, size.upper(), size_measurements(size.upper(), gender), girths)


def larger_sizes_that_close(garment: str, size: str, gender: str, girths: dict) -> list[str]:
    """The standard sizes above `size` that a body of `girths` can wear."""
    return [s for s in SIZES[SIZES.index(size.upper()) + 1:] if too_small_for(garment, s, gender, girths) is None]


def fitted_girths(fit) -> dict:
    """The chest, waist, hip and (when the fit measured it) waist at the navel (cm) a body
    fit achieved, as `chart_size` takes them."""
    keys = ("chest_cm", "waist_cm", "hip_cm", "waist_navel_cm")
    return {k: float(fit.achieved[k]) for k in keys if k in fit.achieved}


def size_for_chest(chest_cm: float, gender: str) -> str | None:
    """The letter whose chest interval holds chest_cm, or None outside the chart."""
    for name, row in size_chart()[gender].items():
        lo, hi = row["chest_cm"]
        if lo <= chest_cm < hi:
            return name
    return None
