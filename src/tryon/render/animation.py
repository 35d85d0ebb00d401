"""Animations from rendered frames: GIF (Pillow) and MP4 (optional imageio-ffmpeg)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from tryon.errors import TryonError
from tryon.io.atomic import atomic_path, atomic_write

__all__ = ["write_gif", "write_mp4"]


def _checked_frames(frames: Sequence[np.ndarray], out: Path) -> list[np.ndarray]:
    arrs = [np.asarray(f) for f in frames]
    if not arrs:
        raise TryonError(f"writing {out}: no frames given")
    shape = arrs[0].shape
    for i, a in enumerate(arrs):
        if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3 or a.shape != shape:
            raise TryonError(
                f"writing {out}: frame {i} must be uint8 [H, W, 3] like frame 0 {shape}, got {a.dtype} {a.shape}"
            )
    return arrs


def _checked_fps(fps: float, out: Path) -> float:
    if not (np.isfinite(fps) and fps > 0):
        raise TryonError(f"writing {out}: fps must be positive, got {fps}")
    return float(fps)


def write_gif(path: str | os.PathLike[str], frames: Sequence[np.ndarray], fps: float = 20.0, loop: int = 0) -> Path:
    """Write RGB frames as an animated GIF (atomic); ``loop=0`` repeats forever.

    GIF delays have 10 ms resolution, so the played rate is approximate. Pillow merges
    consecutive identical frames (their delays add up).
    """
    from PIL import Image

    out = Path(path)
    arrs = _checked_frames(frames, out)
    duration = max(int(round(1000.0 / _checked_fps(fps, out))), 10)
    images = [Image.fromarray(a) for a in arrs]
    with atomic_write(out, "wb") as fh:
        images[0].save(fh, format="GIF", save_all=True, append_images=images[1:], duration=duration, loop=loop)
    return out


def write_mp4(path: str | os.PathLike[str], frames: Sequence[np.ndarray], fps: float = 30.0) -> Path:
    """Write RGB frames as an H.264 MP4 (atomic) with imageio-ffmpeg, if it is installed.

    Odd widths/heights are padded by one replicated row/column (yuv420p needs even sizes).
    """
    out = Path(path)
    arrs = _checked_frames(frames, out)
    rate = _checked_fps(fps, out)
    try:
        import imageio_ffmpeg
    except ImportError:
        raise TryonError(
            f"writing {out}: MP4 output needs the optional package imageio-ffmpeg "
            "(pip install imageio-ffmpeg); or write a GIF with write_gif instead"
        ) from None
    h, w = arrs[0].shape[:2]
    pad = ((0, h % 2), (0, w % 2), (0, 0))
    size = (w + w % 2, h + h % 2)
    with atomic_path(out) as tmp:
        writer = imageio_ffmpeg.write_frames(str(tmp), size, fps=rate, codec="libx264", macro_block_size=2)
        writer.send(None)
        try:
            for a in arrs:
                writer.send(np.ascontiguousarray(np.pad(a, pad, mode="edge")))
        finally:
            writer.close()
    return out
