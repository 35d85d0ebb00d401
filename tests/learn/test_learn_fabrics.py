"""A draping model of many fabrics: trained on drapes whose fabric is drawn per drape, it
reads the fabric's features, refuses to predict without a fabric, says when a fabric lies
beyond those it learned from, and is judged per fabric."""

import numpy as np
import pytest

from tryon.dataset import BodyRanges, DrapeDatasetSpec, load_drape_dataset, make_drape_dataset
from tryon.fabric import load_fabric
from tryon.fabric.blend import FEATURE_NAMES
from tryon.learn.data import training_set
from tryon.learn.model import DrapeModel, ModelError
from tryon.learn.train import TrainConfig, predict_set, train_drape

pytestmark = [pytest.mark.anny, pytest.mark.slow]

FABRICS = ("gray-interlock", "11oz-black-denim")


@pytest.fixture(scope="module")
def skirts(tmp_path_factory):
    out = tmp_path_factory.mktemp("fabrics") / "skirt"
    spec = DrapeDatasetSpec(garment="skirt", sizes=("M", "L"), count=3, edge_length=0.04, shard_size=6, seed=3,
                            extrapolation_bmi=30.0, fabrics=FABRICS,
                            ranges=BodyRanges(genders=("female",), bmi=(19.0, 25.0)))
    make_drape_dataset(spec, out, progress=False)
    return out


@pytest.fixture(scope="module")
def trained(skirts, tmp_path_factory):
    out = tmp_path_factory.mktemp("fabric-model")
    return train_drape(skirts, out, TrainConfig(epochs=4, batch=2), progress=False), out


def test_the_drapes_record_each_fabric_and_the_model_reads_it(skirts, trained):
    model, out = trained
    data = load_drape_dataset(skirts)
    rows = data.rows()
    drawn = {FABRICS[int(a)] for a in data.arrays["fabric_a"][rows]}
    assert drawn == set(FABRICS) and len(rows) >= 4  # both fabrics drawn (seed 3)
    assert model.config.fabric == len(FEATURE_NAMES) and model.fabrics["names"] == list(FABRICS)
    ts = training_set(data, model.priors, model.region)
    assert np.allclose(ts.fabric, data.arrays["fabric_features"][rows])
    low, high = model.fabrics["low"], model.fabrics["high"]
    assert (low <= ts.fabric.min(0) + 1e-6).all() and (high >= ts.fabric.max(0) - 1e-6).all()

    from tryon.dataset.drapes import shape_params

    r = rows[0]
    size = data.manifest.spec["sizes"][int(data.arrays["size"][r])]
    soft, stiff = (model.predict(shape_params(data.arrays["shape_params"][r]), "female", size, load_fabric(f))[0]
                   for f in FABRICS)
    assert np.abs(soft - stiff).max() > 1e-5  # the fabric changes the prediction
    with pytest.raises(ModelError, match="name the fabric"):
        model.predict(shape_params(data.arrays["shape_params"][r]), "female", size)
    # the card gives the error per fabric on every split
    for split, m in model.card["metrics"].items():
        per = m["by_fabric"]
        assert sum(v["samples"] for v in per.values()) == m["samples"]
        assert sum(v["mean_error_cm"] * v["samples"] for v in per.values()) / m["samples"] == pytest.approx(m["mean_error_cm"])
    assert "per fabric" in (out / "MODEL_CARD.md").read_text()
    # the file keeps how it reads fabrics
    loaded = DrapeModel.load(out / "model.npz")
    assert loaded.config.fabric == model.config.fabric and loaded.fabrics["names"] == list(FABRICS)
    assert np.allclose(predict_set(loaded, ts), predict_set(model, ts), atol=1e-5)


def test_a_fabric_beyond_the_learned_ones_is_named_in_the_notes(trained):
    model, _ = trained
    assert model.coverage_notes("female", 165, 22, load_fabric("gray-interlock")) == []
    notes = model.coverage_notes("female", 165, 22, load_fabric("royal-target"))  # far stiffer than the denim
    assert len(notes) == 1 and "royal-target" in notes[0] and "log10_stretch_N_m" in notes[0]


def test_the_judge_reports_every_fabric_on_its_own(skirts, trained):
    from tryon.learn.evaluate import Judge

    model, _ = trained
    data = load_drape_dataset(skirts)
    ts = training_set(data, model.priors, model.region)
    judge = Judge(data, ts, model)
    assert [f.name for f in judge.fabrics] == judge.fabric_labels  # no blends here: each a measured fabric
    pred = predict_set(model, ts)
    whole = judge.record("learned", "all", pred, 1.0)
    each = judge.records_by_fabric("learned", "all", pred, 1.0, refine_s=np.arange(len(pred), dtype=float))
    assert [r["fabric"] for r in each] == sorted(set(judge.fabric_labels)) and whole["fabric"] == "all"
    assert sum(r["samples"] for r in each) == whole["samples"] == len(pred)
    assert all(r["garment"] == "skirt" for r in each + [whole])
    mean = sum(r["mean_error_cm"] * r["samples"] for r in each) / whole["samples"]
    assert mean == pytest.approx(whole["mean_error_cm"], rel=1e-6)


def test_a_model_of_one_drawn_fabric_names_that_fabric():
    from tryon.fabric.blend import fabric_features
    from tryon.learn.train import fabric_normalisation

    denim = fabric_features(load_fabric("11oz-black-denim"))
    spec = {"fabric": "gray-interlock", "fabrics": ["11oz-black-denim"]}
    assert fabric_normalisation(np.repeat(denim[None], 3, 0), ["11oz-black-denim"] * 3, spec) == {"names": ["11oz-black-denim"]}
    both = np.stack([denim, fabric_features(load_fabric("gray-interlock"))])
    many = fabric_normalisation(both, ["11oz-black-denim", "gray-interlock"], dict(spec, fabrics=list(FABRICS)))
    assert np.allclose((both - many["mean"]) / many["scale"], [[1, 1, 1, 1], [-1, -1, -1, -1]], atol=1e-5)


def test_the_print_bench_refuses_data_of_drawn_fabrics(skirts, tmp_path):
    from tryon.bench.prints import run_print_bench
    from tryon.errors import TryonError

    with pytest.raises(TryonError, match="draws its fabric per drape"):
        run_print_bench(tmp_path / "print.json", skirts)
