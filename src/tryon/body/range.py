"""The BMI range Anny reaches without a distorted mesh (`tryon body-range`).

For each gender at a fixed stature the fit is asked for BMI 12 to 50; each row reports
the BMI achieved, the mesh distortion (`fit.mesh_distortion`) and the largest local
change the fit needed, for the default fit (the ANSUR II prior's body) and for Anny's
average shape (`prior=False`). `fit.BMI_RANGE` is the range where every row reaches its
target and looks like a plausible person (docs/BODY.md shows the renders this was judged on).
"""

from __future__ import annotations


from contextlib import contextmanager

from tryon.body import fit as fitmod

PROBE_BMIS = (12, 14, 15, 17, 20, 25, 30, 35, 40, 45, 48, 50)


@contextmanager
def _probing_beyond_the_range():
    """Lift `fit.BMI_RANGE` while probing; yields the supported range to report against."""
    saved = fitmod.BMI_RANGE
    fitmod.BMI_RANGE = {g: (5.0, 80.0) for g in saved}
    try:
        yield saved
    finally:
        fitmod.BMI_RANGE = saved


def bmi_range_table(height_cm: float = 172.0, bmis=PROBE_BMIS) -> list[dict]:
    rows = []
    with _probing_beyond_the_range() as saved:
        for gender in ("female", "male"):
            for b in bmis:
                for prior in (True, False):
                    f = fitmod.fit_body(fitmod.Measurements(height_cm=height_cm, bmi=float(b), gender=gender), prior=prior)
                    local = max((abs(v) for v in f.params.local.values()), default=0.0)
                    rows.append({"gender": gender, "height_cm": height_cm, "body": "prior" if prior else "anny-average",
                                 "bmi_asked": float(b), "bmi_achieved": f.achieved["bmi"],
                                 "mesh_distortion": f.distortion, "largest_local_change": float(local),
                                 "weight_phenotype": f.params.weight, "muscle_phenotype": f.params.muscle,
                                 "supported": bool(saved[gender][0] <= b <= saved[gender][1])})
    return rows


SHEET_BMIS = (14, 15, 17, 25, 35, 40, 45, 48)


def render_range_sheet(path, height_cm: float = 172.0, bmis=SHEET_BMIS, size=(220, 520)):
    """Front views of the fitted bodies (rows: female and male, each as the default fit
    with the ANSUR II prior makes them and as Anny's average shape; columns: BMI asked),
    each labelled with the BMI and whether it is inside `fit.BMI_RANGE`: the picture the
    supported range is judged on (docs/BODY.md)."""
    import numpy as np
    from PIL import Image, ImageDraw

    from tryon.render.colormap import label_font
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes, save_png

    rows = []
    with _probing_beyond_the_range() as saved:
        for gender, prior in (("female", True), ("female", False), ("male", True), ("male", False)):
            tiles = []
            for b in bmis:
                f = fitmod.fit_body(fitmod.Measurements(height_cm=height_cm, bmi=float(b), gender=gender), prior=prior)
                v = f.shape.vertices.detach().numpy()
                cam = Camera.fit([v], "front", aspect=size[0] / size[1], margin=1.02)
                img = Image.fromarray(render_meshes([RenderMesh(v, f.shape.faces, color=(0.8, 0.68, 0.6))], *size, camera=cam))
                draw = ImageDraw.Draw(img)
                ok = saved[gender][0] <= b <= saved[gender][1]
                draw.text((8, 6), f"{gender} BMI {b}", fill=(0, 0, 0), font=label_font(16))
                draw.text((8, 46), "ANSUR II prior" if prior else "Anny average", fill=(60, 60, 60), font=label_font(14))
                draw.text((8, 26), "supported" if ok else "refused", fill=(20, 120, 40) if ok else (180, 30, 30), font=label_font(16))
                tiles.append(np.asarray(img.convert("RGB")))
            rows.append(np.concatenate(tiles, axis=1))
    return save_png(path, np.concatenate(rows, axis=0))
