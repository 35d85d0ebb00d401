"""Parametric pattern drafts from body measurements and ease.

Each draft takes `drafting_measurements` of a body (metres, see tryon.body.measure) and
an `Ease` and returns a `Pattern` whose panels carry their placement on the body:
`tshirt`, `longsleeve`, `skirt`, `trousers`, `dress`. The constructions are simplified
block patterns in the usual way of flat pattern making (Aldrich, "Metric Pattern Cutting"):
a straight bodice block with a curved armhole and neckline, a sleeve whose cap length
matches the armhole, a two-panel skirt, a four-panel trouser with crotch extensions.

Panel coordinates: x across (the body's left towards +x on front panels, seen from the
outside), y up, origin at the hem centre; all outlines counter-clockwise.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from tryon.errors import TryonError
from tryon.garment.pattern import SEAM_EASE, Edge, Panel, Pattern, Seam

GARMENTS = ("tshirt", "longsleeve", "skirt", "trousers", "dress")


@dataclass
class Ease:
    """Ease (m) added to body girths, and style lengths."""

    chest: float = 0.10
    waist: float = 0.04
    hip: float = 0.06
    bicep: float = 0.08
    neck_width: float = 0.04
    short_sleeve: float = 0.20
    top_below_hip: float = 0.04
    skirt_below_knee: float = 0.02
    waistband: float = 0.01  # trousers: a waistband fits close, so that it holds them up


# A garment is far too small for a body whose girth at the garment's defining girth (chest
# for tops and dresses, hip for skirts and trousers, as sizes are chosen) exceeds the
# garment's finished girth by more than this: a BMI-45 woman's 150 cm bust in a women's
# XXL T-shirt (135 cm with ease, 11 % less) draped only by stretching the cloth 35 %.
WEAR_STRETCH = 0.10
DEFINING_GIRTH = {"tshirt": "chest", "longsleeve": "chest", "dress": "chest", "skirt": "hip", "trousers": "hip"}
# Skirts and trousers hang from a waistband pinned round the waist: a band more than this
# smaller than the waist does not close (the same woman's 132 cm waist in the XXL's 110 cm
# band: 55 % strain at the band and cloth pressed into itself). A belted or elastic band
# gives more than the cloth below it; a man of 172 cm and 84 kg wears size M trousers
# (14 % over) as the trouser cases of the drape tests do.
WAISTBAND_STRETCH = 0.15
WAISTBAND_GARMENTS = ("skirt", "trousers")
# Tops and dresses also go over the hip: a top's body runs straight from the chest to a hem
# below the hip (the larger of chest and hip with ease), a dress's skirt from the hip. A
# 200 cm, 180 kg man's 148 cm hip in a men's XXL T-shirt (134 cm there) strained it 57-60 %
# and a denim long sleeve could not be draped.
OVER_THE_HIP = ("tshirt", "longsleeve", "dress")
# Skirts, trousers and dresses narrow from the hip line up to the waist; the belly at the
# navel (ANSUR II's waist) lies about a third of the way down (`NAVEL_FRACTION`). A body
# fuller there than the garment by more than `WEAR_STRETCH` presses the cloth into itself:
# the 175 cm, 138 kg woman of the ANSUR II prior (natural waist 122 cm, 137 cm at the
# navel, hip 141 cm) strained XXL trousers and skirts 56 % over the belly and stuck a knit
# skirt in the fail-safe, though her waist closed the band and her hip the seat. Checked
# when the body's girth at the navel is known (`waist_navel_cm`).
NAVEL_FRACTION = 1.0 / 3.0
BELLY_GARMENTS = ("skirt", "trousers", "dress")


def finished_girth(garment: str, girth: str, size_girths: dict) -> float:
    """The garment's girth (cm) at 'chest', 'hip' or 'waist': the size's with `Ease`."""
    ease = Ease()
    allowance = {"chest": ease.chest, "hip": ease.hip,
                 "waist": ease.waistband if garment == "trousers" else ease.waist}[girth]
    made = size_girths[f"{girth}_cm"] + 100.0 * allowance
    if girth == "hip" and garment in ("tshirt", "longsleeve"):  # straight from the chest down
        made = max(made, finished_girth(garment, "chest", size_girths))
    return made


def girth_at_navel(garment: str, size_girths: dict) -> float:
    """The garment's girth (cm) at the body's navel: between its waist and hip for skirts,
    trousers and dresses, its straight body (hip) for tops."""
    hip = finished_girth(garment, "hip", size_girths)
    if garment not in BELLY_GARMENTS:
        return hip
    waist = finished_girth(garment, "waist", size_girths)
    return waist + NAVEL_FRACTION * (hip - waist)


def size_too_small(garment: str, size: str, size_girths: dict, body_girths: dict) -> str | None:
    """Why a standard size is too small for a body (None when it fits): the body's girth at
    the garment's `DEFINING_GIRTH` beyond the garment's finished girth there by more than
    `WEAR_STRETCH` (for tops and dresses, also at the hip: `OVER_THE_HIP`), or, for skirts
    and trousers, its waist beyond the waistband by more than `WAISTBAND_STRETCH`; when the
    body's `waist_navel_cm` is given, its belly beyond the garment's girth there
    (`girth_at_navel`) by more than `WEAR_STRETCH`. Girths in cm, keyed 'chest_cm',
    'waist_cm', 'hip_cm' (and 'waist_navel_cm')."""
    checks = [(DEFINING_GIRTH[garment], WEAR_STRETCH)]
    if garment in OVER_THE_HIP:
        checks.append(("hip", WEAR_STRETCH))
    if garment in WAISTBAND_GARMENTS:
        checks.append(("waist", WAISTBAND_STRETCH))
    verb = "measure" if garment == "trousers" else "measures"
    for girth, stretch in checks:
        made = finished_girth(garment, girth, size_girths)
        body = body_girths[f"{girth}_cm"]
        if body > made * (1.0 + stretch):
            word = "bust / chest" if girth == "chest" else girth
            basis = "chest" if girth == "hip" and made == finished_girth(garment, "chest", size_girths) else girth
            return (f"size {size} is too small for this body: its {garment} {verb} {made:.0f} cm around the {word} "
                    f"(the size's {size_girths[f'{basis}_cm']:.0f} cm {basis} with ease) and this body's {word} is {body:.0f} cm, "
                    f"{100 * (body / made - 1):.1f} % more (more than {100 * stretch:.0f} % is far too small)")
    belly = body_girths.get("waist_navel_cm")
    if belly is not None:
        made = girth_at_navel(garment, size_girths)
        if belly > made * (1.0 + WEAR_STRETCH):
            return (f"size {size} is too small for this body: its {garment} {verb} about {made:.0f} cm around the "
                    f"belly at the navel (between the size's waist and hip with ease) and this body's waist at the "
                    f"navel is {belly:.0f} cm, {100 * (belly / made - 1):.1f} % more (more than "
                    f"{100 * WEAR_STRETCH:.0f} % is far too small)")
    return None


def bezier(name: str, p0, p1, p2, p3) -> Edge:
    return Edge(name, np.array([p0, p1, p2, p3], dtype=float), "bezier")


def line(name: str, p0, p1) -> Edge:
    return Edge(name, np.array([p0, p1], dtype=float), "line")


def mirror_edges(edges: list[Edge]) -> list[Edge]:
    """Mirror in x (x -> -x), keeping the outline counter-clockwise: the edge order and
    each edge's direction reverse, and _l / _r in names swap."""
    out = []
    for e in reversed(edges):
        name = e.name.replace("_l", "_TMP").replace("_r", "_l").replace("_TMP", "_r")
        out.append(Edge(name, (e.points * [-1.0, 1.0])[::-1], e.kind))
    return out


