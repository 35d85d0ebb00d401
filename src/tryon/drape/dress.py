"""Dressing: put a pattern's panels around a body in the A-pose and sew them.

1. Placement. Every panel is wrapped onto a tube around its body part, outside the skin:
   torso panels onto elliptic cross-sections of the torso (front panels on the front half,
   back panels on the back half, the top bending over the shoulders so front and back
   shoulder seams meet), sleeves onto cylinders around the arms, trouser panels onto
   the front / back halves of the pelvis and each leg. Seams that both tubes share
   (side seams, underarm seams, outseams) start closed; the rest start a few centimetres
   apart. Vertices still closer to the skin than the clearance are pushed out along the
   skin's normal.
2. Sewing. The cloth simulator pulls every seam pair together with zero-length springs,
   with the body as a collision obstacle, self-collision on (a stitched pair counts as
   one vertex), gravity off and still-air damping, until the widest seam gap is under a
   millimetre. Sleeves start far enough out along the arms that no panel passes through
   another, so the sewn garment does not either.
3. Welding. Seam pairs become single vertices; each face keeps its own pattern
   coordinates (per-corner material coordinates), so the rest shape stays the pattern's.
   The welded garment relaxes briefly (self-collision on, gravity off, still air) from
   the strain that closing the last millimetres of a seam leaves.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp
import torch

from tryon.body.pose import BodyPose
from tryon.errors import SimulationError, TryonError
from tryon.fabric.base import Fabric
from tryon.garment.pattern import Panel, Pattern
from tryon.garment.triangulate import GarmentMesh, merge_stitched, triangulate_pattern
from tryon.io.atomic import atomic_write

if TYPE_CHECKING:
    from tryon.sim.loop import StepRecord

log = logging.getLogger(__name__)

DRESS_VERSION = 25
# Dressed garments are cached and shared by every drape, dataset and service call, so they
# must be the same whichever of them dressed first: dressing keeps the block-Jacobi solve
# the cache was filled with, not the simulator's default (two-level from 1,500 vertices).
DRESSING_LINEAR_SOLVER = "pcg"


# --------------------------------------------------------------------------- tubes
class TorsoTube:
    """Elliptic cross-sections around the torso (legs included below the crotch, arms
    excluded), every centimetre of height: centre y, half width, front and back depth."""

    def __init__(self, body: BodyPose, clearance: float, step: float = 0.01):
        v = body.vertices[body.part == 0]
        legs = body.vertices[body.part >= 3]
        v = np.vstack([v, legs])
        self.z = np.arange(0.0, body.vertices[:, 2].max() + step, step)
        half, front, back, yc = (np.zeros(len(self.z)) for _ in range(4))
        for k, z in enumerate(self.z):
            sel = v[np.abs(v[:, 2] - z) < 0.6 * step + 0.01]
            if len(sel) < 3:
                half[k], front[k], back[k], yc[k] = np.nan, np.nan, np.nan, np.nan
                continue
            lo, hi = sel[:, 1].min(), sel[:, 1].max()
            yc[k] = 0.5 * (lo + hi)
            half[k] = np.abs(sel[:, 0]).max()
            front[k], back[k] = yc[k] - lo, hi - yc[k]
        for a in (half, front, back, yc):
            good = np.isfinite(a)
            a[~good] = np.interp(self.z[~good], self.z[good], a[good])
        scale = 1.08  # a section's corners stick out of the ellipse through its extremes
        self.half = scale * half + clearance
        self.front = scale * front + clearance
        self.back = scale * back + clearance
        self.yc = yc

    def at(self, z: np.ndarray, what: str) -> np.ndarray:
        return np.interp(z, self.z, getattr(self, what))


class LegTube:
    """Elliptic cross-sections around one leg every centimetre of height: centre (cx, cy)
    and half axes (rx, ry), outside the skin. Below the ankle the foot would widen the
    section, so the lower shin's section continues down to the floor; `z_below` walks
    down the leg's (tilted) centre line by arc length."""

    def __init__(self, body: BodyPose, limb: int, clearance: float, step: float = 0.01):
        v = body.vertices[body.part == limb]
        self.z = np.arange(0.0, body.vertices[:, 2].max() + step, step)
        cx, cy, rx, ry = (np.zeros(len(self.z)) for _ in range(4))
        for k, z in enumerate(self.z):
            sel = v[np.abs(v[:, 2] - z) < 0.6 * step + 0.01]
            if len(sel) < 3:
                cx[k] = cy[k] = rx[k] = ry[k] = np.nan
                continue
            cx[k], cy[k] = 0.5 * (sel[:, 0].min() + sel[:, 0].max()), 0.5 * (sel[:, 1].min() + sel[:, 1].max())
            rx[k], ry[k] = 0.5 * np.ptp(sel[:, 0]), 0.5 * np.ptp(sel[:, 1])
        for a in (cx, cy, rx, ry):
            good = np.isfinite(a)
            a[~good] = np.interp(self.z[~good], self.z[good], a[good])
        kernel = np.ones(5) / 5.0  # a 5 cm running mean: single slices are noisy (hands, folds)
        for a in (cx, cy, rx, ry):
            a[:] = np.convolve(np.pad(a, 2, mode="edge"), kernel, mode="valid")
        foot = body.heads.get("foot." + ("L" if limb == 3 else "R"))
        if foot is not None:
            low = self.z < foot[2] + 0.03
            k = int(np.searchsorted(self.z, foot[2] + 0.03))
            k = min(k, len(self.z) - 1)
            for a in (cx, cy, rx, ry):
                a[low] = a[k]
        self.cx, self.cy = cx, cy
        self.rx, self.ry = 1.1 * rx + clearance, 1.1 * ry + clearance
        # arc length along the bones (hip joint, knee, ankle; straight on to the floor)
        side = "L" if limb == 3 else "R"
        joints = [body.heads.get(f"{b}.{side}") for b in ("upperleg01", "lowerleg01", "foot")]
        if all(j is not None for j in joints):
            j = np.array(joints[::-1])  # ankle, knee, hip: increasing height
            knots_z = np.concatenate([[0.0], j[:, 2], [self.z[-1] + 1.0]])
            seg = np.linalg.norm(np.diff(j, axis=0), axis=1) / np.maximum(np.diff(j[:, 2]), 1e-6)  # length per height
            slope = np.concatenate([[seg[0]], seg, [1.0]])
            knots_s = np.concatenate([[0.0], np.cumsum(slope * np.diff(knots_z))])
            self.s = np.interp(self.z, knots_z, knots_s)
        else:
            self.s = self.z.copy()

    def at(self, z: np.ndarray, what: str) -> np.ndarray:
        return np.interp(z, self.z, getattr(self, what))

    @classmethod
    def symmetric_pair(cls, body: BodyPose, clearance: float) -> dict[str, "LegTube"]:
        """Left and right leg tubes made mirror images of each other (their mean), so
        that the two legs' panels meet exactly on the midline at the crotch seams."""
        left, right = cls(body, 3, clearance), cls(body, 4, clearance)
        for what, sign in (("cx", -1.0), ("cy", 1.0), ("rx", 1.0), ("ry", 1.0), ("s", 1.0)):
            mean = 0.5 * (getattr(left, what) + sign * getattr(right, what))
            setattr(left, what, mean)
            setattr(right, what, sign * mean)
        return {"L": left, "R": right}

    def z_below(self, z0: float, distance: np.ndarray) -> np.ndarray:
        """Height reached walking `distance` down the centre line from height z0."""
        s0 = float(np.interp(z0, self.z, self.s))
        return np.interp(s0 - np.asarray(distance), self.s, self.z)


