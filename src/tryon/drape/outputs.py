"""Files a drape writes: meshes, a GLB scene, renders, fit maps, the pattern and report.json."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tryon.io.atomic import atomic_output_dir, atomic_write
from tryon.io.frames import save_frames_npz
from tryon.io.mesh_io import write_glb, write_obj
from tryon.render.appearance import appearance, fabric_colors
from tryon.render.colormap import add_colorbar, scalar_to_rgb
from tryon.render.offscreen import Camera, RenderMesh, render_meshes, save_png
from tryon.io.json_safe import dumps_json

SKIN = (0.80, 0.68, 0.60)
CLOTH = (0.27, 0.45, 0.72)
VIEWS = ("front", "back", "side")
PRINT_TEXEL = 0.003  # m: triangle size a print is drawn on


def face_to_vertex(faces: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Area-agnostic average of per-face values onto vertices."""
    acc = np.zeros(n)
    cnt = np.zeros(n)
    for k in range(3):
        np.add.at(acc, faces[:, k], values)
        np.add.at(cnt, faces[:, k], 1)
    return acc / np.maximum(cnt, 1)


def garment_look(g, x: np.ndarray, fabric: str, pr=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertices, faces, colours and normals (None: the faces' own) that draw garment `g`
    draped at `x`: the fabric's look, and the placed print `pr` if any, on triangles fine
    enough for its image (about `PRINT_TEXEL`), shaded with the garment's own smooth normals."""
    if pr is None:
        return x, g.faces, fabric_colors(fabric, g.uv), None
    from tryon.garment.prints import panel_xy
    from tryon.render.appearance import subdivide_faces
    from tryon.sim.geometry import vertex_normals

    touched = pr.touched_faces(g)
    edge = float(np.linalg.norm(g.corner_uv[touched, 1] - g.corner_uv[touched, 0], axis=1).mean())
    face_of, bary, faces, _ = subdivide_faces(g.faces, touched, len(g.uv), max(1, int(np.ceil(edge / PRINT_TEXEL))))
    corners = g.faces[face_of]
    normals = vertex_normals(x, g.faces)
    x = np.concatenate([x, np.einsum("pk,pkd->pd", bary, x[corners])])
    n = np.concatenate([normals, np.einsum("pk,pkd->pd", bary, normals[corners])])
    uv = np.concatenate([g.uv, np.einsum("pk,pkd->pd", bary, g.corner_uv[face_of])])
    front = np.zeros(len(uv), bool)
    front[len(g.uv):] = True
    front[np.unique(g.faces[touched])] = True   # other panels' material coordinates are not the front's
    ink = pr.rgba_at(panel_xy(uv))
    a = np.where(front, ink[:, 3], 0.0)[:, None]
    return x, faces, (1 - a) * fabric_colors(fabric, uv) + a * ink[:, :3], n


def render_views(body_v, body_f, cloth_v, cloth_f, cloth_colors=None, size=(600, 800), views=VIEWS,
                 cloth_normals=None) -> list[np.ndarray]:
    """Body and garment from each named view, framed on the body."""
    body = RenderMesh(body_v, body_f, color=SKIN, two_sided=False)
    cloth = RenderMesh(cloth_v, cloth_f, color=CLOTH, vertex_colors=cloth_colors, vertex_normals=cloth_normals)
    out = []
    for view in views:
        cam = Camera.fit([body_v, cloth_v], view, aspect=size[0] / size[1], margin=1.05)
        out.append(render_meshes([body, cloth], size[0], size[1], camera=cam))
    return out


def fit_map_image(body_v, body_f, cloth_v, cloth_f, face_values, vmax: float, label: str, cmap: str = "turbo") -> np.ndarray:
    """Front and back views of the garment coloured by a per-face quantity, with a legend."""
    colors = scalar_to_rgb(face_to_vertex(cloth_f, face_values, len(cloth_v)), 0.0, vmax, cmap=cmap)
    imgs = render_views(body_v, body_f, cloth_v, cloth_f, colors, size=(500, 700), views=("front", "back"))
    return add_colorbar(np.concatenate(imgs, axis=1), 0.0, vmax, cmap=cmap, label=label, fmt="{:.0f}" if vmax >= 10 else "{:.1f}")


def pressure_face_values(faces: np.ndarray, pressure_vertex: np.ndarray) -> np.ndarray:
    return pressure_vertex[faces].mean(1)


def report_dict(result) -> dict:
    req = result.request
    g = result.garment
    return {
        "garment": req.garment,
        "size": None if req.garment_obj is not None else (req.size or "made-to-measure"),
        "fabric": req.fabric,
        "body": result.person.report(),
        "fit_model": result.fit_model.report() if result.fit_model is not None else None,
        "pattern": ({"panels": [p.name for p in g.pattern.panels], "seams": len(g.pattern.seams),
                     "area_m2": g.pattern.area(), "edge_length_m": req.edge_length}
                    if g.pattern is not None else {"obj": g.stats.get("source")}),
        "mesh": {"garment_vertices": int(len(g.vertices)), "garment_faces": int(len(g.faces)), "body_vertices": int(len(result.body_vertices))},
        "dressing": g.stats,
        "print": req.graphic_print(g).describe(g) if req.print_image is not None and g.pattern is not None else None,
        **{k: v for k, v in result.metrics.items()},
        "penetration_pct": result.metrics["penetration_pct"],
        "max_strain": result.metrics["max_strain"],
        "wall_s": result.timings["wall_s"],
        "timings": result.timings,
        "settings": {"dt": req.dt, "morph_time": result.metrics.get("morph_s", req.morph_time), "max_settle_time": req.max_settle_time,
                     "rest_speed": req.rest_speed, "thickness": req.thickness, "friction": req.friction},
    }


def write_outputs(result, out: str | Path, force: bool = False) -> dict:
    """Write everything into `out` (built under a temporary name, renamed when complete;
    an existing `out` is replaced only when tryon wrote it, or with `force`)."""
    from tryon.drape.pipeline import STATE_FILE, save_state
    from tryon.garment.pattern import plot_pattern

    out = Path(out)
    g = result.garment
    bv, bf = result.body_vertices, result.body_faces
    report = report_dict(result)
    look_v, look_f, look_c, look_n = garment_look(g, result.x, str(result.request.fabric),
                                                  result.request.graphic_print(g) if g.pattern is not None else None)
    with atomic_output_dir(out, force=force) as tmp:
        write_obj(tmp / "garment.obj", result.x, g.faces, corner_uv=g.corner_uv)  # vt: material coordinates (m)
        write_obj(tmp / "body.obj", bv, bf)
        write_glb(tmp / "tryon.glb", [(bv, bf, SKIN, "body"), (result.x, g.faces, appearance(str(result.request.fabric)).color,
                                                                 "garment")])
        for view, img in zip(VIEWS, render_views(bv, bf, look_v, look_f, look_c, cloth_normals=look_n)):
            save_png(tmp / f"render_{view}.png", img)
        save_png(tmp / "fit_map.png", fit_map_image(bv, bf, result.x, g.faces, 100.0 * result.strain,
                                                    vmax=max(10.0, float(np.percentile(100 * result.strain, 99))), label="strain %"))
        kpa = pressure_face_values(g.faces, result.pressure) / 1000.0
        save_png(tmp / "pressure_map.png", fit_map_image(bv, bf, result.x, g.faces, kpa,
                                                         vmax=max(0.5, float(np.percentile(kpa, 99))), label="contact kPa"))
        if g.pattern is not None:
            g.pattern.save(tmp / "pattern.json")
            g.pattern.to_svg(tmp / "pattern.svg")
            plot_pattern(g.pattern, tmp / "pattern.png")
        save_frames_npz(tmp / "frames.npz", np.stack(result.frames), g.faces, uv=g.uv, times=np.asarray(result.frame_times),
                        body_vertices=bv, body_faces=bf, face_strain=result.strain, vertex_pressure=result.pressure)
        save_state(result, tmp / STATE_FILE)
        if result.request.print_image is not None:  # the drape folder stands alone (tryon animate reads it)
            import shutil

            shutil.copyfile(result.request.print_image, tmp / "print.png")
        with atomic_write(tmp / "report.json") as fh:
            fh.write(dumps_json(report, indent=2))
    return report
