"""Drape datasets whose fabric is drawn per drape and whose bodies are draped in the sizes
around their own (generator version 3)."""

import numpy as np
import pytest

from tryon.dataset import BodyRanges, DrapeDatasetSpec, load_drape_dataset, make_drape_dataset
from tryon.dataset.drapes import (BLENDED, GENERATOR_VERSION, GENERATOR_VERSION_FIXED_FABRIC, fabric_group, fabric_named,
                                  own_size_index, recorded_fabric_names, unit_body, unit_fabric, unit_of, window_sizes)
from tryon.dataset.store import DatasetError
from tryon.errors import FabricError, TryonError
from tryon.fabric import load_fabric
from tryon.fabric.blend import blend_fabrics, fabric_features
from tryon.garment.sizes import SIZES, size_measurements

FABRICS = ("gray-interlock", "11oz-black-denim", "navy-sparkle-sweat")


def _spec(**kw):
    base = dict(garment="tshirt", sizes=("S", "M", "L"), count=1, edge_length=0.03, shard_size=2,
                ranges=BodyRanges(genders=("female",), bmi=(18.0, 30.0)), fabrics=FABRICS, fabric_mix=0.5,
                size_window=2)
    return DrapeDatasetSpec(**{**base, **kw})


def test_a_blend_runs_between_its_two_fabrics():
    a, b = load_fabric("gray-interlock"), load_fabric("11oz-black-denim")
    assert np.allclose(blend_fabrics(a, b, 0.0).parameters(), a.parameters())
    assert np.allclose(blend_fabrics(a, b, 1.0).parameters(), b.parameters())
    fa, fm, fb = (fabric_features(f) for f in (a, blend_fabrics(a, b, 0.5), b))
    assert np.all((np.minimum(fa, fb) <= fm) & (fm <= np.maximum(fa, fb)))
    assert fb[0] > fa[0] and fb[3] > fa[3]  # denim: stiffer and heavier than the T-shirt jersey
    with pytest.raises(FabricError, match="outside 0-1"):
        blend_fabrics(a, b, 1.5)


def test_only_specs_that_draw_make_version_3_samples():
    plain = DrapeDatasetSpec(sizes=("S", "M"), count=3).manifest("v")
    assert plain.generator_version == GENERATOR_VERSION_FIXED_FABRIC and plain.count == 6
    assert not {"fabrics", "fabric_mix", "size_window"} & set(plain.spec)
    drawn = _spec(count=3).manifest("v")
    assert drawn.generator_version == GENERATOR_VERSION and drawn.count == 6
    assert drawn.spec["fabrics"] == list(FABRICS) and drawn.spec["size_window"] == 2
    with pytest.raises(DatasetError, match="unit_body"):
        unit_of(drawn, 0)


@pytest.mark.parametrize("kw, message", [
    (dict(fabrics=("gray-interlock", "gray-interlock")), "distinct"),
    (dict(fabrics=("gray-interlock",), fabric_mix=0.3), "at least two"),
    (dict(fabric_mix=1.5), "probability"),
    (dict(size_window=4), "1 to 3"),
    (dict(sizes=("S", "L"), size_window=1), "consecutive"),
    (dict(fabrics=("gray-interlock", "my+fabric.json")), "may not hold"),
])
def test_a_drawn_spec_is_checked_before_any_work(kw, message):
    with pytest.raises(TryonError, match=message):
        _spec(**kw).validate()


def test_each_unit_draws_its_own_fabric_the_same_on_every_run():
    manifest = _spec(count=200).manifest("v")
    draws = [unit_fabric(manifest, u)[1] for u in range(200)]
    again = unit_fabric(manifest, 17)[1]
    assert all(np.array_equal(again[k], draws[17][k]) for k in again)
    blended = np.array([int(d["fabric_a"]) != int(d["fabric_b"]) for d in draws])
    assert 0.4 < blended.mean() < 0.6  # fabric_mix 0.5
    assert {int(d["fabric_a"]) for d in draws} == {0, 1, 2}
    t = np.array([float(d["fabric_t"]) for d in draws])
    assert np.all(t[~blended] == 0.0) and np.all((t[blended] >= 0.0) & (t[blended] <= 1.0))
    fabric, record = unit_fabric(manifest, int(np.argmax(blended)))
    assert np.allclose(record["fabric_features"], fabric_features(fabric))


def test_the_recorded_fabric_names_give_back_each_drawn_fabric():
    manifest = _spec(count=40).manifest("v")
    made = [unit_fabric(manifest, u) for u in range(40)]
    arrays = {k: np.stack([np.float32(r[k]) if k == "fabric_t" else r[k] for _, r in made])
              for k in ("fabric_a", "fabric_b", "fabric_t")}  # as a shard stores them
    arrays["unit"] = np.arange(40)
    names = recorded_fabric_names(manifest.spec, arrays)
    assert [fabric.name for fabric, _ in made] == names.tolist()
    for (fabric, _), name in zip(made, names):
        assert np.array_equal(fabric_named(name).parameters(), fabric.parameters())
    groups = {fabric_group(n) for n in names}
    assert BLENDED in groups and groups - {BLENDED} <= set(FABRICS)
    one = DrapeDatasetSpec(sizes=("S",), count=2, fabric="11oz-black-denim").manifest("v")
    assert recorded_fabric_names(one.spec, {"unit": np.arange(2)}).tolist() == ["11oz-black-denim"] * 2


def _girths(size: str, gender: str) -> dict:
    m = size_measurements(size, gender)
    return {"chest_girth": m["chest_cm"] / 100, "hip_girth": m["hip_cm"] / 100}


def test_a_body_is_draped_in_the_sizes_around_its_own():
    assert own_size_index("tshirt", "male", _girths("L", "male")) == SIZES.index("L")
    women_l = _girths("L", "female")
    assert own_size_index("trousers", "female", {**women_l, "hip_girth": women_l["hip_girth"] + 0.09}) > SIZES.index("L")
    # the dress takes the larger of the chest's and the hip's size
    assert own_size_index("dress", "female", {**_girths("S", "female"), "hip_girth": women_l["hip_girth"]}) == SIZES.index("L")
    assert window_sizes("tshirt", "male", _girths("M", "male"), list(SIZES), 4) == ["S", "M", "L", "XL"]
    assert window_sizes("tshirt", "male", _girths("XS", "male"), list(SIZES), 4) == ["XS", "S", "M", "L"]
    assert window_sizes("tshirt", "male", _girths("XXL", "male"), list(SIZES), 4) == ["M", "L", "XL", "XXL"]


@pytest.mark.anny
@pytest.mark.slow
def test_a_drawn_dataset_records_the_fabric_and_size_of_each_drape(tmp_path):
    spec = _spec(count=1)
    store, report = make_drape_dataset(spec, tmp_path / "d", progress=False)
    assert report.made == 2
    data = load_drape_dataset(tmp_path / "d")
    a = data.arrays
    body = unit_body(data.manifest, 0)
    expect = window_sizes("tshirt", "female", _measured(body), ["S", "M", "L"], 2)
    assert [data.manifest.spec["sizes"][int(s)] for s in a["size"]] == expect
    for u in (0, 1):
        fabric, record = unit_fabric(data.manifest, u)
        assert np.allclose(a["fabric_features"][u], record["fabric_features"])
        assert int(a["fabric_a"][u]) == int(record["fabric_a"])
    assert a["ok"].all() and np.isfinite(a["x"]).all()


def _measured(body) -> dict:
    from tryon.body.measure import drafting_measurements

    return drafting_measurements(body.sample.shape())