class Midline:
    """The body's profile in its mid-sagittal plane (|x| < 1.5 cm): the front-most and
    back-most y of the torso at each height, NaN below the crotch."""

    def __init__(self, body: BodyPose, step: float = 0.01):
        v = body.vertices[(body.part == 0) & (np.abs(body.vertices[:, 0]) < 0.015)]
        self.z = np.arange(0.0, body.vertices[:, 2].max() + step, step)
        self.front = np.full(len(self.z), np.nan)
        self.back = np.full(len(self.z), np.nan)
        for k, z in enumerate(self.z):
            sel = v[np.abs(v[:, 2] - z) < 0.6 * step + 0.01]
            if len(sel):
                self.front[k], self.back[k] = sel[:, 1].min(), sel[:, 1].max()
        for a in (self.front, self.back):  # a 5 cm running mean where defined: single slices are noisy
            good = np.isfinite(a)
            num = np.convolve(np.where(good, a, 0.0), np.ones(5), mode="same")
            den = np.convolve(good.astype(float), np.ones(5), mode="same")
            a[good] = num[good] / den[good]

    def at(self, z: np.ndarray, what: str) -> np.ndarray:
        vals = getattr(self, what)
        k = np.clip(np.round(np.asarray(z) / (self.z[1] - self.z[0])).astype(int), 0, len(self.z) - 1)
        return vals[k]


class ArmTube:
    """A cylinder around a straight arm: joint J, axis A (towards the hand), e_top (up and
    out, perpendicular to A), e_front (towards -y); radius profile r(t) of the skin."""

    def __init__(self, body: BodyPose, side: str, clearance: float):
        self.J = body.heads[f"upperarm01.{side}"]
        wrist = body.heads[f"wrist.{side}"]
        self.A = (wrist - self.J) / np.linalg.norm(wrist - self.J)
        up = np.array([0.0, 0.0, 1.0]) - self.A[2] * self.A
        self.e_top = up / np.linalg.norm(up)
        f = np.cross(self.A, self.e_top)
        self.e_front = f if f[1] < 0 else -f
        v = body.vertices[body.part == (1 if side == "L" else 2)]
        rel = v - self.J
        t = rel @ self.A
        radial = np.linalg.norm(rel - np.outer(t, self.A), axis=1)
        self.t = np.arange(-0.15, t.max() + 0.01, 0.01)
        r = np.array([radial[np.abs(t - tk) < 0.015].max() if np.any(np.abs(t - tk) < 0.015) else np.nan for tk in self.t])
        good = np.isfinite(r)
        r[~good] = np.interp(self.t[~good], self.t[good], r[good])
        self.r = r + clearance

    def radius(self, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self.t, self.r)


