"""The BMI range Anny reaches without a distorted mesh (`tryon body-range`).

For each gender at a fixed stature the fit is asked for BMI 12 to 50; each row reports
the BMI achieved, the mesh distortion (`fit.mesh_distortion`) and the largest local
change the fit needed. `fit.BMI_RANGE` is the range where every row reaches its target
and looks like a plausible person (docs/BODY.md shows the renders this was judged on).
"""

from __future__ import annotations


from tryon.body import fit as fitmod

PROBE_BMIS = (12, 14, 15, 17, 20, 25, 30, 35, 40, 45, 48, 50)


def bmi_range_table(height_cm: float = 172.0, bmis=PROBE_BMIS) -> list[dict]:
    rows = []
    saved = fitmod.BMI_RANGE
    fitmod.BMI_RANGE = (5.0, 80.0)  # probe beyond the supported range
    try:
        for gender in ("female", "male"):
            for b in bmis:
                f = fitmod.fit_body(fitmod.Measurements(height_cm=height_cm, bmi=float(b), gender=gender))
                local = max((abs(v) for v in f.params.local.values()), default=0.0)
                rows.append({"gender": gender, "height_cm": height_cm, "bmi_asked": float(b), "bmi_achieved": f.achieved["bmi"],
                             "mesh_distortion": f.distortion, "largest_local_change": float(local),
                             "weight_phenotype": f.params.weight, "muscle_phenotype": f.params.muscle,
                             "supported": bool(saved[0] <= b <= saved[1])})
    finally:
        fitmod.BMI_RANGE = saved
    return rows
