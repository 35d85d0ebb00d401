"""A clip as pictures: the frames of a video file (OpenCV's reader, which ships with the
person finder) or of a folder of pictures, taken at the rate asked for, and the one person
followed through them.

`follow_person` starts from the tallest person the finder sees in the first frame that
has one, then in each frame takes the person nearest where the followed one was (a
crowd's others are skipped, and a frame where the followed one is lost, or only someone
far away is seen, counts as not found).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tryon.errors import InputFileError, TryonError
from tryon.perceive.images import load_photo
from tryon.perceive.person import PersonInPhoto, people_in_photo

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
PICTURE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".webp", ".tif", ".tiff")
MAX_JUMP = 0.5  # of the followed person's height: farther between frames is someone else


@dataclass
class Frames:
    """RGB frames [H,W,3] uint8 and their times (s from the first frame of the source)."""

    images: list[np.ndarray]
    times: np.ndarray
    source: str

    @property
    def fps(self) -> float:
        return round(float(1.0 / np.median(np.diff(self.times))), 6) if len(self.times) > 1 else 0.0


def _step(rate: float, fps: float) -> int:
    """Every how many source frames one is kept: the kept frames are evenly spaced (the
    clip's rate is rate / step, the nearest to `fps` that is)."""
    return max(1, int(round(rate / fps)))


def read_frames(source: str | Path, fps: float = 5.0, max_frames: int | None = None,
                folder_fps: float = 5.0, start_s: float = 0.0, end_s: float | None = None) -> Frames:
    """The frames of `source` (a video file, or a folder of pictures taken `folder_fps`
    apart, in name order) at about `fps` frames a second (every k-th source frame, so
    they stay evenly spaced: `Frames.fps` is the rate they have), at most `max_frames`,
    from `start_s` to `end_s` of the source (times stay the source's); frames outside
    are not decoded."""
    path = Path(source)
    if not fps > 0 or not folder_fps > 0:
        raise TryonError(f"frame rates must be positive, got {fps} and {folder_fps} per second")
    if max_frames is not None and max_frames < 1:
        raise TryonError(f"max_frames {max_frames}: give at least 1 (or none, for every frame)")
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in PICTURE_SUFFIXES)
        if not files:
            raise InputFileError(f"{path}: the folder holds no pictures ({', '.join(PICTURE_SUFFIXES)})")
        idx = [i for i in range(0, len(files), _step(folder_fps, fps))
               if i / folder_fps >= start_s - 1e-9 and (end_s is None or i / folder_fps <= end_s + 1e-9)][:max_frames]
        if not idx:
            raise InputFileError(f"{path}: no frames between {start_s:g} s and {end_s} s")
        return Frames([load_photo(files[i]) for i in idx], np.asarray(idx) / folder_fps, str(path))
    if not path.exists():
        raise InputFileError(f"{path}: no such video file or folder of frames")
    return _read_video(path, fps, max_frames, start_s, end_s)


def _read_video(path: Path, fps: float, max_frames: int | None, start_s: float = 0.0,
                end_s: float | None = None) -> Frames:
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        rate = cap.get(cv2.CAP_PROP_FPS) if cap.isOpened() else 0.0
        if not cap.isOpened() or not rate > 0:
            raise InputFileError(f"{path}: not a video this reader can decode (use {', '.join(VIDEO_SUFFIXES)}, "
                                 "or a folder of frames)")
        step = _step(rate, fps)
        images, times, i = [], [], 0
        while max_frames is None or len(images) < max_frames:
            if end_s is not None and i / rate > end_s + 1e-9:
                break
            if not cap.grab():
                break
            if i % step == 0 and i / rate >= start_s - 1e-9:
                ok, frame = cap.retrieve()
                if not ok or frame is None:
                    break  # a frame that cannot be decoded ends the clip: the kept ones stay evenly spaced
                images.append(np.ascontiguousarray(frame[..., ::-1]))
                times.append(i / rate)
            i += 1
    finally:
        cap.release()
    if not images:
        raise InputFileError(f"{path}: the video has no frames that can be decoded"
                             + (f" from {start_s:g} s" if start_s > 0 else ""))
    return Frames(images, np.asarray(times), str(path))


def _centre(p: PersonInPhoto) -> np.ndarray:
    x0, y0, x1, y1 = p.box
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2]) / p.scale


def follow_person(frames: Frames, finder=people_in_photo) -> list[PersonInPhoto | None]:
    """Per frame the followed person, or None where they are not found."""
    out: list[PersonInPhoto | None] = []
    last: PersonInPhoto | None = None
    for k, image in enumerate(frames.images):
        found = finder(image, f"{Path(frames.source).name} frame {k}")
        if not found:
            out.append(None)
            continue
        if last is None:
            pick = max(found, key=lambda p: p.height_px)
        else:
            pick = min(found, key=lambda p: float(np.linalg.norm(_centre(p) - _centre(last))))
            if np.linalg.norm(_centre(pick) - _centre(last)) > MAX_JUMP * last.height_px:
                out.append(None)
                continue
        out.append(pick)
        last = pick
    if last is None:
        raise TryonError(f"{frames.source}: no person found in any of its {len(frames.images)} frames")
    return out
