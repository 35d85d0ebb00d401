"""What `tryon size` writes: `size.json` (the recommendation, its reasons and every
size's numbers) and `sizes.png` (each size's strain map, front and back, labelled)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tryon.drape.pipeline import DrapeResult
from tryon.sizing.judge import ease_words


def sizes_picture(results: list[DrapeResult | str], judged: list[dict], recommended: str) -> np.ndarray:
    """Each size's strain map (front and back), labelled, side by side."""
    from PIL import Image, ImageDraw, ImageFont

    from tryon.drape.outputs import fit_map_image

    try:
        font = ImageFont.load_default(size=26)
    except TypeError:  # Pillow before 10.1: the fixed bitmap font
        font = ImageFont.load_default()
    tiles = []
    for r, j in zip(results, judged):
        if isinstance(r, str):  # a size the simulator could not drape
            continue
        img = fit_map_image(r.body_vertices, r.body_faces, r.x, r.garment.faces, 100.0 * r.strain, vmax=20.0, label="strain %")
        pil = Image.fromarray(img[..., :3])
        mark = " (recommended)" if j["size"] == recommended else ("" if j["fits"] else " (does not fit)")
        if "not_refined" in j:
            mark += " (predicted)"
        ImageDraw.Draw(pil).text((12, 12), f"size {j['size']}{mark}: {ease_words(j)}", fill=(0, 0, 0), font=font)
        tiles.append(np.asarray(pil))
    h = max(t.shape[0] for t in tiles)
    tiles = [np.pad(t, ((0, h - t.shape[0]), (0, 0), (0, 0)), constant_values=255) for t in tiles]
    return np.concatenate(tiles, axis=1)


def write_size_outputs(rec: dict, results: list[DrapeResult | str], out: str | Path, force: bool = False) -> Path:
    from tryon.io.atomic import atomic_output_dir
    from tryon.io.json_safe import dumps_json
    from tryon.render.offscreen import save_png

    with atomic_output_dir(out, force=force) as tmp:
        (tmp / "size.json").write_text(dumps_json(rec, indent=1))
        save_png(tmp / "sizes.png", sizes_picture(results, rec["sizes"], rec["recommended"]))
    return Path(out)
