"""A graphic print on a garment's front panel: a user's image, placed on the pattern, that
is also a material.

A screen print is a layer of ink cured into the fabric: where it covers the cloth, the
cloth is heavier and stiffer (a plastisol deposit of about 0.1 mm weighs 100-200 g/m^2
and stiffens knit jersey several times in bending). `GraphicPrint` holds the image and
where it sits on the front panel (centred, its top a little below the neckline), says
which garment faces it covers (`faces`: the image's alpha at each face's centre), gives
the simulator a `MaterialRegion` of those faces, and gives renders its colour at any
material coordinate (`rgba_at`), so the print drapes with the shirt.

Placement is in panel coordinates (metres; x across with the body's left towards +x seen
from the front, y up from the hem, tryon.garment.drafts): the image's columns run along
+x, its rows down -y. An image without an alpha channel is an opaque rectangle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tryon.errors import InputFileError, TryonError

# Defaults of a plastisol screen print on jersey (assumed, not measured): ink areal density
# and multipliers of the fabric's membrane and bending stiffness where the ink lies.
PRINT_DENSITY = 0.15       # kg/m^2 added
PRINT_STRETCH_SCALE = 3.0
PRINT_BEND_SCALE = 10.0
PRINT_WIDTH = 0.24         # m
PRINT_TOP_BELOW_NECK = 0.07  # m, from the lowest point of the front neckline
MAX_PIXELS = 4096          # per side
COVERED = 0.5              # alpha at a face's centre above which the face is printed


def _load_rgba(path: Path) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    from tryon.limits import check_file_size

    if not path.is_file():
        raise InputFileError(f"print image {path} does not exist; give a PNG file")
    check_file_size(path, "print image")
    try:
        with Image.open(path) as im:
            if max(im.size) > MAX_PIXELS:
                raise InputFileError(f"print image {path} is {im.size[0]}x{im.size[1]} pixels; at most {MAX_PIXELS} per "
                                     "side (a print needs no more than about 1 mm per pixel)")
            rgba = np.asarray(im.convert("RGBA"), dtype=np.float64) / 255.0
    except (UnidentifiedImageError, Image.DecompressionBombError, OSError, ValueError) as exc:
        raise InputFileError(f"print image {path} cannot be read as an image ({exc}); give a PNG file") from None
    if rgba.ndim != 3 or min(rgba.shape[:2]) < 2:
        raise InputFileError(f"print image {path} has no usable pixels (shape {rgba.shape}); give at least 2x2 pixels")
    if rgba[..., 3].max() < COVERED:
        raise InputFileError(f"print image {path} is transparent everywhere; nothing would be printed")
    return rgba


@dataclass
class GraphicPrint:
    """An image printed on the front panel, `width` metres wide (module docstring)."""

    rgba: np.ndarray                    # [rows, cols, 4] in 0..1
    source: str = "print"
    width: float = PRINT_WIDTH
    top_below_neck: float = PRINT_TOP_BELOW_NECK
    added_density: float = PRINT_DENSITY
    stretch_scale: float = PRINT_STRETCH_SCALE
    bend_scale: float = PRINT_BEND_SCALE
    origin: np.ndarray = field(default_factory=lambda: np.zeros(2))  # panel (x, y) of the image's top-left corner

    @classmethod
    def load(cls, path: str | Path, width_cm: float = 100 * PRINT_WIDTH, **material) -> "GraphicPrint":
        """Read a PNG (or any image PIL reads); `material` overrides the ink's defaults."""
        if not (np.isfinite(width_cm) and 2.0 <= width_cm <= 60.0):
            raise TryonError(f"print width {width_cm} cm is outside 2-60 cm")
        out = cls(_load_rgba(Path(path)), str(path), width=width_cm / 100.0, **material)
        out.check_material()
        return out

    def check_material(self) -> None:
        for what, value in (("stretch scale", self.stretch_scale), ("bend scale", self.bend_scale)):
            if not (np.isfinite(value) and 0.1 <= value <= 1000.0):
                raise TryonError(f"print {what} {value} is outside 0.1-1000 (a multiplier of the fabric's stiffness)")
        if not (np.isfinite(self.added_density) and 0.0 <= self.added_density <= 2.0):
            raise TryonError(f"print density {self.added_density} kg/m^2 is outside 0-2")

    @property
    def height(self) -> float:
        rows, cols = self.rgba.shape[:2]
        return self.width * rows / cols

    def placed_on(self, pattern) -> "GraphicPrint":
        """This print centred on `pattern`'s front panel, its top `top_below_neck` below the
        front neckline's lowest point; refused when the panel is too narrow for it."""
        try:
            front = pattern.panel("front")
        except TryonError:
            raise TryonError(f"a print goes on a front panel, and the {pattern.name} has none "
                             f"(panels: {', '.join(p.name for p in pattern.panels)})") from None
        outline = front.outline()
        neck_low = min(float(e.polyline(50)[:, 1].min()) for e in front.edges if e.name.startswith("neck"))
        top = neck_low - self.top_below_neck
        lo = outline[:, 1].min()
        if top - self.height < lo:
            raise TryonError(f"a {100 * self.width:.0f} cm wide print of this image is {100 * self.height:.0f} cm tall; "
                             f"the front panel has {100 * (top - lo):.0f} cm below the neckline: give a smaller --print-width-cm")
        band = outline[np.abs(outline[:, 1] - (top - 0.5 * self.height)) < 0.05]
        panel_width = float(band[:, 0].max() - band[:, 0].min()) if len(band) else float(np.ptp(outline[:, 0]))
        if self.width > 0.9 * panel_width:
            raise TryonError(f"a {100 * self.width:.0f} cm wide print does not fit on a front panel {100 * panel_width:.0f} cm "
                             "wide; give a smaller --print-width-cm")
        placed = GraphicPrint(**{**self.__dict__})
        placed.origin = np.array([-0.5 * self.width, top])
        return placed

    def rgba_at(self, xy: np.ndarray) -> np.ndarray:
        """The print's colour and alpha [n, 4] at panel points `xy` [n, 2] (alpha 0 off the image),
        bilinear between pixel centres."""
        rows, cols = self.rgba.shape[:2]
        px = (np.asarray(xy, float)[:, 0] - self.origin[0]) / self.width * cols - 0.5
        py = (self.origin[1] - np.asarray(xy, float)[:, 1]) / self.height * rows - 0.5
        inside = (px >= -0.5) & (px <= cols - 0.5) & (py >= -0.5) & (py <= rows - 0.5)
        x0 = np.clip(np.floor(px), 0, cols - 2).astype(int)
        y0 = np.clip(np.floor(py), 0, rows - 2).astype(int)
        fx = np.clip(px - x0, 0, 1)[:, None]
        fy = np.clip(py - y0, 0, 1)[:, None]
        im = self.rgba
        out = ((1 - fy) * ((1 - fx) * im[y0, x0] + fx * im[y0, x0 + 1])
               + fy * ((1 - fx) * im[y0 + 1, x0] + fx * im[y0 + 1, x0 + 1]))
        out[~inside] = 0.0
        return out

    def faces(self, garment) -> np.ndarray:
        """Indices of `garment`'s front-panel faces the print covers (alpha at their centre)."""
        front = _front_faces(garment)
        centre = garment.corner_uv[front].mean(1)
        covered = self.rgba_at(panel_xy(centre))[:, 3] >= COVERED
        return front[covered]

    def touched_faces(self, garment) -> np.ndarray:
        """Front-panel faces whose material extent meets the image's rectangle (what a picture
        of the print must draw finer than the mesh)."""
        front = _front_faces(garment)
        xy = panel_xy(garment.corner_uv[front])                 # [k,3,2]
        lo, hi = xy.min(1), xy.max(1)
        x0, y1 = self.origin
        meets = (hi[:, 0] >= x0) & (lo[:, 0] <= x0 + self.width) & (hi[:, 1] >= y1 - self.height) & (lo[:, 1] <= y1)
        return front[meets]

    def region(self, garment):
        """The simulator's `MaterialRegion` of the printed faces."""
        from tryon.sim.model import MaterialRegion

        faces = self.faces(garment)
        if len(faces) == 0:
            raise TryonError(f"the print {self.source} covers no face of the garment (too small for its "
                             "{:.1f} cm edges?); give a larger --print-width-cm".format(100 * _edge(garment)))
        return MaterialRegion(faces, self.stretch_scale, self.bend_scale, self.added_density, name="print")

    def describe(self, garment) -> dict:
        faces = self.faces(garment)
        e1, e2 = (garment.corner_uv[faces, 1:] - garment.corner_uv[faces, :1]).transpose(1, 0, 2)
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
        return {"image": self.source, "width_cm": round(100 * self.width, 2), "height_cm": round(100 * self.height, 2),
                "faces": int(len(faces)), "area_cm2": round(1e4 * float(area), 1), "added_density_kg_m2": self.added_density,
                "stretch_scale": self.stretch_scale, "bend_scale": self.bend_scale}


