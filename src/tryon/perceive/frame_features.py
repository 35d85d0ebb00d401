"""What the fabric classifier reads of one frame of a clip, the same for the clip datasets'
renders and for real video: the person finder's mask in the square crop around the person
(CROP px, packed bits), the garment's mask found in the picture (`garment_mask`) in that
crop (GARMENT_CROP px, packed bits), and the 33 keypoints in the crop (0-1) with their
visibility."""

from __future__ import annotations

import numpy as np

from tryon.perceive.garment_mask import garment_mask
from tryon.perceive.person import CROP, PersonInPhoto, crop_box, crop_mask

GARMENT_CROP = 64  # px: the garment's mask is kept coarser than the person's


def frame_features(image: np.ndarray | None, person: PersonInPhoto | None, garment: str,
                   box: tuple[int, int, int, int] | None = None) -> tuple[dict[str, np.ndarray], tuple]:
    """The frame's features: `person` as found in `image` (its working picture), or None
    (nothing found: empty masks and keypoints in the crop around `box`, which must then be
    given; `image` is not needed). Keys: found, crop (x0, y0, side px), mask_bits, found_garment_bits, keypoints
    (float16 [33,2]), visibility (float16 [33]); and the crop (x0, y0, side) itself."""
    if person is None:
        if box is None:
            raise ValueError("a frame without a person needs the box to crop around")
        crop = crop_box(box)
        empty_person, empty_garment = np.zeros(CROP * CROP // 8, np.uint8), np.zeros(GARMENT_CROP ** 2 // 8, np.uint8)
        return {"found": np.bool_(False), "crop": np.array(crop, np.float32), "mask_bits": empty_person,
                "found_garment_bits": empty_garment, "keypoints": np.zeros((33, 2), np.float16),
                "visibility": np.zeros(33, np.float16)}, crop
    crop = crop_box(person.box)
    x0, y0, side = crop
    found_garment = garment_mask(person.image, person.mask, person.keypoints, garment).astype(np.float32)
    return {"found": np.bool_(True), "crop": np.array(crop, np.float32),
            "mask_bits": np.packbits(crop_mask(person.mask, crop, CROP) > 0.5),
            "found_garment_bits": np.packbits(crop_mask(found_garment, crop, GARMENT_CROP) > 0.5),
            "keypoints": ((person.keypoints - [x0, y0]) / side).astype(np.float16),
            "visibility": np.asarray(person.visibility, np.float16)}, crop