# --------------------------------------------------------------------------- panel placement
def _half_ellipse(a: np.ndarray, b: np.ndarray, frac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (x, depth) on the half ellipse x = a sin(phi), depth = b cos(phi), phi in
    [-pi/2, pi/2], at arc-length fraction `frac` in [-1, 1] (0 = centre)."""
    phi = np.linspace(-np.pi / 2, np.pi / 2, 181)
    x = a[:, None] * np.sin(phi)[None]
    d = b[:, None] * np.cos(phi)[None]
    seg = np.hypot(np.diff(x, axis=1), np.diff(d, axis=1))
    s = np.concatenate([np.zeros((len(a), 1)), np.cumsum(seg, 1)], 1)
    s = s / np.maximum(s[:, -1:], 1e-12) * 2.0 - 1.0
    out_x, out_d = np.empty(len(a)), np.empty(len(a))
    for i in range(len(a)):
        out_x[i] = np.interp(frac[i], s[i], x[i])
        out_d[i] = np.interp(frac[i], s[i], d[i])
    return out_x, out_d


def _panel_half_width(panel: Panel) -> float:
    lo, hi = panel.bounds()
    return max(abs(lo[0]), abs(hi[0]))


def _row_half_width(panel: Panel, y: np.ndarray) -> np.ndarray:
    """Half width of a symmetric torso panel at heights y, up to the top of its side seams
    (the underarm; a skirt's waist), so that every row reaches the side of the body and the
    side seams start closed however the waist is shaped; above the side seams (shoulders,
    armholes) the width at their top."""
    tops = [e.points[:, 1].max() for e in panel.edges if e.name.startswith("side")]
    if not tops:
        return np.full(len(y), _panel_half_width(panel))
    lo, hi = _outline_span(panel, np.minimum(y, min(tops) - 1e-6))
    return np.maximum(np.maximum(np.abs(lo), np.abs(hi)), 1e-6)


def _z_along_surface(s: np.ndarray, frac: np.ndarray, z_top: float, tube: TorsoTube, side: str,
                     step: float = 0.005) -> np.ndarray:
    """Heights at which each panel column, run down the tube's `side` from `z_top`, has
    covered `s` metres of cloth: the column at arc fraction `frac` follows the tube's
    half width and depth at that angle, so over a bust or belly it reaches less far down
    than `z_top - s` (laid straight down, such a panel starts stretched by a quarter and
    rides up as it contracts)."""
    zs = z_top - np.arange(0.0, z_top + step, step)
    phi = 0.5 * np.pi * frac[:, None]
    px = tube.at(zs, "half")[None] * np.sin(phi)
    py = tube.at(zs, "yc")[None] + (-1.0 if side == "front" else 1.0) * tube.at(zs, side)[None] * np.cos(phi)
    seg = np.sqrt(np.diff(px, axis=1) ** 2 + np.diff(py, axis=1) ** 2 + step ** 2)
    run = np.concatenate([np.zeros((len(s), 1)), np.cumsum(seg, axis=1)], axis=1)
    k = np.array([np.searchsorted(r, v) for r, v in zip(run, s)])
    k = np.clip(k, 1, len(zs) - 1)
    rows = np.arange(len(s))
    t = (s - run[rows, k - 1]) / np.maximum(run[rows, k] - run[rows, k - 1], 1e-12)
    return zs[k - 1] + np.clip(t, 0.0, None) * (zs[k] - zs[k - 1])


def place_torso(points: np.ndarray, panel: Panel, tube: TorsoTube) -> np.ndarray:
    """Front/back panel onto the torso tube. A bodice's top `over_shoulder` metres (its
    placement key) bend over the shoulders (the depth shrinks to the mid-plane), so front
    and back meet there; a skirt's waist stays on the tube."""
    _, hi = panel.bounds()
    top = float(panel.placement.get("top_z", 0.0))
    over_shoulder = float(panel.placement.get("over_shoulder", 0.0))
    s = hi[1] - points[:, 1]  # distance below the panel top, along the panel
    z_flat = top - over_shoulder
    front = panel.placement.get("side", "front") == "front"
    along_surface = bool(panel.placement.get("along_surface"))
    # a made-to-measure hem dips below its side corners (y < 0): those rows keep the hem's width
    rows = np.maximum(points[:, 1], 0.0) if along_surface else points[:, 1]
    frac = np.clip(points[:, 0] / _row_half_width(panel, rows), -1.0, 1.0)
    if along_surface:
        below = _z_along_surface(s - over_shoulder, frac, z_flat, tube, "front" if front else "back")
    else:
        below = top - s
    z = np.where(s > over_shoulder, below, z_flat)
    lift = np.clip(over_shoulder - s, 0.0, over_shoulder) / max(over_shoulder, 1e-12)  # 1 at the top, 0 below the bend
    z = z + 0.6 * over_shoulder * np.sin(0.5 * np.pi * lift)
    zq = np.minimum(z, z_flat)
    depth = tube.at(zq, "front" if front else "back")
    depth = depth * np.cos(0.5 * np.pi * lift)
    x, d = _half_ellipse(tube.at(zq, "half"), depth, frac)
    if front:
        return np.stack([x, tube.at(zq, "yc") - d, z], 1)
    return np.stack([-x, tube.at(zq, "yc") + d, z], 1)


def _outline_span(panel: Panel, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Leftmost and rightmost x of the panel outline at heights y."""
    p = panel.outline(80)
    q = np.roll(p, -1, axis=0)
    y = np.clip(y, p[:, 1].min() + 1e-4, p[:, 1].max() - 1e-4)  # the top and bottom rows: just inside
    lo = np.full(len(y), np.inf)
    hi = np.full(len(y), -np.inf)
    for a, b in zip(p, q):
        if abs(b[1] - a[1]) < 1e-9:  # horizontal (up to rounding): its ends are on the neighbours
            continue
        t = (y - a[1]) / (b[1] - a[1])
        ok = (t >= 0) & (t <= 1)
        xs = a[0] + t * (b[0] - a[0])
        lo = np.where(ok, np.minimum(lo, xs), lo)
        hi = np.where(ok, np.maximum(hi, xs), hi)
    bad = ~np.isfinite(lo)
    lo[bad], hi[bad] = np.min(p[:, 0]), np.max(p[:, 0])
    return lo, hi


def place_sleeve(points: np.ndarray, panel: Panel, tube: ArmTube, limb: str) -> np.ndarray:
    """Sleeve onto a cylinder around the arm: x wraps around (0 on top, the underarm
    seams meet underneath), y runs along the arm from the cap down to the hem."""
    _, hi = panel.bounds()
    cap = float(panel.placement.get("cap_height", 0.1))
    length = hi[1]
    s = length - points[:, 1]
    t = s - 0.5 * cap
    y_cap = length - cap
    lo_x, hi_x = _outline_span(panel, np.minimum(points[:, 1], y_cap))
    half = 0.5 * (hi_x - lo_x)
    theta = np.clip(points[:, 0] / np.maximum(half, 1e-6), -1.0, 1.0) * np.pi
    r = np.maximum(tube.radius(t), half / np.pi)
    side = -tube.e_front if limb == "L" else tube.e_front  # the panel's -x half is the front on the left sleeve
    return tube.J + np.outer(t, tube.A) + r[:, None] * (np.outer(np.cos(theta), tube.e_top) + np.outer(np.sin(theta), side))


CROTCH_BLEND = 0.10  # m: below the crotch point the inseam moves from the midline to the leg's inner side
LEG_GAP = 0.004      # m: each leg's cloth keeps this far from the midline, but at the crotch seams ...
LEG_GAP_RAMP = 0.006  # m: ... reached this far from them, so the two legs never start in contact


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _crotch_point_x(panel: Panel) -> float:
    """Panel x of a trouser panel's crotch point (the lower end of its crotch edge)."""
    try:
        pts = panel.edge("crotch").points
    except TryonError:
        return 0.0
    return float(pts[np.argmin(pts[:, 1]), 0])


def place_leg(points: np.ndarray, panel: Panel, torso: TorsoTube, leg: LegTube, midline: Midline,
              clearance: float) -> np.ndarray:
    """Trouser panel, one row of the panel (its inner edge to its outer edge) at a time,
    wrapped half-way round an elliptic section from the inner side to the outer side:
    below the crotch line the leg's section (rows spaced along the tilted leg, the
    inseam on the inner side of the leg), above it the half of the torso's section on the
    panel's side, reached through a blend over the lower part of the rise in which the
    crotch seam follows the body's mid-sagittal profile (outside the skin) from the crotch
    point up to the centre front / back. Every point of a left panel keeps x >= 0 and
    every point of a right one x <= 0 (the crotch seams lie on x = 0, so all seams start
    closed), and front panels stay in front of back panels (the y of the sections'
    centres), so the start is free of crossings."""
    _, hi = panel.bounds()
    top_z = float(panel.placement["top_z"])
    crotch_y = float(panel.placement.get("crotch_y", 0.45 * hi[1]))
    zc = top_z - (hi[1] - crotch_y)  # the trouser's crotch point
    py = points[:, 1]
    z = np.where(py >= crotch_y, top_z - (hi[1] - py), leg.z_below(zc, np.maximum(crotch_y - py, 0.0)))
    lo_x, hi_x = _outline_span(panel, py)
    limb = panel.placement["limb"]
    front = panel.placement["side"] == "front"
    outer_is_high = (limb == "L") == front
    f = (points[:, 0] - lo_x) / np.maximum(hi_x - lo_x, 1e-9)
    f = np.clip(f if outer_is_high else 1.0 - f, 0.0, 1.0)
    band = 0.4 * (top_z - zc)
    w = _smoothstep((z - zc) / band)
    zl = np.minimum(z, zc)
    # the leg's own section (its centre on the limb's side, x > 0 for both limbs here)
    lcx = np.abs(leg.at(zl, "cx"))
    c_x = (1 - w) * lcx
    c_y = (1 - w) * leg.at(zl, "cy") + w * torso.at(z, "yc")
    depth = torso.at(z, "front" if front else "back")
    r_y = (1 - w) * leg.at(zl, "ry") + w * depth
    x_side = (1 - w) * (lcx + leg.at(zl, "rx")) + w * torso.at(z, "half")
    x_side = np.maximum(x_side, c_x + 0.02)
    # the inner edge: the inner side of the leg below the crotch, the mid-sagittal profile above
    prof = midline.at(z, "front" if front else "back")
    ahead = (c_y - prof) if front else (prof - c_y)
    reach = np.where(np.isfinite(prof), np.maximum(ahead, 0.0) + clearance, 0.0) * (z > zc)
    # ... but bridging hollows (the buttocks' cleft), as cloth does: at least an ellipse's reach
    reach = np.maximum(reach, r_y * np.sin(0.5 * np.pi * w))
    # ... and at least as far from the crotch point as the crotch seam runs across the panel
    # (the seam's flat lower part runs under the body towards the front / back)
    inner_x = lo_x if outer_is_high else hi_x
    reach = np.maximum(reach, np.abs(inner_x - _crotch_point_x(panel)) * (z > zc))
    a0 = np.arcsin(np.clip(reach / np.maximum(r_y, 1e-6), 0.0, 1.0))
    # the inner side of the leg's section, drawn to the midline towards the crotch point
    below = _smoothstep((zc - z) / CROTCH_BLEND)
    inner_leg = np.maximum(np.maximum(lcx - leg.at(zl, "rx"), 0.0) * below, LEG_GAP * _smoothstep((zc - z) / LEG_GAP_RAMP))
    start_x = (1 - w) * inner_leg
    r_in = np.maximum(c_x - start_x, 0.0) / np.maximum(np.cos(a0), 1e-3)
    ang = a0 + (np.pi - a0) * f
    cos = np.cos(ang)
    x = np.where(cos > 0, c_x - r_in * cos, c_x - (x_side - c_x) * cos)
    # away from the crotch seams (on the midline above the crotch point) each leg keeps its gap
    from_seam = f * (hi_x - lo_x)
    x = np.maximum(x, np.where(z > zc, LEG_GAP * np.clip(from_seam / LEG_GAP_RAMP, 0.0, 1.0), start_x))
    y = c_y + (-1.0 if front else 1.0) * r_y * np.sin(ang)
    sign_x = 1.0 if limb == "L" else -1.0
    return np.stack([sign_x * x, y, z], 1)


def place_pattern(mesh: GarmentMesh, body: BodyPose, clearance: float = 0.012) -> np.ndarray:
    """3D start positions [N,3] of every panel vertex around the body."""
    torso = TorsoTube(body, clearance)
    arms = {s: ArmTube(body, s, clearance) for s in ("L", "R")}
    legs = LegTube.symmetric_pair(body, clearance)
    midline = Midline(body)
    x = np.zeros((mesh.num_vertices, 3))
    for k, panel in enumerate(mesh.pattern.panels):
        sel = mesh.panel_of_vertex == k
        pts = mesh.points2d[sel]
        part = panel.placement.get("part")
        if part == "torso":
            x[sel] = place_torso(pts, panel, torso)
        elif part == "arm":
            x[sel] = place_sleeve(pts, panel, arms[panel.placement["limb"]], panel.placement["limb"])
        elif part == "leg":
            x[sel] = place_leg(pts, panel, torso, legs[panel.placement["limb"]], midline, clearance)
        else:
            raise TryonError(f"panel {panel.name!r}: unknown placement part {part!r}; use torso, arm or leg")
    return x


SLEEVE_SHIFT_STEP = 0.01  # m: sleeves move out along the arm in these steps ...
SLEEVE_SHIFT_MAX = 0.15   # m: ... until they clear the bodice (sewing pulls them back in)


def placed_apart(x: np.ndarray, mesh: GarmentMesh, body: BodyPose, clearance: float) -> tuple[np.ndarray, int, float]:
    """Positions x from `place_pattern`, clear of the skin (`clear_of_skin`), with the sleeves moved out
    along their arms until no panel passes through another: a sleeve cap placed around
    the shoulder joint lies partly inside the bodice, and sewing (with self-collision on)
    cannot undo a crossing it starts with. Returns positions, vertices pushed out of the
    skin and the sleeves' shift (m)."""
    from tryon.sim.collision import stitch_alias
    from tryon.sim.geometry import mesh_edges
    from tryon.sim.geometry import edge_face_intersections

    sleeves = [(mesh.panel_of_vertex == k, ArmTube(body, p.placement["limb"], clearance).A)
               for k, p in enumerate(mesh.pattern.panels) if p.placement.get("part") == "arm"]
    edges = mesh_edges(mesh.faces)
    alias = stitch_alias(mesh.stitches, len(x))
    for shift in np.arange(0.0, SLEEVE_SHIFT_MAX + 1e-9, SLEEVE_SHIFT_STEP):
        moved = x.copy()
        for sel, axis in sleeves:
            moved[sel] += shift * axis
        moved, pushed = clear_of_skin(moved, body, clearance)
        moved, _ = _unfold(moved, mesh.faces, edges, mesh.panel_of_vertex, body, clearance)
        if not sleeves or len(edge_face_intersections(moved, edges, moved, mesh.faces, True, alias)) == 0:
            return moved, pushed, float(shift)  # without sleeves: nothing to move (a crossing is counted after sewing)
    raise SimulationError(f"placing {mesh.pattern.name}: the panels still cross each other with the sleeves "
                          f"{100 * SLEEVE_SHIFT_MAX:.0f} cm out along the arms")


def _smooth_out(x: np.ndarray, edges: np.ndarray, body: BodyPose, clearance: float, flawed, rings: int,
                rounds: int = 10) -> tuple[np.ndarray, int]:
    """Up to `rounds` times: the vertices `flawed(x)` marks (a mask and a count of flaws)
    and `rings` rings of their neighbours take their neighbours' mean, then are pushed
    out of the skin again. Returns the positions and the count of flaws at first."""
    n = len(x)
    adj = sp.coo_matrix((np.ones(2 * len(edges)), (edges.reshape(-1), edges[:, ::-1].reshape(-1))), shape=(n, n)).tocsr()
    degree = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)
    first = None
    for _ in range(rounds):
        near, count = flawed(x)
        first = count if first is None else first
        if count == 0:
            break
        for _ in range(rings):
            near |= adj @ near > 0
        x = x.copy()
        x[near] = (adj @ x)[near] / degree[near, None]
        x, _ = clear_of_skin(x, body, clearance)
    return x, int(first or 0)


def _unfold(x: np.ndarray, faces: np.ndarray, edges: np.ndarray, panel: np.ndarray, body: BodyPose, clearance: float,
            rounds: int = 10) -> tuple[np.ndarray, int]:
    """Folds of a panel through itself that pushing out of the skin made (neighbours
    pushed to either side of a crease such as the armpit) smoothed away: the vertices of
    crossing edges and faces and their neighbours take their neighbours' mean, then are
    pushed out again. Returns the positions and how many crossings there were at first."""
    from tryon.sim.geometry import edge_face_intersections

    def crossings(p: np.ndarray) -> tuple[np.ndarray, int]:
        hits = edge_face_intersections(p, edges, p, faces, True)
        hits = hits[panel[edges[hits[:, 0], 0]] == panel[faces[hits[:, 1], 0]]]
        near = np.zeros(len(p), bool)
        near[edges[hits[:, 0]].ravel()] = True
        near[faces[hits[:, 1]].ravel()] = True
        return near, len(hits)

    return _smooth_out(x, edges, body, clearance, crossings, rings=1, rounds=rounds)


def _triangle_areas(corners: np.ndarray) -> np.ndarray:
    """Areas of triangles [F,3,D] (D = 2 or 3)."""
    d1, d2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    if corners.shape[2] == 2:
        return 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    return 0.5 * np.linalg.norm(np.cross(d1, d2), axis=1)


def _uncollapse(x: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, body: BodyPose, clearance: float,
                rounds: int = 10) -> np.ndarray:
    """Triangles that pushing out of the skin collapsed (corners inside a fold of a very
    heavy body all moved to about the same point) spread again: their vertices and two
    rings of neighbours take their neighbours' mean, then are pushed out again."""
    from tryon.sim.geometry import mesh_edges

    rest = _triangle_areas(corner_uv)

    def collapsed(p: np.ndarray) -> tuple[np.ndarray, int]:
        bad = _triangle_areas(p[faces]) < 0.05 * rest
        near = np.zeros(len(p), bool)
        near[faces[bad].ravel()] = True
        return near, int(bad.sum())

    return _smooth_out(x, mesh_edges(faces), body, clearance, collapsed, rings=2, rounds=rounds)[0]


def clear_of_skin(x: np.ndarray, body: BodyPose, clearance: float) -> tuple[np.ndarray, int]:
    """Points closer to the skin than `clearance` (or inside) moved out along the skin's
    normal (`tryon.sim.geometry.push_outside`), and how many moved."""
    from tryon.sim.geometry import push_outside

    out, moved, _ = push_outside(x, body.vertices, body.faces, clearance)
    return out, int(moved.sum())


# Where the thighs leave less room than two layers at the placement clearance (a very
# heavy body's inner thighs, 12-20 mm apart), pushing a welded trouser's two leg tubes out
# to that clearance puts them through each other (a 175 cm, 138 kg woman: 114 crossings
# below the crotch at 12 mm, none at 5 mm): they are pushed out only this far, and the
# relaxation's contact forces take them the rest of the way.
TIGHT_CLEARANCE = 0.005


def _welded_clear_of_skin(pos: np.ndarray, faces: np.ndarray, edges: np.ndarray, body: BodyPose,
                          clearance: float) -> tuple[np.ndarray, int, float]:
    """`clear_of_skin` of a garment welded where it was placed, at `clearance`, or at
    `TIGHT_CLEARANCE` when that would put the garment through itself and the tighter push
    crosses less: (positions, how many moved, the clearance used)."""
    from tryon.sim.geometry import edge_face_intersections

    out, pushed = clear_of_skin(pos, body, clearance)
    crossings = len(edge_face_intersections(out, edges, out, faces, True))
    if clearance > TIGHT_CLEARANCE and crossings:
        tight, n = clear_of_skin(pos, body, TIGHT_CLEARANCE)
        if len(edge_face_intersections(tight, edges, tight, faces, True)) < crossings:
            log.info("pushed out of the skin to %.0f mm only: at %.0f mm the garment crossed itself",
                     1000 * TIGHT_CLEARANCE, 1000 * clearance)
            return tight, n, TIGHT_CLEARANCE
    return out, pushed, clearance


DRESSING_THICKNESS = 0.003  # m: contact distance while dressing (the drape then uses the request's)
STILL_AIR_DAMPING = 8.0  # 1/s: dressing moves cloth to its place without swinging


def cloth_on_body(cloth, fabric: Fabric, body, thickness: float, friction: float = 0.0, self_collision: bool = True,
                  self_friction: float = 0.3, still: bool = False, stitches: np.ndarray | None = None,
                  stitch_stiffness: float = 0.0, pins: list | None = None, regions: list | None = None):
    """The `ClothModel` of a garment around a body obstacle, for dressing (`still`: no
    gravity, still-air damping) and draping alike."""
    from tryon.sim.model import ClothModel, CollisionSettings

    return ClothModel(cloth, fabric, obstacles=[body], pins=pins or [],
                      gravity=(0.0, 0.0, 0.0) if still else (0.0, 0.0, -9.8),
                      collision=CollisionSettings(thickness=thickness, friction=friction, self_friction=self_friction,
                                                  self_collision=self_collision),
                      stitches=None if stitches is None else torch.from_numpy(stitches),
                      stitch_stiffness=stitch_stiffness, air_damping=STILL_AIR_DAMPING if still else 0.0,
                      regions=regions)


# --------------------------------------------------------------------------- sewing
@dataclass
class DressedGarment:
    """A sewn garment around a body: vertices [N,3], faces [F,3], material coordinates
    per vertex and per face corner, the panel of each face and the pattern."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    corner_uv: np.ndarray
    face_panel: np.ndarray
    pattern: Pattern | None      # None: imported from an OBJ (tryon.drape.obj_garment)
    seam_vertices: np.ndarray
    stats: dict = field(default_factory=dict)

    def cloth_mesh(self, x: np.ndarray | None = None):
        from tryon.sim.mesh import ClothMesh

        pos = self.vertices if x is None else x
        return ClothMesh(torch.from_numpy(pos), torch.from_numpy(self.uv), torch.from_numpy(self.faces),
                         name=self.name, face_uv=torch.from_numpy(self.corner_uv))

    @property
    def name(self) -> str:
        return self.pattern.name if self.pattern is not None else Path(self.stats.get("source", "garment")).stem

    def save(self, path: str | Path) -> Path:
        with atomic_write(path, "wb") as fh:
            np.savez_compressed(fh, vertices=self.vertices, faces=self.faces, uv=self.uv, corner_uv=self.corner_uv,
                                face_panel=self.face_panel, seam_vertices=self.seam_vertices,
                                pattern=json.dumps(self.pattern.to_dict() if self.pattern is not None else None),
                                stats=json.dumps(self.stats))
        return Path(path)

    @classmethod
    def from_state(cls, state: dict) -> "DressedGarment":
        """The garment of a drape folder's loaded state (`tryon.drape.pipeline.load_state`), as draped."""
        return cls(state["x"], state["faces"], state["uv"], state["corner_uv"], state["face_panel"],
                   Pattern.from_dict(state["pattern"]) if state.get("pattern") else None, np.zeros(0, np.int64))

    @classmethod
    def load(cls, path: str | Path) -> "DressedGarment":
        with np.load(path, allow_pickle=False) as d:
            pattern = json.loads(str(d["pattern"]))
            return cls(d["vertices"], d["faces"], d["uv"], d["corner_uv"], d["face_panel"],
                       Pattern.from_dict(pattern) if pattern is not None else None, d["seam_vertices"],
                       json.loads(str(d["stats"])))


SEW_STALL_STEPS = 20  # a seam gap that closed less than 2 % in this many steps has stalled
# A seam end the skin holds open (the neckline corner of a shoulder seam on a heavy neck and
# trapezius: both sides lie on the skin, which the stitch would pull them through) stalls a
# centimetre or so apart however long it is sewn. Such a gap, up to SKIN_HELD_GAP, is
# welded once it has stalled for SKIN_HELD_STALL_STEPS steps: each side moves at most
# 7.5 mm, along the skin, and the relaxation after welding evens the cloth out.
SKIN_HELD_GAP = 0.015
SKIN_HELD_STALL_STEPS = 3 * SEW_STALL_STEPS


def sew(mesh: GarmentMesh, x0: np.ndarray, body: BodyPose, fabric: Fabric, dt: float = 0.01, max_steps: int = 300,
        tolerance: float = 0.003, stiffness: float = 120.0, max_stiffness: float = 2000.0, max_gap: float = 0.01,
        progress: bool = True) -> tuple[np.ndarray, dict]:
    """Pull the seams shut in simulation; returns panel-vertex positions [N,3] and stats.
    The stitch stiffness grows `SEW_TIGHTENING` a step (up to `max_stiffness`), so the
    seams close gently first and then tightly against the cloth's own resistance. Sewing
    stops when every gap is under `tolerance`, or under `SEAMS_CLOSED` and no longer
    closing (a coarse neckline against the skin); seams that end within `max_gap` are
    welded by the caller, and so are gaps up to `SKIN_HELD_GAP` when every stitch still
    open is held apart by the skin (`held_open_by_skin`); a wider gap is an error. (Closing the last 3 mm to 1 mm took a
    denim dress 40 of its 70 steps; welding moves each side 1.5 mm, and the folds that
    can put through the cloth next to it are smoothed out after welding.)"""
    from tryon.sim.integrator import ImplicitEulerSolver, StepOptions
    from tryon.sim.loop import run
    from tryon.sim.mesh import ClothMesh
    from tryon.sim.model import Control
    from tryon.sim.obstacles import Obstacle

    cloth = ClothMesh(torch.from_numpy(x0), torch.from_numpy(mesh.uv), torch.from_numpy(mesh.faces), name=mesh.pattern.name)
    model = cloth_on_body(cloth, fabric, Obstacle("body", body.vertices, body.faces), DRESSING_THICKNESS,
                          self_collision=True, still=True, stitches=mesh.stitches, stitch_stiffness=stiffness)
    st = mesh.stitches
    gap0 = stitch_gap(x0, st)
    ramp = {"k": stiffness}

    def tightening(step: int, t: float) -> Control:
        k, ramp["k"] = ramp["k"], min(max_stiffness, ramp["k"] * SEW_TIGHTENING)
        return Control(stitch_stiffness=k)

    seams = {"gap": gap0, "history": []}

    def stalled(history: list, steps: int) -> bool:
        return len(history) > steps and history[-1] > 0.98 * history[-1 - steps]

    def closed(rec) -> bool:  # shut, or as shut as it gets (a weldable gap that stopped closing)
        x = rec.state.x.numpy()
        seams["gap"] = gap = stitch_gap(x, st)
        history = seams["history"]
        history.append(gap)
        if gap <= tolerance or (gap <= SEAMS_CLOSED and stalled(history, SEW_STALL_STEPS)):
            return True
        return (max_gap < gap <= SKIN_HELD_GAP and stalled(history, SKIN_HELD_STALL_STEPS)
                and held_open_by_skin(x, st, body, tolerance))

    t0 = time.perf_counter()
    state = model.initial_state()
    steps = 0
    if gap0 > tolerance:
        outcome = run(ImplicitEulerSolver(model, StepOptions(linear_solver=DRESSING_LINEAR_SOLVER)), state, dt,
                      until=max_steps, observers=[closed], control=tightening,
                      progress="sewing" if progress else None)
        state, steps = outcome.state, outcome.step
    gap = seams["gap"]
    held = max_gap < gap <= SKIN_HELD_GAP and held_open_by_skin(state.x.numpy(), st, body, tolerance)
    if gap > max_gap and not held:
        x = state.x.numpy()
        g = np.linalg.norm(x[st[:, 0]] - x[st[:, 1]], axis=1)
        worst = np.argsort(-g)[:3]
        names = [mesh.pattern.panels[k].name for k in mesh.panel_of_vertex[st[worst, 0]]]
        where = "; ".join(f"{n} vertex {int(st[k, 0])} at ({', '.join(f'{100 * c:.1f}' for c in x[st[k, 0]])}) cm, "
                          f"{100 * g[k]:.1f} cm from its partner" for n, k in zip(names, worst))
        raise SimulationError(f"sewing {mesh.pattern.name}: seams still {gap * 100:.1f} cm apart after {steps} steps ({where})")
    stats = {"sew_steps": steps, "sew_gap_start_m": gap0, "sew_gap_end_m": gap, "sew_s": time.perf_counter() - t0}
    if held:
        stats["sew_held_by_skin"] = True
    return state.x.numpy(), stats


def held_open_by_skin(x: np.ndarray, stitches: np.ndarray, body: BodyPose, shut: float) -> bool:
    """Whether every stitch pair still open (more than `shut` apart) lies on the skin at
    both ends (within twice the dressing contact distance): the body, not the cloth, holds
    it open, and every other seam is shut."""
    from tryon.sim.geometry import signed_obstacle_distance

    g = np.linalg.norm(x[stitches[:, 0]] - x[stitches[:, 1]], axis=1)
    ends = np.unique(stitches[g > shut].reshape(-1))
    return bool(len(ends)) and bool(np.all(signed_obstacle_distance(x[ends], body.vertices, body.faces)
                                           <= 2.0 * DRESSING_THICKNESS))


SEAMS_CLOSED = 0.005  # m: a placement whose every stitch pair is this close is welded at once


def stitch_gap(x: np.ndarray, stitches: np.ndarray) -> float:
    """The widest gap (m) between stitched vertex pairs; 0 without stitches."""
    return float(np.linalg.norm(x[stitches[:, 0]] - x[stitches[:, 1]], axis=1).max()) if len(stitches) else 0.0
SEW_TIGHTENING = 1.06  # the stitch stiffness's growth per sewing step


RELAX_WINDOW = 5      # steps: the relaxation's minimum length, and the span over which it must keep slowing down
RELAX_SLOWING = 0.9  # ... by this factor at least, or the welding strain is spent
RELAX_DRIFT_SPEED = 0.3  # m/s: drift and contact jitter are slower; a faster garment is still spending strain


class RelaxTest:
    """Stops a relaxation once the fastest vertex is slower than `rest_speed` (from step
    `RELAX_WINDOW` on), or, with `until_slowing_stops`, once it has stopped slowing down:
    still faster than `RELAX_SLOWING` times its speed `RELAX_WINDOW` steps before (from
    step 2 x `RELAX_WINDOW` on), and slower than `RELAX_DRIFT_SPEED`. The strain that
    welding left is spent by then, and what still moves is the garment drifting in
    weightless air and contact jitter on the skin, which gravity and the drape's own
    settling take care of. (A women's XL dress on a 158 cm / 92 kg body: 0.89 m/s after
    the first step, 0.17 by the fifth, then 0.10-0.17 for the next 75 steps. Without the
    speed bound a women's S knit dress stopped at 0.97 m/s after 10 steps and had not
    settled 190 drape steps later.)"""

    def __init__(self, rest_speed: float, until_slowing_stops: bool = True):
        self.rest_speed, self.until_slowing_stops = rest_speed, until_slowing_stops
        self.speeds: list[float] = []
        self.stuck = False

    @property
    def speed(self) -> float:
        return self.speeds[-1] if self.speeds else float("inf")

    def __call__(self, rec: StepRecord) -> bool:
        v = rec.state.v.numpy()
        self.speeds.append(float(np.linalg.norm(v, axis=1).max()) if len(v) else 0.0)
        if rec.stats.fallback:
            # even halved steps could not resolve a contact (a welded shoulder seam pressed
            # into its own fold: the cloth then stands still at 40 s a step); the drape's
            # own contact distance and steps take it from here
            self.stuck = True
            return True
        if len(self.speeds) < RELAX_WINDOW:
            return False
        if self.speed <= self.rest_speed:
            return True
        return (self.until_slowing_stops and len(self.speeds) >= 2 * RELAX_WINDOW and self.speed < RELAX_DRIFT_SPEED
                and self.speed > RELAX_SLOWING * self.speeds[-1 - RELAX_WINDOW])


def relax(x: np.ndarray, faces: np.ndarray, uv: np.ndarray, corner_uv: np.ndarray, body: BodyPose, fabric: Fabric,
          name: str, dt: float = 0.01, max_steps: int = 40, rest_speed: float = 0.02,
          until_slowing_stops: bool = False) -> tuple[np.ndarray, dict]:
    """Let a welded garment placed around the body relax from its placement strain: the
    cloth simulator with the body as obstacle, self-collision on, gravity off and
    still-air damping, until the fastest vertex is slower than `rest_speed` or, with
    `until_slowing_stops` (a sewn garment, whose welds closed only the last millimetres),
    no longer slowing down (`RelaxTest`); at least `RELAX_WINDOW` steps, at most
    `max_steps`. A placement welded at once (skirts, trousers) carries the placement's
    whole strain and relaxes to `rest_speed` or `max_steps`: stopped when it no longer
    slowed, women's XXL trousers left the relaxation at 0.58 m/s and did not settle in the
    drape. (Relaxing those with twice the step, 20 steps of 20 ms, left made-to-measure
    denim trousers for a 175 cm, 138 kg woman at 0.15 m/s instead of 0.25, and that drape
    took 46 s instead of 63; but the knit pair for the same body then started with its
    crotch pressed through itself and stopped in the fail-safe.)"""
    from tryon.sim.integrator import ImplicitEulerSolver, StepOptions
    from tryon.sim.loop import run
    from tryon.sim.mesh import ClothMesh
    from tryon.sim.obstacles import Obstacle

    cloth = ClothMesh(torch.from_numpy(x), torch.from_numpy(uv), torch.from_numpy(faces), name=name,
                      face_uv=torch.from_numpy(corner_uv))
    model = cloth_on_body(cloth, fabric, Obstacle("body", body.vertices, body.faces), DRESSING_THICKNESS,
                          self_collision=True, still=True)
    t0 = time.perf_counter()
    relaxed = RelaxTest(rest_speed, until_slowing_stops)
    outcome = run(ImplicitEulerSolver(model, StepOptions(linear_solver=DRESSING_LINEAR_SOLVER)), model.initial_state(), dt,
                  until=max_steps, observers=[relaxed])
    stats = {"relax_steps": outcome.step, "relax_final_speed": relaxed.speed, "sew_s": time.perf_counter() - t0}
    if relaxed.stuck:
        stats["relax_stuck"] = True
    return outcome.state.x.numpy(), stats


def dress_pattern(pattern: Pattern, body: BodyPose, fabric: Fabric, edge_length: float = 0.012,
                  clearance: float = 0.012, progress: bool = True, mesh: GarmentMesh | None = None) -> DressedGarment:
    """Triangulate, place, sew and weld a pattern around a posed body. A placement whose
    seams all start closed (trousers) is welded first and then relaxed with self-collision
    on, so the garment never passes through itself; otherwise the panels start apart
    (`placed_apart`) and the seams are sewn shut in simulation, with self-collision on
    (stitched vertices are one vertex to it), welded and relaxed.
    The dressed garment's self-intersections (edge through triangle) are counted in its
    stats: a drape cannot undo them. `mesh` is the pattern's triangulation when the
    caller has one (`transfer_mesh`: one topology for every size)."""
    from tryon.sim import geometry as geo
    from tryon.sim.geometry import mesh_edges

    t0 = time.perf_counter()
    if mesh is None:
        mesh = triangulate_pattern(pattern, edge_length)
    elif mesh.pattern is not pattern:
        raise TryonError(f"the mesh handed to dress {pattern.name} triangulates another pattern")
    x = place_pattern(mesh, body, clearance)
    st = mesh.stitches
    unfolded = 0
    unfold_welded = False
    if len(st) and stitch_gap(x, st) <= SEAMS_CLOSED:
        # where a trouser panel turns from leg to torso above the crotch its rows can fold
        smoothed, unfolded = _unfold(x, mesh.faces, mesh_edges(mesh.faces), mesh.panel_of_vertex, body, clearance)
        if stitch_gap(smoothed, st) <= SEAMS_CLOSED:
            x = smoothed
        else:
            # smoothing each panel on its own tore the seams open (the crotch of a heavy
            # man: 6.8 cm, and sewing trousers from there took a minute a step): the
            # placement is welded as it is and the welded garment is smoothed instead,
            # pushed out only `TIGHT_CLEARANCE` (his thighs leave no room for more)
            unfold_welded = True
    gap0 = stitch_gap(x, st)
    closed = gap0 <= SEAMS_CLOSED
    if closed:
        stats = {"sew_steps": 0, "sew_gap_start_m": gap0, "sew_gap_end_m": 0.0, "sew_s": 0.0}
    else:
        x, pushed, shift = placed_apart(x, mesh, body, clearance)
        # a coarse mesh cannot follow the neck's curve everywhere: a neckline stitch can
        # stay a few millimetres open against the skin; welding it moves each side by at
        # most half of `max_gap`
        x, stats = sew(mesh, x, body, fabric, max_gap=max(0.01, 0.5 * edge_length), progress=progress)
        stats["sleeve_shift_m"] = shift
    pos, faces, corner_uv, group = merge_stitched(mesh, x)
    edges = mesh_edges(faces)
    if closed:
        if unfold_welded:
            pos, unfolded = _unfold(pos, faces, edges, np.zeros(len(pos), np.int64), body, TIGHT_CLEARANCE)
        pos, pushed, pushed_to = _welded_clear_of_skin(pos, faces, edges, body, clearance)
        pos = _uncollapse(pos, faces, corner_uv, body, pushed_to)
        stats["skin_clearance_m"] = pushed_to
    else:
        # welding a seam a millimetre or two open can put it through a tight fold next to
        # it (the bodice folded back under the armhole at the armpit): smooth such folds out
        if stats.get("sew_held_by_skin"):
            # the seam the skin held open was welded at its middle, on or in the skin
            pos, _ = clear_of_skin(pos, body, 2.0 * DRESSING_THICKNESS)
        pos, unfolded = _unfold(pos, faces, edges, np.zeros(len(pos), np.int64), body, DRESSING_THICKNESS)
    uv = np.zeros((len(pos), 2))
    uv[faces.reshape(-1)] = corner_uv.reshape(-1, 2)
    # a placement welded at once relaxes from its placement strain; a sewn one from the
    # strain that welding a seam a few millimetres open leaves (a coarse neckline welded
    # 6 mm apart flung the drape's first step)
    pos, relaxed = relax(pos, faces, uv, corner_uv, body, fabric, pattern.name, until_slowing_stops=not closed)
    stats.update({k: v for k, v in relaxed.items() if k != "sew_s"}, sew_s=stats["sew_s"] + relaxed["sew_s"])
    owner = mesh.panel_of_vertex[mesh.faces[:, 0]]
    counts = np.bincount(group, minlength=len(pos))
    n_self, _ = geo.count_intersections(pos, faces, edges, np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64))
    stats.update({"vertices": int(len(pos)), "faces": int(len(faces)), "pushed_out_at_start": pushed, "unfolded_crossings": unfolded,
                  "self_intersections": int(n_self), "edge_length_m": edge_length, "dress_s": time.perf_counter() - t0})
    if n_self:
        log.warning("dressing %s: the sewn garment crosses itself at %d edge-triangle pairs", pattern.name, n_self)
    return DressedGarment(pos, faces, uv, corner_uv, owner, pattern, np.nonzero(counts > 1)[0], stats)


