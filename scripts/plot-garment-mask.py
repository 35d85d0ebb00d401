"""docs/images/garment-mask-real.jpg: the garment found in frames of a real video
(`tryon.perceive.garment_mask`): garment red, the rest of the person blue, keypoints green.

The video used in the docs is Sports2D's demo (BSD-3-Clause), from its wheel:
    pip download --no-deps sports2d==0.8.34 -d /tmp/s2d && unzip -o /tmp/s2d/*.whl Sports2D/Demo/demo.mp4 -d /tmp/s2d
    .venv/bin/python scripts/plot-garment-mask.py /tmp/s2d/Sports2D/Demo/demo.mp4 tshirt 90 110 130 150 170
"""

import sys

import numpy as np
from PIL import Image

from tryon.perceive.garment_mask import garment_mask
from tryon.perceive.person import detect_person, working_image


def frames_of(path: str, wanted: set[int]) -> dict[int, np.ndarray]:
    import cv2

    cap, out, i = cv2.VideoCapture(path), {}, 0
    while len(out) < len(wanted):
        ok, frame = cap.read()
        if not ok:
            break
        if i in wanted:
            out[i] = frame[..., ::-1].copy()
        i += 1
    return out


def tile(image: np.ndarray, garment: str, height: int = 300) -> np.ndarray | None:
    import cv2

    work, _ = working_image(image)
    p = detect_person(work, "frame")
    if p is None:
        return None
    m = garment_mask(p.image, p.mask, p.keypoints, garment)
    rest = (p.mask > 0.5) & ~m
    ov = p.image.astype(np.float64)
    ov[m] = 0.4 * ov[m] + (150, 0, 0)
    ov[rest] = 0.6 * ov[rest] + (0, 0, 100)
    ov = ov.astype(np.uint8)
    for q in p.keypoints:
        cv2.circle(ov, (int(q[0]), int(q[1])), 2, (0, 255, 0), -1)
    x0, y0, x1, y1 = p.box
    pad = (y1 - y0) // 12
    crop = ov[max(0, y0 - pad):y1 + pad, max(0, x0 - pad):x1 + pad]
    return np.asarray(Image.fromarray(crop).resize((int(crop.shape[1] * height / crop.shape[0]), height)))


def main() -> None:
    path, garment, idx = sys.argv[1], sys.argv[2], [int(i) for i in sys.argv[3:]]
    frames = frames_of(path, set(idx))
    tiles = [t for t in (tile(frames[i], garment) for i in idx if i in frames) if t is not None]
    if not tiles:
        raise SystemExit("no person found in the frames asked for")
    Image.fromarray(np.hstack(tiles)).save("docs/images/garment-mask-real.jpg", quality=88)


if __name__ == "__main__":
    main()
