"""Reading photos: any size, JPEG or PNG (or anything Pillow opens), EXIF orientation
honoured, returned as RGB uint8; every failure is one clear error naming the file."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from tryon.errors import InputFileError

MAX_PIXELS = 80_000_000   # a 10k x 8k photo; beyond this Pillow's bomb guard would refuse anyway
MIN_SIDE = 64


def load_photo(path: str | os.PathLike[str]) -> np.ndarray:
    """The photo at `path` as an [H,W,3] uint8 RGB array, turned upright by its EXIF tag."""
    from PIL import Image, ImageOps, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such image file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                if im.width * im.height > MAX_PIXELS:
                    raise InputFileError(f"{path}: {im.width}x{im.height} is too large a picture "
                                         f"(at most {MAX_PIXELS // 1_000_000} megapixels); scale it down")
                im = ImageOps.exif_transpose(im)
                rgb = np.asarray(_to_rgb(im), dtype=np.uint8)
    except InputFileError:
        raise
    except (UnidentifiedImageError, Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise InputFileError(f"{path}: not a picture Pillow can read ({type(exc).__name__})") from exc
    except (OSError, ValueError, SyntaxError, EOFError) as exc:  # truncated or damaged files
        raise InputFileError(f"{path}: the picture is damaged or incomplete ({exc})") from exc
    if min(rgb.shape[:2]) < MIN_SIDE:
        raise InputFileError(f"{path}: {rgb.shape[1]}x{rgb.shape[0]} pixels is too small a picture "
                             f"(at least {MIN_SIDE} on each side)")
    return np.ascontiguousarray(rgb)


def _to_rgb(im):
    """RGB of any mode: transparency over white, 16-bit and float scaled down, palettes expanded."""
    from PIL import Image

    if im.mode in ("I;16", "I;16B", "I;16L", "I", "F"):
        a = np.asarray(im, dtype=np.float64)
        hi = a.max() if a.size and a.max() > 0 else 1.0
        im = Image.fromarray((a / hi * 255).clip(0, 255).astype(np.uint8))
    if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
        im = im.convert("RGBA")
        white = Image.new("RGBA", im.size, (255, 255, 255, 255))
        im = Image.alpha_composite(white, im)
    return im.convert("RGB")
