"""What a worker process does with one fit: the body, then every size draped and judged,
each answer written to the store as it comes (`predicted`, then `refined`; `simulated`
for garments without a learned model), with a fit map PNG and a GLB per size under
`<data>/fits/<fit_id>/`."""

from __future__ import annotations

import math
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from tryon.serve.store import Store

# sizes simulated when a garment has no learned model and the request names none
SIMULATED_SIZES = ("S", "M", "L", "XL")


def fit_folder(data: Path, fit_id: str) -> Path:
    return data / "fits" / fit_id


@lru_cache(maxsize=64)
def _body(request_json: str):
    """The body of a request, fitted once per worker (the quick fit)."""
    import json

    from tryon.body.amortised import quick_fit
    from tryon.body.fit import Measurements

    return quick_fit(Measurements(**json.loads(request_json)))


def learned_garment(garment: str) -> bool:
    from tryon.learn.model import shipped_model_path

    return shipped_model_path(garment).is_file()


def run_fit(db: str, data: str, fit_id: str) -> str:
    """Run fit `fit_id` to its end; returns its last status. Any error becomes `failed`
    with the error's message (a worker that dies is caught by the dispatcher)."""
    import json

    from tryon.errors import TryonError
    from tryon.io.threads import one_torch_thread

    store = Store(db)
    row = store.fit(fit_id)
    body_request, _ = store.body(row.body_id)
    req = row.request
    try:
        with one_torch_thread():
            person = _body(json.dumps(body_request, sort_keys=True))
            store.update(fit_id, "running", 0.1)
            if learned_garment(req["garment"]):
                _answer(store, data, fit_id, body_request, req, person, refine=False, status="predicted", progress=0.3)
                return _answer(store, data, fit_id, body_request, req, person, refine=True, status="refined")
            return _answer(store, data, fit_id, body_request, req, person, refine=False, status="simulated")
    except TryonError as exc:
        store.update(fit_id, "failed", 1.0, reason=str(exc)[:500])
        return "failed"
    except Exception as exc:  # noqa: BLE001 - a job's bug must not take the worker down; its reason is kept
        store.update(fit_id, "failed", 1.0, reason=f"internal error: {type(exc).__name__}: {str(exc)[:300]}")
        return "failed"


def _answer(store: Store, data: str, fit_id: str, body_request: dict, req: dict, person, refine: bool, status: str,
            progress: float = 1.0) -> str:
    from tryon.body.fit import Measurements
    from tryon.learn.size import size_recommendation

    t0 = time.perf_counter()
    method = "learned" if status != "simulated" else "simulate"
    sizes = req.get("sizes") or (None if method == "learned" else list(SIMULATED_SIZES))
    rec, results = size_recommendation(Measurements(**body_request), garment=req["garment"], fabric=req["fabric"],
                                       method=method, refine=refine, sizes=sizes, person=person)
    folder = fit_folder(Path(data), fit_id)
    result = {"recommended": rec["recommended"], "reasons": rec["reasons"], "method": rec["method"],
              "sizes": [_size_entry(fit_id, j, r, folder, status) for j, r in zip(rec["sizes"], results)],
              "wall_s": round(time.perf_counter() - t0, 3)}
    store.update(fit_id, status, progress, result=result)
    return status


def _number(x) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else round(float(x), 3)


