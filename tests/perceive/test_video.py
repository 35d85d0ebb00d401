"""Clips as pictures: a video file or a folder of frames read at the rate asked for, bad
sources named, and one person followed through the frames."""

import numpy as np
import pytest

from tryon.errors import InputFileError, TryonError
from tryon.perceive.person import PersonInPhoto
from tryon.perceive.video import Frames, follow_person, read_frames


def _write_video(path, n=30, fps=30.0):
    cv2 = pytest.importorskip("cv2")
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (64, 48))
    for k in range(n):
        writer.write(np.full((48, 64, 3), 8 * k, np.uint8))
    writer.release()


def test_a_video_is_read_at_the_rate_asked_for(tmp_path):
    _write_video(tmp_path / "clip.avi")
    frames = read_frames(tmp_path / "clip.avi", fps=5.0)
    assert len(frames.images) == 5 and frames.images[0].shape == (48, 64, 3)
    assert np.allclose(frames.times, [0.0, 0.2, 0.4, 0.6, 0.8]) and frames.fps == pytest.approx(5.0)
    # the frames are the ones at those times (brightness 8 per source frame)
    assert [int(round(im.mean() / 8)) for im in frames.images] == [0, 6, 12, 18, 24]
    assert len(read_frames(tmp_path / "clip.avi", fps=5.0, max_frames=3).images) == 3
    # a window of the source: only its frames are decoded, their times stay the source's
    part = read_frames(tmp_path / "clip.avi", fps=5.0, start_s=0.35, end_s=0.85)
    assert np.allclose(part.times, [0.4, 0.6, 0.8]) and [int(round(im.mean() / 8)) for im in part.images] == [12, 18, 24]


def test_a_folder_of_frames_is_read_in_name_order(tmp_path):
    from PIL import Image

    for k in range(6):
        Image.fromarray(np.full((80, 64, 3), 40 * k, np.uint8)).save(tmp_path / f"f{k:02d}.png")
    frames = read_frames(tmp_path, fps=5.0, folder_fps=10.0)
    assert [int(im.mean()) for im in frames.images] == [0, 80, 160]
    assert np.allclose(frames.times, [0.0, 0.2, 0.4])
    # asked for more frames than the folder has: every frame, at the folder's own rate
    every = read_frames(tmp_path, fps=15.0, folder_fps=5.0)
    assert len(every.images) == 6 and every.fps == pytest.approx(5.0)
    # a 25 fps source asked for 15 fps keeps every other frame: 12.5 fps, evenly spaced
    assert read_frames(tmp_path, fps=15.0, folder_fps=25.0).fps == pytest.approx(12.5)


def test_bad_sources_are_named(tmp_path):
    (tmp_path / "notes.mp4").write_text("not a video")
    with pytest.raises(InputFileError, match="not a video"):
        read_frames(tmp_path / "notes.mp4")
    with pytest.raises(InputFileError, match="no such video"):
        read_frames(tmp_path / "missing.mp4")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputFileError, match="no pictures"):
        read_frames(tmp_path / "empty")
    with pytest.raises(TryonError, match="positive"):
        read_frames(tmp_path / "empty", folder_fps=0.0)
    with pytest.raises(TryonError, match="at least 1"):
        read_frames(tmp_path / "notes.mp4", max_frames=0)


def _person(x0, y0, x1, y1):
    mask = np.zeros((200, 300))
    mask[y0:y1, x0:x1] = 1.0
    return PersonInPhoto("p", np.zeros((200, 300, 3), np.uint8), 1.0, mask, np.zeros((33, 2)), np.ones(33),
                         np.zeros((33, 3)))


def test_the_tallest_person_is_followed_through_a_crowd():
    walker = [_person(20 + 10 * k, 40, 50 + 10 * k, 180) for k in range(5)]   # tall, walking right
    other = _person(250, 100, 270, 160)                                       # short, standing
    seen = [[other, walker[0]], [walker[1], other], [other], [walker[3]], []]
    frames = Frames([np.zeros((200, 300, 3), np.uint8)] * 5, np.arange(5) * 0.2, "clip.mp4")
    calls = iter(seen)
    followed = follow_person(frames, finder=lambda image, name: next(calls))
    # frame 2 sees only the other person, far from where the walker was: not found
    assert followed == [walker[0], walker[1], None, walker[3], None]
    with pytest.raises(TryonError, match="no person found in any of its 5 frames"):
        follow_person(frames, finder=lambda image, name: [])
