"""What each fabric preset looks like in a render: its colour and, where the fabric has
one, a print (dots, stripes) evaluated on the garment's material coordinates (metres),
so a print follows the cloth as it drapes. Prints are coloured per vertex: features
smaller than about two edge lengths blur."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT = (0.27, 0.45, 0.72)


@dataclass(frozen=True)
class Appearance:
    color: tuple[float, float, float]
    print_color: tuple[float, float, float] | None = None
    print_kind: str = ""          # "dots" or "stripes"
    period_m: float = 0.04
    size: float = 0.3             # share of the period covered (dot radius or stripe width)


# the measured fabrics' look, from their names and descriptions (Wang et al. 2011)
APPEARANCES = {
    "ivory-rib-knit": Appearance((0.93, 0.89, 0.80)),
    "pink-ribbon-brown": Appearance((0.40, 0.26, 0.18), (0.93, 0.62, 0.70), "stripes", 0.06, 0.3),
    "white-dots-on-blk": Appearance((0.06, 0.06, 0.07), (0.95, 0.95, 0.95), "dots", 0.06, 0.25),
    "navy-sparkle-sweat": Appearance((0.12, 0.15, 0.33)),
    "camel-ponte-roma": Appearance((0.74, 0.58, 0.40)),
    "gray-interlock": Appearance((0.56, 0.57, 0.60)),
    "11oz-black-denim": Appearance((0.11, 0.12, 0.15)),
    "white-swim-solid": Appearance((0.93, 0.93, 0.92)),
    "tango-red-jet-set": Appearance((0.80, 0.16, 0.12)),
    "royal-target": Appearance((0.16, 0.27, 0.66)),
    "paper": Appearance((0.95, 0.94, 0.90)),
    "aluminium": Appearance((0.76, 0.77, 0.79)),
}


def appearance(fabric: str) -> Appearance:
    """The preset's look; a fabric file of the user's own is drawn in the default blue."""
    return APPEARANCES.get(fabric, Appearance(DEFAULT))


def fabric_colors(fabric: str, uv: np.ndarray) -> np.ndarray:
    """Per-vertex colours [N,3] of a garment in `fabric` with material coordinates `uv` [N,2] (m)."""
    look = appearance(fabric)
    colors = np.tile(np.asarray(look.color, float), (len(uv), 1))
    if look.print_color is None:
        return colors
    phase = np.mod(np.asarray(uv, float) / look.period_m, 1.0) - 0.5
    if look.print_kind == "dots":
        on = np.hypot(phase[:, 0], phase[:, 1]) < look.size
    else:  # stripes across the grain (v)
        on = np.abs(phase[:, 1]) < 0.5 * look.size
    colors[on] = look.print_color
    return colors