def _size_entry(fit_id: str, judged: dict, result, folder: Path, status: str) -> dict:
    """What the API says of one size, with its files written."""
    entry = {"size": judged["size"], "fits": bool(judged["fits"]), "why_not": judged["why_not"],
             "ease_cm": _number(judged["torso_ease_cm"]), "overstretched_area_pct": _number(judged["overstrained_area_pct"]),
             "max_strain_pct": _number(judged["max_strain_pct"]),
             "judged_on": judged.get("judged_on", "refined drape" if status == "refined" else status)}
    if isinstance(result, str):  # a size the simulator could not drape
        return entry
    regions = judged.get("regions", {})
    pressures = [r["mean_pressure_kpa"] for r in regions.values() if "mean_pressure_kpa" in r]
    entry["pressure_kpa"] = _number(max(pressures)) if pressures else None
    tag = f"{judged['size']}-{status}"
    _write_size_files(result, folder, tag)
    entry["fit_map_url"] = f"/v1/files/{fit_id}/{tag}-fit_map.png"
    entry["glb_url"] = f"/v1/files/{fit_id}/{tag}.glb"
    entry["scene_url"] = f"/v1/files/{fit_id}/{tag}-scene.json"
    return entry


def _write_size_files(result, folder: Path, tag: str) -> None:
    from tryon.drape.outputs import SKIN, fit_map_image
    from tryon.io.mesh_io import write_glb
    from tryon.render.appearance import appearance
    from tryon.render.offscreen import save_png

    folder.mkdir(parents=True, exist_ok=True)
    g, bv, bf = result.garment, result.body_vertices, result.body_faces
    strain = 100.0 * np.asarray(result.strain)
    save_png(folder / f"{tag}-fit_map.png", fit_map_image(bv, bf, result.x, g.faces, strain,
                                                          vmax=max(10.0, float(np.percentile(strain, 99))), label="strain %"))
    write_glb(folder / f"{tag}.glb", [(bv, bf, SKIN, "body"),
                                      (result.x, g.faces, appearance(str(result.request.fabric)).color, "garment")])
    _write_scene(result, folder, tag)


def _write_scene(result, folder: Path, tag: str) -> None:
    """What the page draws: `<tag>-scene.json` (layout, colours, scales) and
    `<tag>-scene.bin` (little-endian float32 / uint32 arrays), with per garment vertex its
    strain (%), contact pressure (kPa) and ease (cm: its distance to the skin)."""
    from tryon.drape.outputs import SKIN, face_to_vertex
    from tryon.io.atomic import atomic_write
    from tryon.io.json_safe import dumps_json
    from tryon.render.appearance import appearance
    from tryon.sim.collision import nearest_surface_points

    g, x = result.garment, np.asarray(result.x)
    strain = face_to_vertex(g.faces, 100.0 * np.asarray(result.strain), len(x))
    pressure = np.asarray(result.pressure) / 1000.0
    ease = 100.0 * np.maximum(nearest_surface_points(x, result.body_vertices, result.body_faces)[0], 0.0)
    arrays = [("garment_positions", x.astype("<f4")), ("garment_faces", g.faces.astype("<u4")),
              ("body_positions", np.asarray(result.body_vertices).astype("<f4")),
              ("body_faces", np.asarray(result.body_faces).astype("<u4")),
              ("strain", strain.astype("<f4")), ("pressure", pressure.astype("<f4")), ("ease", ease.astype("<f4"))]
    layout, offset = {}, 0
    for name, a in arrays:
        layout[name] = {"offset": offset, "count": int(a.size), "type": "uint32" if a.dtype.kind == "u" else "float32"}
        offset += a.nbytes
    meta = {"layout": layout, "bin": f"{tag}-scene.bin", "garment_vertices": len(x),
            "colors": {"skin": list(SKIN), "cloth": list(appearance(str(result.request.fabric)).color)},
            "scales": {"strain": float(max(10.0, np.percentile(strain, 99))),
                       "pressure": float(max(0.5, np.percentile(pressure, 99))), "ease": 5.0},
            "units": {"strain": "strain %", "pressure": "contact pressure kPa", "ease": "ease cm (gap to the skin)"}}
    with atomic_write(folder / f"{tag}-scene.bin", "wb") as fh:
        for _, a in arrays:
            fh.write(np.ascontiguousarray(a).tobytes())
    with atomic_write(folder / f"{tag}-scene.json") as fh:
        fh.write(dumps_json(meta))
