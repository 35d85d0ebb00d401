import os

import pytest
import torch

os.environ.setdefault("TQDM_DISABLE", "1")
torch.set_num_threads(1)


@pytest.fixture
def tmp_out(tmp_path):
    return tmp_path / "out"


@pytest.fixture(scope="session")
def size_m_man():
    """The men's size-M fit model (Anny fitted to the size chart) and its drafting
    measurements, fitted once for every test that drafts on it."""
    from tryon.body.fit import Measurements, fit_body
    from tryon.body.measure import drafting_measurements
    from tryon.garment.sizes import size_measurements

    m = size_measurements("M", "male")
    fit = fit_body(Measurements(height_cm=m["height_cm"], gender="male", chest_cm=m["chest_cm"], waist_cm=m["waist_cm"],
                                hip_cm=m["hip_cm"]), prior=False)  # as tryon drape fits a size's fit model
    return fit.shape, drafting_measurements(fit.shape)
