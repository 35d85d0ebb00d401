"""Fabric estimation: observed files, the three methods, and `tryon fit-fabric`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tryon.cli import main
from tryon.diff.fit import fit_fabric, parameter_errors
from tryon.diff.observed import load_observed, make_observed, save_observed
from tryon.errors import TryonError
from tryon.fabric.presets import load_fabric


@pytest.fixture(scope="module")
def observed(tmp_path_factory):
    """A short hanging-in-wind sequence of a 4x4 cloth made with a measured preset."""
    path = tmp_path_factory.mktemp("obs") / "denim.npz"
    save_observed(path, make_observed("11oz-black-denim", resolution=4, duration=0.32, frame_time=0.04))
    return path


def test_observed_file_round_trip(observed):
    obs = load_observed(observed)
    assert obs.positions.shape == (9, 16, 3)
    assert obs.fabric == "11oz-black-denim"
    assert obs.steps_per_frame == 4
    assert len(obs.pinned) == 2
    moved = np.linalg.norm(obs.positions[-1] - obs.positions[0], axis=1)
    assert moved.max() > 0.02  # the cloth falls and swings
    np.testing.assert_array_equal(obs.positions[-1][obs.pinned], obs.positions[0][obs.pinned])


def test_bad_observed_files_are_explained(tmp_path, observed):
    data = dict(np.load(observed))
    del data["wind_drag"]
    np.savez(tmp_path / "missing.npz", **data)
    with pytest.raises(TryonError, match="missing keys \\['wind_drag'\\]"):
        load_observed(tmp_path / "missing.npz")
    data = dict(np.load(observed))
    data["uv"] = data["uv"][:-1]
    np.savez(tmp_path / "uv.npz", **data)
    with pytest.raises(TryonError, match="'uv' must be \\[16, 2\\]"):
        load_observed(tmp_path / "uv.npz")
    with pytest.raises(TryonError, match="unknown fit method"):
        fit_fabric(load_observed(observed), method="newton")


@pytest.mark.slow
def test_gradient_fit_recovers_density_with_fewer_simulations(observed):
    obs = load_observed(observed)
    truth = load_fabric("11oz-black-denim")
    grad, est = fit_fabric(obs, "gradient")
    fd, _ = fit_fabric(obs, "finite-difference")
    start_error, _ = est.simulation_error(np.zeros(9))
    err, _ = est.simulation_error(grad.theta)
    errors = parameter_errors(grad.fabric, truth)
    assert errors["density_error"] < 0.05
    assert err < 0.02 and err < 0.5 * start_error
    assert grad.simulations < fd.simulations
    assert grad.gradient_evaluations == grad.simulations


def test_parameter_errors_are_relative_frobenius():
    truth = load_fabric("gray-interlock")
    scaled = truth.with_parameters(truth.parameters() * 1.1)
    errors = parameter_errors(scaled, truth)
    for key in ("density_error", "stretching_error", "linear_stretching_error", "nonlinear_stretching_error", "bending_error"):
        assert errors[key] == pytest.approx(0.1)


def test_fit_fabric_command_writes_outputs(tmp_path, observed):
    out = tmp_path / "fit"
    assert main(["fit-fabric", str(observed), "--out", str(out), "--truth", "11oz-black-denim", "--method", "physical", "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    for key in ("simulation_error", "simulations", "wall_s", "density_error", "stretching_error", "bending_error"):
        assert np.isfinite(report[key])
    assert report["simulations"] == 0
    for name in ("fabric.json", "loss_curve.png", "observed_vs_fit.png"):
        assert (out / name).stat().st_size > 100
    fitted = load_fabric(str(out / "fabric.json"))
    assert float(fitted.density) == pytest.approx(report["fitted"]["density_kg_m2"])


def test_make_observed_command(tmp_path):
    out = tmp_path / "obs.npz"
    assert main(["fit-fabric", "--make-observed", "gray-interlock", str(out), "--resolution", "3", "--duration", "0.08", "--quiet"]) == 0
    assert load_observed(out).positions.shape == (3, 9, 3)
    assert main(["fit-fabric", "--make-observed", "no-such-fabric", str(tmp_path / "x.npz"), "--quiet"]) == 2