def panel_xy(uv: np.ndarray, grain: tuple[float, float] = (0.0, 1.0)) -> np.ndarray:
    """Panel coordinates of material coordinates (u along the grain, v across it; the inverse
    of tryon.garment.triangulate.PanelMesh.material_uv)."""
    g = np.asarray(grain, float)
    uv = np.asarray(uv, float)
    return uv[..., :1] * g + uv[..., 1:2] * np.array([-g[1], g[0]])


def _front_faces(garment) -> np.ndarray:
    if garment.pattern is None:
        raise TryonError("a print needs a garment drafted from a pattern (it goes on the front panel); "
                         "an OBJ garment has no panels")
    names = [p.name for p in garment.pattern.panels]
    if "front" not in names:
        raise TryonError(f"a print goes on a front panel, and the {garment.pattern.name} has none (panels: {', '.join(names)})")
    grain = garment.pattern.panel("front").grain
    if np.linalg.norm(np.asarray(grain) - (0.0, 1.0)) > 1e-9:
        raise TryonError("a print needs a front panel cut on the straight grain")
    return np.flatnonzero(garment.face_panel == names.index("front"))


def _edge(garment) -> float:
    e = garment.corner_uv[:, [1, 2, 0]] - garment.corner_uv
    return float(np.linalg.norm(e, axis=-1).mean())
