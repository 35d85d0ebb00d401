"""How much deformation a fabric's stretching and bending produce: the sensitivity
analysis that places the fabric classes' bin edges (`tryon.perceive.fabric_classes`).

Two standard tests, each simulated to rest for fabrics whose stiffness is stepped along
one axis (the mean of the ten measured Wang 2011 fabrics, its stretching or bending data
scaled, everything else kept):

- stretching: a 1 m square hung from its two top corners (the `hanging` example scene
  without wind, 6.7 cm edges); the deformation is how far the cloth hangs below its own
  length (mm);
- bending: a drape test after Cusick (BS 5058): a 30 cm square laid on a 16 cm square
  pedestal; the deformation is how much of the overhang falls out of the shadow, 100 (1 -
  drape coefficient) %, the coefficient being the shadow's area beyond the pedestal over
  the flat overhang's. (A cantilever strip, Peirce's test, snaps: the fabrics of the
  softer half of the range all fold straight down at the clamp's edge, the stiffer ones
  hold out, so its response jumps instead of grading.)

Each response falls as the stiffness rises and saturates where the fabric barely
deforms. Bin edges are placed at equal steps of the response between the two ends of the
range, so neighbouring classes differ by the same deformation (the chapter's classes are
"set by how much deformation they produce"): narrow bins where a small change of stiffness
shows, wide ones where it no longer does.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from tryon.fabric.blend import fabric_features, scaled_stiffness
from tryon.fabric.presets import mean_preset_fabric
from tryon.fabric.wang2011 import MEASURED_FABRICS, WangFabric

STRETCH_FEATURE, BEND_FEATURE = 0, 2  # columns of `fabric_features`
# the classes span the measured fabrics widened by this fraction of their span each side
RANGE_MARGIN = 0.1
DRAPE_TEST = {"side": 0.3, "pedestal": 0.16, "resolution": 31, "height": 0.5}
SHADOW_PIXELS = 600  # the shadow is rasterised at side / 600 (0.5 mm)
SETTLE_S = {"stretching": 3.0, "bending": 2.5}
AVERAGE_LAST_S = 0.5  # the response is averaged over the last half second (what is left of the swing)
STILL_AIR_DAMPING = 8.0  # 1/s: the tests want the rest shape, not the swing (damping does not move the rest)


@dataclass
class Response:
    axis: str              # "stretching" | "bending"
    log10_stiffness: list[float]  # the fabric feature (log10 N/m or N m) at each sample
    deformation: list[float]  # mm (stretching) or % of the overhang (bending)
    seconds: float


def measured_range(axis: str) -> tuple[float, float]:
    """The feature range the classes span: the measured fabrics' widened by `RANGE_MARGIN`."""
    col = STRETCH_FEATURE if axis == "stretching" else BEND_FEATURE
    values = [float(fabric_features(WangFabric.from_preset(n))[col]) for n in MEASURED_FABRICS]
    lo, hi = min(values), max(values)
    pad = RANGE_MARGIN * (hi - lo)
    return lo - pad, hi + pad


def scaled_fabric(base: WangFabric, axis: str, log10_target: float) -> WangFabric:
    """`base` with its stretching (or bending) data scaled so that the fabric feature of
    that axis is `log10_target` (the features scale linearly with the data)."""
    col = STRETCH_FEATURE if axis == "stretching" else BEND_FEATURE
    factor = 10.0 ** (log10_target - float(fabric_features(base)[col]))
    key = "stretching" if axis == "stretching" else "bending"
    return scaled_stiffness(base, factor if key == "stretching" else 1.0, factor if key == "bending" else 1.0,
                            name=f"{base.name}-{key}-{log10_target:.2f}")


def _hanging_scene(fabric: WangFabric, resolution: int = 16):
    from tryon.sim.scene import example_scene

    return example_scene("hanging", resolution, fabric=fabric.to_arcsim_dict(), duration=SETTLE_S["stretching"],
                         wind={"velocity": [0.0, 0.0, 0.0], "density": 1.0, "drag": 0.0})


def _drape_test_scene(fabric: WangFabric):
    from tryon.sim.scene import parse_scene

    c = DRAPE_TEST
    side, top = c["side"], c["pedestal"]
    spec = {"name": "drape-test", "dt": 0.01, "duration": SETTLE_S["bending"], "frame_time": 0.04,
            "description": "Cusick's drape test: a square of cloth falls over a pedestal",
            "cloth": {"grid": {"resolution": [c["resolution"]] * 2, "size": [side, side],
                               "origin": [-side / 2, -side / 2, c["height"] + 0.005]},
                      "fabric": fabric.to_arcsim_dict()},
            "obstacles": [{"type": "box", "name": "pedestal", "center": [0.0, 0.0, c["height"] / 2],
                           "size": [top, top, c["height"]]}],
            "collision": {"friction": 0.6}}
    return parse_scene(spec, default_name="drape-test")