def cache_dir() -> Path:
    return Path(os.environ.get("TRYON_CACHE_DIR", str(Path.home() / ".cache" / "tryon"))) / "dressed"


def cache_key(pattern: Pattern, body: BodyPose, fabric: Fabric, edge_length: float, mesh: GarmentMesh | None = None) -> str:
    h = hashlib.sha256()
    if mesh is not None:
        h.update(np.round(mesh.points2d, 7).tobytes() + mesh.faces.tobytes())
    h.update(json.dumps(pattern.to_dict(), sort_keys=True).encode())
    h.update(np.round(body.vertices, 5).tobytes())
    h.update(json.dumps(fabric.parameters().tolist()).encode())
    h.update(f"{edge_length:.5f}-v{DRESS_VERSION}".encode())
    return h.hexdigest()[:24]


def dress_cached(pattern: Pattern, body: BodyPose, fabric: Fabric, edge_length: float = 0.012, progress: bool = True,
                 mesh: GarmentMesh | None = None) -> DressedGarment:
    """`dress_pattern`, cached on disk per pattern, body, fabric, edge length and mesh."""
    path = cache_dir() / f"{pattern.name}-{cache_key(pattern, body, fabric, edge_length, mesh)}.npz"
    if path.exists():
        try:
            g = DressedGarment.load(path)
            g.stats["cached"] = True
            return g
        except (OSError, ValueError, KeyError) as exc:  # a damaged cache entry is rebuilt
            log.warning("ignoring unreadable dressing cache %s (%s)", path, exc)
    g = dress_pattern(pattern, body, fabric, edge_length, progress=progress, mesh=mesh)
    g.save(path)
    # the garment as the cache holds it (the pattern's points rounded to 1 um), so that a
    # drape from a fresh dressing equals the drape from the cached one bit for bit
    g = DressedGarment.load(path)
    g.stats["cached"] = False
    return g