def symmetric_panel(name: str, right_half: list[Edge], placement: dict, merge_top: bool = True) -> Panel:
    """A panel symmetric about x = 0 from the edges of its right half (x >= 0), given
    counter-clockwise from the hem centre up to the top centre. The two halves of the
    bottom edge (and of the top edge when `merge_top`) become one edge."""
    first, last = right_half[0], right_half[-1]
    if abs(first.start[0]) > 1e-9 or abs(last.end[0]) > 1e-9:
        raise TryonError(f"panel {name}: the right half must start and end on the centre line")
    left = mirror_edges(right_half)
    bottom = _merge(left[-1], first, first.name.replace("_r", ""))
    if merge_top:
        top = _merge(last, left[0], last.name.replace("_r", ""))
        edges = [bottom] + right_half[1:-1] + [top] + left[1:-1]
    else:
        edges = [bottom] + right_half[1:] + left[:-1]
    return Panel(name, edges, (0.0, 1.0), placement)


def _merge(a: Edge, b: Edge, name: str) -> Edge:
    """Join two edges meeting on the centre line into one (a line or a bezier)."""
    if a.kind == "line" and b.kind == "line":
        return line(name, a.start, b.end)
    # a smooth curve through both halves: a cubic through the outer ends with tangents
    pa, pb = a.points, b.points
    return bezier(name, pa[0], pa[0] + 2.0 * (pa[1] - pa[0]), pb[-1] + 2.0 * (pb[-2] - pb[-1]), pb[-1])


