"""The body from photos, end to end on renders: two people of the same stature and weight
whose hips differ, photographed from the front and the side, read as they are."""

import json

import numpy as np
import pytest
from PIL import Image

HEIGHT = 168.0


def _photos(tmp_path, name: str, weight_kg: float) -> tuple[list[str], dict]:
    """Front and left photos of a woman as the photo datasets take them, and her tapes."""
    from tryon.body.fit import Measurements, fit_body
    from tryon.dataset.photos import photograph

    fit = fit_body(Measurements(height_cm=HEIGHT, weight_kg=weight_kg, gender="female"))
    paths = []
    for view, img in zip(("front", "left"), photograph(fit.shape, ("front", "left"), seed=3)):
        path = tmp_path / f"{name}-{view}.png"
        Image.fromarray(img).save(path)
        paths.append(str(path))
    return paths, fit.achieved


@pytest.mark.anny
def test_from_images_reads_the_body_off_the_photos_and_writes_its_files(tmp_path, capsys):
    """No weight given: all the photos know of the two women is what they see."""
    from tryon.cli import main

    read, truth = {}, {}
    for name, weight in (("slim", 55.0), ("full", 88.0)):
        photos, truth[name] = _photos(tmp_path, name, weight)
        out = tmp_path / f"out-{name}"
        assert main(["body", "from-images", *photos, "--height-cm", str(HEIGHT), "--gender", "female",
                     "--out", str(out)]) == 0
        m = json.loads((out / "measurements.json").read_text())
        assert {"height_cm", "weight_kg", "chest_cm", "waist_cm", "hip_cm", "neck_cm", "thigh_cm", "inseam_cm",
                "arm_length_cm", "shoulder_width_cm"} <= set(m) and m["weight_given"] is False
        assert all(m[f"{k}_sd"] > 0 for k in ("weight_kg", "chest_cm", "waist_cm", "hip_cm"))
        assert len(list(out.glob("overlay-*.png"))) == 2 and (out / "body.obj").is_file()
        report = json.loads((out / "report.json").read_text())
        assert abs(report["body"]["achieved"]["height_cm"] - HEIGHT) < 1.0
        read[name] = m
    for key, tape in (("weight_kg", "weight_kg"), ("hip_cm", "hip_cm"), ("chest_cm", "chest_cm")):
        seen = read["full"][key] - read["slim"][key]
        real = truth["full"][tape] - truth["slim"][tape]
        assert seen > 0.6 * real, key   # the photos see most of the difference
        for name in read:
            assert abs(read[name][key] - truth[name][tape]) < 0.12 * truth[name][tape], (name, key)


@pytest.mark.anny
def test_from_images_refuses_a_picture_without_a_person_naming_it(tmp_path, capsys):
    from tryon.cli import main

    wall = tmp_path / "wall.png"
    Image.fromarray(np.full((640, 480, 3), 150, np.uint8)).save(wall)
    assert main(["body", "from-images", str(wall), "--height-cm", "170", "--gender", "male", "--out",
                 str(tmp_path / "out")]) == 2
    assert "wall.png: no person found" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()   # nothing half-written


def test_drape_with_images_refuses_typed_girths(tmp_path, capsys):
    from tryon.cli import main

    assert main(["drape", "--images", "a.png", "--height-cm", "170", "--gender", "male", "--chest-cm", "100",
                 "--out", str(tmp_path / "d")]) == 2
    assert "--chest-cm" in capsys.readouterr().err


def test_the_number_of_views_and_the_person_are_checked_before_any_work(tmp_path):
    from tryon.errors import TryonError
    from tryon.learn.body_from_photos import body_from_image_files

    with pytest.raises(TryonError, match="1 to 8 views"):
        body_from_image_files([], 170, "male")
    with pytest.raises(TryonError, match="height"):
        body_from_image_files(["x.png"], 250, "male")
    with pytest.raises(TryonError, match="gender"):
        body_from_image_files(["x.png"], 170, "other")
    with pytest.raises(TryonError, match="age 12"):
        body_from_image_files(["x.png"], np.float32(170.0), "male", age=12)
