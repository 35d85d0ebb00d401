"""What the page draws of one size: `<tag>-scene.json` (layout, colours, colour scales)
and `<tag>-scene.bin` (little-endian float32 / uint32 arrays), with per garment vertex its
strain (%), contact pressure (kPa; absent for a prediction, which has none until refined)
and ease (cm: its distance to the skin)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class SceneArrays:
    x: np.ndarray  # garment vertices [N,3] (m)
    faces: np.ndarray  # garment faces [F,3]
    body_vertices: np.ndarray
    body_faces: np.ndarray
    strain: np.ndarray  # per face, principal stretch - 1
    pressure: np.ndarray | None  # per vertex (Pa)
    skin_distance: np.ndarray  # per vertex (m)


def write_scene(folder: Path, tag: str, s: SceneArrays, fabric: str) -> None:
    from tryon.drape.outputs import SKIN, face_to_vertex
    from tryon.io.atomic import atomic_write
    from tryon.io.json_safe import dumps_json
    from tryon.io.packed import packed_layout, write_packed
    from tryon.render.appearance import appearance

    folder.mkdir(parents=True, exist_ok=True)
    x = np.asarray(s.x)
    strain = face_to_vertex(s.faces, 100.0 * np.asarray(s.strain), len(x))
    ease = 100.0 * np.maximum(np.asarray(s.skin_distance), 0.0)
    arrays = [("garment_positions", x.astype("<f4")), ("garment_faces", np.asarray(s.faces).astype("<u4")),
              ("body_positions", np.asarray(s.body_vertices).astype("<f4")),
              ("body_faces", np.asarray(s.body_faces).astype("<u4")),
              ("strain", strain.astype("<f4")), ("ease", ease.astype("<f4"))]
    scales = {"strain": float(max(10.0, np.percentile(strain, 99))), "ease": 5.0}
    if s.pressure is not None:
        pressure = np.asarray(s.pressure) / 1000.0
        arrays.append(("pressure", pressure.astype("<f4")))
        scales["pressure"] = float(max(0.5, np.percentile(pressure, 99)))
    layout = packed_layout(arrays)
    meta = {"layout": layout, "bin": f"{tag}-scene.bin", "garment_vertices": len(x),
            "colors": {"skin": list(SKIN), "cloth": list(appearance(fabric).color)}, "scales": scales,
            "units": {"strain": "strain %", "pressure": "contact pressure kPa", "ease": "ease cm (gap to the skin)"}}
    write_packed(folder / f"{tag}-scene.bin", arrays)
    with atomic_write(folder / f"{tag}-scene.json") as fh:
        fh.write(dumps_json(meta))