# --------------------------------------------------------------------------- bodice
@dataclass
class BodiceDims:
    length: float          # hem to neck point (side of the neck), along the body
    half_chest: float      # panel half width at the chest
    half_hem: float
    armhole_depth: float   # shoulder point down to the underarm
    shoulder_x: float      # shoulder point
    shoulder_drop: float
    neck_x: float          # half neck width
    neck_depth_front: float
    neck_depth_back: float
    waist_y: float | None = None   # fitted waist (dress)
    half_waist: float | None = None


def bodice_dims(m: dict, ease: Ease, hem_height: float) -> BodiceDims:
    shoulder_top = m["shoulder_height"]
    neck_point = m["neck_height"] + 0.01
    length = neck_point - hem_height
    half_chest = (m["chest_girth"] + ease.chest) / 4.0
    half_hem = max(half_chest, (m["hip_girth"] + ease.hip) / 4.0) if hem_height < m["hip_height"] + 0.05 else half_chest
    return BodiceDims(
        length=length,
        half_chest=half_chest,
        half_hem=half_hem,
        armhole_depth=max(0.17, shoulder_top - m["chest_height"] + 0.02),
        shoulder_x=m["shoulder_width"] / 2.0 + 0.01,
        shoulder_drop=max(0.02, neck_point - shoulder_top),
        neck_x=m["neck_girth"] / 6.0 + ease.neck_width / 2.0,
        neck_depth_front=0.08,
        neck_depth_back=0.02,
    )


def bodice_half(d: BodiceDims, front: bool, sleeveless: bool = False) -> list[Edge]:
    """Right half of a front/back bodice, counter-clockwise from the hem centre."""
    L, W = d.length, d.half_chest
    y_under = L - d.shoulder_drop - d.armhole_depth
    sx, sy = d.shoulder_x - (0.02 if sleeveless else 0.0), L - d.shoulder_drop
    nd = d.neck_depth_front if front else d.neck_depth_back
    edges = [line("hem_r", (0.0, 0.0), (d.half_hem, 0.0))]
    if d.waist_y is not None:
        edges.append(line("skirt_side_r", (d.half_hem, 0.0), (d.half_waist, d.waist_y)))
        edges.append(bezier("side_r", (d.half_waist, d.waist_y), (d.half_waist, d.waist_y + 0.35 * (y_under - d.waist_y)),
                            (W, y_under - 0.3 * (y_under - d.waist_y)), (W, y_under)))
    else:
        edges.append(line("side_r", (d.half_hem, 0.0), (W, y_under)))
    edges.append(bezier("armhole_r", (W, y_under), (sx + 0.35 * (W - sx), y_under), (sx, sy - 0.55 * (sy - y_under)), (sx, sy)))
    edges.append(line("shoulder_r", (sx, sy), (d.neck_x, L)))
    edges.append(bezier("neck_r", (d.neck_x, L), (d.neck_x, L - 0.55 * nd), (0.55 * d.neck_x, L - nd), (0.0, L - nd)))
    return edges