def shadow_area(x: np.ndarray, faces: np.ndarray, extent: float) -> float:
    """Area (m^2) of the union of the triangles' projections on the floor, rasterised on a
    `SHADOW_PIXELS`-square grid over [-extent, extent]^2."""
    n = SHADOW_PIXELS
    px = 2 * extent / n
    centres = -extent + px * (np.arange(n) + 0.5)
    covered = np.zeros((n, n), bool)
    tri = x[faces][:, :, :2]
    for a, b, c in tri:
        lo = np.clip(((np.minimum(np.minimum(a, b), c) + extent) / px).astype(int), 0, n - 1)
        hi = np.clip(((np.maximum(np.maximum(a, b), c) + extent) / px).astype(int) + 1, 0, n)
        gx, gy = np.meshgrid(centres[lo[0]:hi[0]], centres[lo[1]:hi[1]], indexing="ij")
        p = np.stack([gx, gy], -1)
        d = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        if abs(d) < 1e-14:
            continue
        w1 = ((p[..., 0] - a[0]) * (c[1] - a[1]) - (p[..., 1] - a[1]) * (c[0] - a[0])) / d
        w2 = ((b[0] - a[0]) * (p[..., 1] - a[1]) - (b[1] - a[1]) * (p[..., 0] - a[0])) / d
        covered[lo[0]:hi[0], lo[1]:hi[1]] |= (w1 >= 0) & (w2 >= 0) & (w1 + w2 <= 1)
    return float(covered.sum()) * px * px


def deformation(axis: str, fabric: WangFabric) -> float:
    """The test's deformation for `fabric` at rest: mm (stretching) or % (bending); see
    the module docstring."""
    from tryon.sim.runner import simulate

    scene = _hanging_scene(fabric) if axis == "stretching" else _drape_test_scene(fabric)
    scene.model.air_damping = STILL_AIR_DAMPING
    result = simulate(scene, progress=False)
    x, t = np.asarray(result.positions), np.asarray(result.times)
    last = x[t >= t[-1] - AVERAGE_LAST_S - 1e-9]
    if axis == "stretching":
        top = float(scene.model.mesh.x.numpy()[:, 2].max())
        return 1000.0 * float(np.mean([top - f[:, 2].min() - 1.0 for f in last]))
    side, top = DRAPE_TEST["side"], DRAPE_TEST["pedestal"]
    faces = scene.model.faces.numpy()
    shadow = shadow_area(last[-1], faces, side)
    return 100.0 * (1.0 - (shadow - top * top) / (side * side - top * top))


def measure_response(axis: str, samples: int = 9, progress: bool = True) -> Response:
    """The deformation at `samples` stiffnesses evenly spaced (log) over the classes' range."""
    if axis not in ("stretching", "bending"):
        raise ValueError(f"axis must be 'stretching' or 'bending', got {axis!r}")
    t0 = time.perf_counter()
    base = mean_preset_fabric()
    grid = np.linspace(*measured_range(axis), samples)
    out = [deformation(axis, scaled_fabric(base, axis, float(s)))
           for s in tqdm(grid, desc=f"{axis} sensitivity", disable=not progress)]
    return Response(axis, grid.tolist(), out, time.perf_counter() - t0)


def smoothed_response(response: Response, points: int = 401) -> tuple[np.ndarray, np.ndarray]:
    """The response on a fine grid: a power law in stiffness (a line in log deformation
    against log stiffness), bent by a quadratic term where the data ask for it and the
    bent curve still falls over the whole range. A drape test's fold count changes in
    steps (the stiffest fabrics of the range fall in fewer, larger folds); binning by the
    raw curve would crowd bins into such a step, and a quadratic pulled by it turns back."""
    s = np.asarray(response.log10_stiffness)
    d = np.asarray(response.deformation)
    if np.any(d <= 0):
        raise ValueError(f"the {response.axis} test's deformations must be positive, got {d.min():.3g}")
    fine = np.linspace(s[0], s[-1], points)
    bent = np.polyfit(s, np.log(d), 2)
    slope = np.polyval(np.polyder(bent), fine)
    coeffs = bent if np.all(slope < 0) else np.polyfit(s, np.log(d), 1)
    return fine, np.minimum.accumulate(np.exp(np.polyval(coeffs, fine)))


def equal_deformation_edges(response: Response, bins: int) -> list[float]:
    """Bin edges (log10 stiffness, `bins` + 1 of them, the range's ends included) at equal
    steps of the (smoothed) deformation between the range's ends."""
    s, d = smoothed_response(response)
    if d[0] - d[-1] <= 1e-9 * d[0]:
        raise ValueError(f"the {response.axis} test deforms the same at every stiffness: no bins to set")
    levels = np.linspace(d[0], d[-1], bins + 1)[1:-1]
    # np.interp needs increasing x: read the falling curve backwards (a flat stretch of the
    # monotone curve gets a tiny slope so that it has one inverse)
    rising = d[::-1] + 1e-12 * d[0] * np.arange(len(d))
    inner = np.interp(levels[::-1], rising, s[::-1])[::-1]
    return [float(s[0]), *map(float, inner), float(s[-1])]
