"""Scalar fields to colours (fit maps) and a labelled colour-bar legend.

Colour maps are sampled once from matplotlib into 256-entry lookup tables and then
interpolated with numpy, so mapping millions of values is a couple of array ops.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from typing import Any

import numpy as np

from tryon.errors import TryonError

__all__ = ["scalar_to_rgb", "add_colorbar", "colormap_lut"]

_LUT_SIZE = 256


@lru_cache(maxsize=16)
def colormap_lut(cmap: str) -> np.ndarray:
    """``[256, 3]`` sRGB table (floats 0..1) of a matplotlib colour map, e.g. viridis, turbo, coolwarm."""
    from matplotlib import colormaps

    if cmap not in colormaps:
        raise TryonError(f"unknown colour map {cmap!r}; try 'viridis', 'turbo' or 'coolwarm'")
    table = colormaps[cmap](np.linspace(0.0, 1.0, _LUT_SIZE))[:, :3]
    table = np.asarray(table, dtype=np.float64)
    table.setflags(write=False)
    return table


def _normalize(values: np.ndarray, vmin: float | None, vmax: float | None) -> tuple[np.ndarray, float, float]:
    finite = np.isfinite(values)
    lo = float(values[finite].min()) if vmin is None and finite.any() else float(vmin if vmin is not None else 0.0)
    hi = float(values[finite].max()) if vmax is None and finite.any() else float(vmax if vmax is not None else 1.0)
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi < lo:
        raise TryonError(f"colour range must be finite with vmin <= vmax, got [{lo}, {hi}]")
    if hi == lo:
        return np.where(finite, 0.5, np.nan), lo, hi
    return np.clip((values - lo) / (hi - lo), 0.0, 1.0), lo, hi


def scalar_to_rgb(
    values: Any,
    vmin: float | None = None,
    vmax: float | None = None,
    cmap: str = "viridis",
    nan_color: Sequence[float] = (0.6, 0.6, 0.6),
) -> np.ndarray:
    """Map scalars to sRGB colours ``[..., 3]`` (floats 0..1).

    Values are clipped to ``[vmin, vmax]`` (default: the finite data range); NaN/inf
    get ``nan_color``. Colours are linearly interpolated in a 256-entry table.
    """
    if hasattr(values, "detach"):
        values = values.detach().cpu().numpy()
    v = np.asarray(values, dtype=np.float64)
    t, _, _ = _normalize(v, vmin, vmax)
    lut = colormap_lut(cmap)
    x = np.nan_to_num(t, nan=0.0) * (_LUT_SIZE - 1)
    i0 = np.clip(np.floor(x).astype(np.int64), 0, _LUT_SIZE - 2)
    frac = (x - i0)[..., None]
    rgb = lut[i0] * (1.0 - frac) + lut[i0 + 1] * frac
    rgb[~np.isfinite(t)] = np.asarray(nan_color, dtype=np.float64)
    return rgb


# ----------------------------------------------------------------------------- legend


def label_font(size: int) -> Any:
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has only the fixed bitmap font
        return ImageFont.load_default()


def _tick_values(vmin: float, vmax: float, ticks: int | Sequence[float] | None) -> np.ndarray:
    if ticks is None:
        ticks = 5
    if isinstance(ticks, int):
        return np.linspace(vmin, vmax, max(ticks, 2)) if vmax > vmin else np.array([vmin])
    vals = np.asarray(ticks, dtype=np.float64).reshape(-1)
    return vals[(vals >= min(vmin, vmax)) & (vals <= max(vmin, vmax))]


def _text_size(draw: Any, text: str, font: Any) -> tuple[int, int]:
    left, top, right, bottom = draw.textbbox((0, 0), text, font=font)
    return right - left, bottom - top


def _draw_text(draw: Any, xy: tuple[float, float], text: str, font: Any, ink: Any, anchor: tuple[float, float]) -> None:
    """Draw ``text`` so that the fraction ``anchor`` (x, y) of its ink box lands on ``xy``."""
    left, top, right, bottom = draw.textbbox((0, 0), text, font=font)
    x = xy[0] - left - anchor[0] * (right - left)
    y = xy[1] - top - anchor[1] * (bottom - top)
    draw.text((round(x), round(y)), text, fill=ink, font=font)


def add_colorbar(
    image: np.ndarray,
    vmin: float,
    vmax: float,
    cmap: str = "viridis",
    label: str = "",
    ticks: int | Sequence[float] | None = None,
    fmt: str = "{:.3g}",
    extend: bool = True,
) -> np.ndarray:
    """Draw a vertical colour bar with tick labels and a title beside ``image``.

    ``ticks``: a count (default 5, evenly spaced) or explicit values. With ``extend``
    (default) a panel of the image's background colour (its top-left pixel) is added
    on the right so the legend never covers the object; otherwise the legend is drawn
    over the right edge of the image. Returns a new uint8 ``[H, W', 3]`` image.
    """
    from PIL import Image, ImageDraw

    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise TryonError(f"add_colorbar needs a uint8 [H, W, 3] image, got {img.dtype} {img.shape}")
    if not (np.isfinite(vmin) and np.isfinite(vmax)) or vmax < vmin:
        raise TryonError(f"add_colorbar range must be finite with vmin <= vmax, got [{vmin}, {vmax}]")
    h, w = img.shape[:2]
    font = label_font(max(10, round(h * 0.028)))
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    tick_vals = _tick_values(float(vmin), float(vmax), ticks)
    texts = [fmt.format(v) for v in tick_vals]
    text_w = max([_text_size(probe, t, font)[0] for t in texts] + [0])
    label_w, label_h = _text_size(probe, label, font) if label else (0, 0)
    bar_w, tick_len, pad = max(8, round(h * 0.03)), max(3, round(h * 0.008)), max(6, round(h * 0.02))
    panel_w = max(pad + bar_w + tick_len + pad // 2 + text_w + pad, label_w + 2 * pad)

    bg = img[0, 0].astype(np.int64)
    if extend:
        canvas = np.concatenate([img, np.broadcast_to(img[0, 0], (h, panel_w, 3))], axis=1).copy()
    else:
        canvas = img.copy()
    x0 = canvas.shape[1] - panel_w + pad
    top, bottom = round(0.2 * h), round(0.8 * h)
    if label:
        top = max(top, label_h + 2 * pad)
    rows = np.linspace(vmax, vmin, bottom - top)
    canvas[top:bottom, x0 : x0 + bar_w] = np.rint(scalar_to_rgb(rows, vmin, vmax, cmap) * 255)[:, None, :]

    ink = (0, 0, 0) if bg @ np.array([0.299, 0.587, 0.114]) > 128 else (255, 255, 255)
    pil = Image.fromarray(canvas)
    draw = ImageDraw.Draw(pil)
    draw.rectangle([x0 - 1, top - 1, x0 + bar_w, bottom], outline=ink, width=1)
    span = (vmax - vmin) or 1.0
    for value, text in zip(tick_vals, texts):
        y = round(bottom - 1 - (value - vmin) / span * (bottom - top - 1))
        draw.line([x0 + bar_w, y, x0 + bar_w + tick_len, y], fill=ink, width=1)
        _draw_text(draw, (x0 + bar_w + tick_len + pad // 2, y), text, font, ink, (0.0, 0.5))
    if label:
        _draw_text(draw, (canvas.shape[1] - panel_w / 2, top - pad), label, font, ink, (0.5, 1.0))
    return np.asarray(pil)