def _bodice_panels(d: BodiceDims, top_height: float, sleeveless: bool = False,
                   drops: dict[str, float] | None = None) -> list[Panel]:
    """Front and back. With `drops` (made to measure), each panel's centre hangs that much
    below its side seams and the panels are laid on the body along its surface."""
    panels = []
    for side in ("front", "back"):
        place = {"part": "torso", "top_z": top_height, "over_shoulder": 0.05, "side": side}
        half = bodice_half(d, side == "front", sleeveless)
        if drops is not None:
            place["along_surface"] = True
            if drops[side] > 0.0:
                half[0] = _dropped_hem(d.half_hem, drops[side])
        panels.append(symmetric_panel(side, half, place))
    return panels


def _bodice_seams(with_waist: bool) -> list[Seam]:
    # front side_r (body's left, +x) meets back side_l (seen from behind, also the body's left)
    seams = [
        Seam(("front", "side_r"), ("back", "side_l"), reverse=True),
        Seam(("front", "side_l"), ("back", "side_r"), reverse=True),
        Seam(("front", "shoulder_r"), ("back", "shoulder_l"), reverse=True),
        Seam(("front", "shoulder_l"), ("back", "shoulder_r"), reverse=True),
    ]
    if with_waist:
        seams += [
            Seam(("front", "skirt_side_r"), ("back", "skirt_side_l"), reverse=True),
            Seam(("front", "skirt_side_l"), ("back", "skirt_side_r"), reverse=True),
        ]
    return seams


# --------------------------------------------------------------------------- sleeve
def _cap_edge(width: float, length: float, h: float) -> Edge:
    return bezier("cap_r", (width / 2, length - h), (width / 2 - 0.25 * width, length - h + 0.15 * h),
                  (0.22 * width, length), (0.0, length))


def _bisect(f, lo: float, hi: float, target: float) -> float:
    """The x in [lo, hi] where the increasing f(x) reaches `target` (the nearer end if it does not)."""
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(mid) < target else (lo, mid)
    return 0.5 * (lo + hi)


def sleeve_panel(name: str, limb: str, cap_half_length: float, width: float, hem_width: float, length: float) -> Panel:
    """Sleeve with a symmetric cap whose half-curves are `cap_half_length` long (to match
    the armholes), bicep `width`, hem `hem_width`, total `length` (cap top to hem). The
    cap height follows the armhole; where even the tallest cap the sleeve's length allows
    is too short (a short sleeve on a deep armhole), the sleeve and its hem widen until the
    cap matches."""
    h_max = min(length - 0.03, 0.9 * cap_half_length)
    if _cap_edge(width, length, h_max).length() < cap_half_length:
        wider = _bisect(lambda w: _cap_edge(w, length, h_max).length(), width, 4.0 * cap_half_length, cap_half_length)
        hem_width, width = hem_width + (wider - width), wider
    h = _bisect(lambda x: _cap_edge(width, length, x).length(), 0.02, h_max, cap_half_length)

    def cap_right(h: float) -> Edge:
        return _cap_edge(width, length, h)

    right = [line("hem_r", (0.0, 0.0), (hem_width / 2, 0.0)),
             line("underarm_r", (hem_width / 2, 0.0), (width / 2, length - h)),
             cap_right(h)]
    return symmetric_panel(name, right, {"part": "arm", "limb": limb, "cap_height": h}, merge_top=False)


def _sleeves(m: dict, ease: Ease, armhole_front: float, armhole_back: float, length: float, hem_width: float) -> list[Panel]:
    width = max(m["bicep_girth"], 0.3 * m["chest_girth"]) + ease.bicep
    half = 0.5 * (armhole_front + armhole_back)
    return [sleeve_panel(f"sleeve_{s}", s, half, width, hem_width, length) for s in ("L", "R")]


def _sleeve_seams() -> list[Seam]:
    # Sleeve panels are seen from the outside with the cap on top; the body's front is on
    # the panel's -x half for the left sleeve and on its +x half for the right sleeve.
    return [
        Seam(("sleeve_L", "underarm_r"), ("sleeve_L", "underarm_l"), reverse=True),
        Seam(("sleeve_R", "underarm_r"), ("sleeve_R", "underarm_l"), reverse=True),
        Seam(("sleeve_L", "cap_l"), ("front", "armhole_r"), reverse=True),
        Seam(("sleeve_L", "cap_r"), ("back", "armhole_l"), reverse=True),
        Seam(("sleeve_R", "cap_r"), ("front", "armhole_l"), reverse=True),
        Seam(("sleeve_R", "cap_l"), ("back", "armhole_r"), reverse=True),
    ]


# --------------------------------------------------------------------------- garments
def draft_top(m: dict, ease: Ease, long_sleeves: bool) -> Pattern:
    hem_height = m["hip_height"] - ease.top_below_hip
    d = bodice_dims(m, ease, hem_height)
    panels = _bodice_panels(d, m["neck_height"] + 0.01)
    front, back = panels
    af, ab = front.edge("armhole_r").length(), back.edge("armhole_r").length()
    if long_sleeves:
        length, hem = m["arm_length"] + 0.03, m["wrist_girth"] + 0.07
    else:
        length = ease.short_sleeve
        hem = max(m["bicep_girth"], 0.3 * m["chest_girth"]) + ease.bicep - 0.02
    panels += _sleeves(m, ease, af, ab, length, hem)
    name = "longsleeve" if long_sleeves else "tshirt"
    return Pattern(name, panels, _bodice_seams(False) + _sleeve_seams())


@dataclass(frozen=True)
class BodyCover:
    """What a made-to-measure garment below the waist must pass over: the body's girths
    (m) at heights (m) above the floor (`tryon.body.measure.girth_profile`)."""

    heights: np.ndarray
    girths: np.ndarray
    profile_heights: np.ndarray | None = None  # heights (m) of the body's front and back depths
    front_y: np.ndarray | None = None          # the foremost point (y, m; the body faces -y)
    back_y: np.ndarray | None = None           # the rearmost point

    def centre_excess(self, side: str, top: float, bottom: float) -> float:
        """How much longer (m) than `top - bottom` a panel's centre must be to run from
        height `top` down the body's `side` ("front" or "back") over the bust, belly or
        buttocks, bridging hollows, and hang straight from the most prominent point down
        to `bottom` (0 without a profile)."""
        if self.profile_heights is None:
            return 0.0
        out = -self.front_y if side == "front" else self.back_y
        sel = (self.profile_heights <= top) & (self.profile_heights >= bottom)
        h, u = self.profile_heights[sel], out[sel]
        if len(h) < 2:
            return 0.0
        peak = int(np.argmax(u))
        chain = _upper_hull(h[: peak + 1][::-1], u[: peak + 1][::-1])  # from the peak up to the top
        run = float(np.hypot(np.diff(chain[:, 0]), np.diff(chain[:, 1])).sum())
        return max(0.0, run - (h[0] - h[peak]))

    def largest(self, lo: float, hi: float) -> float:
        """The largest girth between heights lo and hi (0 when none is measured there)."""
        sel = (self.heights >= lo) & (self.heights <= hi)
        return float(self.girths[sel].max()) if sel.any() else 0.0

    def waist_over(self, waist: float, hem: float, waist_height: float, hem_height: float, ease: float) -> float:
        """The smallest finished waist (m), at least `waist`, from which a straight skirt to
        a hem of girth `hem` passes over every girth between them with `ease`."""
        sel = (self.heights > hem_height) & (self.heights < waist_height)
        t = (waist_height - self.heights[sel]) / (waist_height - hem_height)  # 0 at the waist, 1 at the hem
        need = (self.girths[sel] + ease - t * hem) / (1.0 - t)
        return max(waist, float(need.max())) if len(need) else waist


def _hip_line(m: dict, cover: BodyCover | None, lo: float, hi: float) -> float:
    """The girth (m) a hip line is drafted from: the body's hip, or made to measure the
    largest girth the garment passes over between heights lo and hi (a belly beyond the
    hip, both upper thighs together)."""
    return m["hip_girth"] if cover is None else max(m["hip_girth"], cover.largest(lo, hi))


def _upper_hull(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The upper convex hull [K,2] of points with increasing x (a string pulled taut over
    them)."""
    hull: list[tuple[float, float]] = []
    for p in zip(x, y):
        while len(hull) >= 2 and ((hull[-1][0] - hull[-2][0]) * (p[1] - hull[-2][1])
                                  - (hull[-1][1] - hull[-2][1]) * (p[0] - hull[-2][0])) >= 0.0:
            hull.pop()
        hull.append(p)
    return np.array(hull)


def _dropped_hem(half_width: float, drop: float) -> Edge:
    """The right half of a hem that dips `drop` below its side corners at the centre: the
    half of one symmetric cubic, so that `symmetric_panel` joins the two halves back into
    that cubic."""
    k = drop / 0.75  # a cubic with both inner control points k down dips 0.75 k at its middle
    return bezier("hem_r", (0.0, -drop), (0.375 * half_width, -drop), (0.75 * half_width, -0.5 * k), (half_width, 0.0))


def draft_dress(m: dict, ease: Ease, cover: BodyCover | None = None) -> Pattern:
    hem_height = m["knee_height"] - ease.skirt_below_knee
    d = bodice_dims(m, ease, hem_height)
    d.waist_y = m["waist_height"] - hem_height
    hip = _hip_line(m, cover, hem_height, m["hip_height"])
    d.half_hem = (hip + ease.hip) / 4.0 + 0.06
    waist = m["waist_girth"] + ease.waist + 0.04
    if cover is not None:  # the skirt must pass over the belly below the waist seam
        waist = cover.waist_over(waist, 4.0 * d.half_hem, m["waist_height"], hem_height, ease.waist)
    d.half_waist = waist / 4.0
    top = m["neck_height"] + 0.01
    # made to measure, each panel's centre is let down by what the bust and belly (the
    # buttocks) add to its run from the neck to the hem: a full bust and tummy adjustment
    # that leaves the side seams as they are
    drops = None if cover is None else {side: cover.centre_excess(side, top, hem_height) for side in ("front", "back")}
    return Pattern("dress", _bodice_panels(d, top, sleeveless=True, drops=drops), _bodice_seams(True))


def draft_skirt(m: dict, ease: Ease, cover: BodyCover | None = None) -> Pattern:
    hem_height = m["knee_height"] - ease.skirt_below_knee
    length = m["waist_height"] - hem_height
    hip_y = length - (m["waist_height"] - m["hip_height"])
    hw = (m["waist_girth"] + ease.waist) / 4.0
    hip = _hip_line(m, cover, hem_height, m["waist_height"])
    hh = (hip + ease.hip) / 4.0
    hem = hh + 0.03
    right = [
        line("hem_r", (0.0, 0.0), (hem, 0.0)),
        bezier("side_r", (hem, 0.0), (hh, 0.45 * hip_y), (hh + 0.01, hip_y + 0.3 * (length - hip_y)), (hw, length)),
        line("waist_r", (hw, length), (0.0, length - 0.01)),
    ]
    place = {"part": "torso", "top_z": m["waist_height"]}
    front = symmetric_panel("front", right, dict(place, side="front"))
    back = symmetric_panel("back", right, dict(place, side="back"))
    seams = [Seam(("front", "side_r"), ("back", "side_l"), reverse=True),
             Seam(("front", "side_l"), ("back", "side_r"), reverse=True)]
    return Pattern("skirt", [front, back], seams)


# Trouser proportions. The block follows the usual straight-trouser construction (Aldrich,
# "Metric Pattern Cutting for Menswear" / "... for Womenswear", the trouser block; the
# same steps in Leena's pattern drafting lesson "men's pants", leenas.com/English/
# draw_men_pants.html, and Wikibooks "Dressmaking/Pants"): a crotch line at the body's
# crotch less a little ease, the hip line, a knee line 6 cm above the midpoint of crotch
# line and hem, front and back panels a quarter of the seat (with ease) wide at the hip
# line, -1 cm / +1 cm front / back, crotch extensions of about 1/16 (front) and 1/9 (back)
# of the seat, the leg centred on the crease (the middle of the crotch line), knee and hem
# widths a quarter of their circumference -1 / +1 cm.
TROUSER_HEM_ABOVE_ANKLE = 0.01  # m: the hem just above the ankle joint, at the ankle bone
TROUSER_CROTCH_EASE = 0.01   # m: the trouser's crotch point below the body's ("body rise + 1 cm")
TROUSER_FRONT_EXTENSION = 1 / 16   # of the seat girth with ease
TROUSER_BACK_EXTENSION = 1 / 9
TROUSER_PANEL_OFFSET = 0.01  # m: back panels this much wider per side than a quarter, fronts narrower
# Knee and hem widths are style ("the knee and hem are usually determined by fashion", R.
# Duffy, "Measuring for trousers"): a classic straight leg has a knee of about 0.47 of the
# seat (18 in for a 38 in seat, G. F. Hertzer, "Garment Cutting in the Twentieth Century",
# "Tight pants") and a hem of about 0.43 of it (16-17 in for a 38-40 in seat; 16 in is the
# narrow end of the usual 16-20 in); both at least enough to pass over the thigh's
# lower part and the foot.
# The back's longer crotch extension makes its inseam (crotch point to knee) longer than the
# front's: 1-2 % in regular sizes, 3-4 % in the largest (a big seat over a short leg). It is
# eased into the front between crotch and knee, as trousers are sewn.
TROUSER_INSEAM_EASE = 0.05
TROUSER_KNEE_PER_SEAT = 0.47
TROUSER_HEM_PER_SEAT = 0.43


def trouser_inseam(m: dict) -> float:
    """The trouser block's inseam (m) for body measurements `m`: from the crotch point
    (`TROUSER_CROTCH_EASE` below the body's) to the hem just above the ankle."""
    return (m["crotch_height"] - TROUSER_CROTCH_EASE) - (m["ankle_height"] + TROUSER_HEM_ABOVE_ANKLE)


def trouser_dims(m: dict, ease: Ease) -> dict:
    """The trouser block's lengths and widths (m) for body measurements `m`: length from
    the waist to the ankle, rise and inseam, and the circumferences at seat, knee and hem."""
    hem_z = m["ankle_height"] + TROUSER_HEM_ABOVE_ANKLE
    crotch_z = m["crotch_height"] - TROUSER_CROTCH_EASE
    seat = m["hip_girth"] + ease.hip
    knee = max(TROUSER_KNEE_PER_SEAT * m["hip_girth"], 0.8 * m["thigh_girth"])
    hem = max(TROUSER_HEM_PER_SEAT * m["hip_girth"], 0.7 * m["thigh_girth"])
    return {"length": m["waist_height"] - hem_z, "inseam": trouser_inseam(m), "rise": m["waist_height"] - crotch_z,
            "hip_y": m["hip_height"] - hem_z, "seat": seat, "waist": m["waist_girth"] + ease.waistband,
            "knee": knee, "hem": hem, "hem_z": hem_z}


def trouser_leg(name: str, m: dict, ease: Ease, front: bool, limb: str) -> Panel:
    """One trouser panel drafted as the body's left leg seen from its side (front or
    back), outseam on +x, then mirrored for the right leg. The crease is x = 0."""
    d = trouser_dims(m, ease)
    length, crotch_y, hip_y = d["length"], d["inseam"], d["hip_y"]
    knee_y = 0.5 * crotch_y + 0.06
    sgn = -1.0 if front else 1.0
    quarter_hip = d["seat"] / 4.0 + sgn * TROUSER_PANEL_OFFSET
    quarter_waist = d["waist"] / 4.0 + sgn * TROUSER_PANEL_OFFSET
    ext = d["seat"] * (TROUSER_FRONT_EXTENSION if front else TROUSER_BACK_EXTENSION)
    knee_half = d["knee"] / 4.0 + sgn * TROUSER_PANEL_OFFSET
    hem_half = d["hem"] / 4.0 + sgn * TROUSER_PANEL_OFFSET
    side = 0.5 * (quarter_hip + ext)        # crease in the middle of the crotch line
    in_top = side - quarter_hip             # centre front / back line at the hip
    tip = in_top - ext                      # crotch point
    waist_side = in_top + 0.01 + quarter_waist
    edges = [
        line("hem", (-hem_half, 0.0), (hem_half, 0.0)),
        line("outseam_shin", (hem_half, 0.0), (knee_half, knee_y)),
        bezier("outseam", (knee_half, knee_y), (knee_half + 0.25 * (side - knee_half), knee_y + 0.4 * (hip_y - knee_y)),
               (side, hip_y - 0.25 * (hip_y - knee_y)), (side, hip_y)),
        bezier("outseam_hip", (side, hip_y), (side, hip_y + 0.4 * (length - hip_y)),
               (waist_side + 0.2 * (side - waist_side), length - 0.25 * (length - hip_y)), (waist_side, length)),
        line("waist", (waist_side, length), (in_top + 0.01, length)),
        bezier("crotch", (in_top + 0.01, length), (in_top, hip_y - 0.02), (in_top - 0.3 * ext, crotch_y + 0.02), (tip, crotch_y)),
        bezier("inseam", (tip, crotch_y), (tip + 0.45 * (-knee_half - tip), crotch_y - 0.25 * (crotch_y - knee_y)),
               (-knee_half, knee_y + 0.45 * (crotch_y - knee_y)), (-knee_half, knee_y)),
        line("inseam_shin", (-knee_half, knee_y), (-hem_half, 0.0)),
    ]
    if limb == "R":
        edges = mirror_edges(edges)
    side_name = "front" if front else "back"
    if not front:  # back panels are seen from behind: the left leg lies on the panel's -x
        edges = mirror_edges(edges)
    return Panel(name, edges, (0.0, 1.0), {"part": "leg", "limb": limb, "side": side_name, "top_z": m["waist_height"],
                                            "crotch_y": crotch_y})


def draft_trousers(m: dict, ease: Ease) -> Pattern:
    panels = [trouser_leg(f"{s}_{l}", m, ease, s == "front", l) for s in ("front", "back") for l in ("L", "R")]
    seams = [Seam((f"front_{l}", e), (f"back_{l}", e), reverse=True,
                  ease=TROUSER_INSEAM_EASE if e == "inseam" else SEAM_EASE)
             for l in ("L", "R") for e in ("outseam_shin", "outseam", "outseam_hip", "inseam", "inseam_shin")]
    seams += [
        Seam(("front_L", "crotch"), ("front_R", "crotch"), reverse=True),
        Seam(("back_L", "crotch"), ("back_R", "crotch"), reverse=True),
    ]
    return Pattern("trousers", panels, seams)


def draft(garment: str, measurements: dict, ease: Ease | None = None, size: str | None = None, meta: dict | None = None,
          cover: BodyCover | None = None) -> Pattern:
    """Draft `garment` (one of GARMENTS) for body `measurements` (metres). `cover`: made to
    measure, the body's girths a skirt or a dress must pass over."""
    ease = ease or Ease()
    makers = {"tshirt": lambda: draft_top(measurements, ease, False), "longsleeve": lambda: draft_top(measurements, ease, True),
              "skirt": lambda: draft_skirt(measurements, ease, cover), "trousers": lambda: draft_trousers(measurements, ease),
              "dress": lambda: draft_dress(measurements, ease, cover)}
    if garment not in makers:
        raise TryonError(f"unknown garment {garment!r}; available: {', '.join(GARMENTS)}")
    pattern = makers[garment]()
    pattern.meta.update({"garment": garment, "size": size, "ease_m": asdict(ease),
                         "body_measurements_cm": {k: round(100 * v, 1) for k, v in measurements.items()}})
    pattern.meta.update(meta or {})
    return pattern
