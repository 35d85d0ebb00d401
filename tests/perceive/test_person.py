"""The person finder on rendered bodies (BlazePose finds Anny renders as it finds people)
and its refusals; photo loading on awkward files."""

import numpy as np
import pytest
from PIL import Image

from tryon.errors import InputFileError
from tryon.perceive.images import load_photo

BACKGROUND = (0.55, 0.6, 0.65)


@pytest.fixture(scope="module")
def standing_render():
    """A front render of Anny's average body in the A-pose, 480x640, and its silhouette."""
    from tryon.body.anny_model import ShapeParams, body_model
    from tryon.body.pose import posed_body
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes

    body = posed_body(body_model().rest_shape(ShapeParams()), "a")
    cam = Camera.fit([body.vertices], "front", aspect=480 / 640)
    img = render_meshes([RenderMesh(body.vertices, body.faces, color=(0.85, 0.68, 0.58))], 480, 640, cam,
                        background=BACKGROUND, backend="numpy")
    silhouette = np.abs(img.astype(int) - np.array(BACKGROUND) * 255).sum(-1) > 12
    return img, silhouette


def _canvas(h: int, w: int) -> np.ndarray:
    return np.tile((np.array(BACKGROUND) * 255).astype(np.uint8), (h, w, 1))


@pytest.mark.anny
def test_a_whole_standing_person_is_found_with_mask_and_keypoints(standing_render):
    from tryon.perceive.person import FEET, HEAD, find_person

    img, silhouette = standing_render
    p = find_person(img, "render.png")
    m = p.mask > 0.5
    assert (m & silhouette).sum() / (m | silhouette).sum() > 0.8  # mask against the true silhouette
    ys = np.nonzero(silhouette)[0]
    assert p.keypoints[HEAD, 1].min() < ys.min() + 0.12 * (ys.max() - ys.min())
    assert p.keypoints[FEET, 1].max() > ys.max() - 0.06 * (ys.max() - ys.min())
    assert abs(p.height_px - (ys.max() - ys.min())) < 0.08 * (ys.max() - ys.min())
    assert p.people_found == 1 and not p.notes


@pytest.mark.anny
@pytest.mark.parametrize("crop,word", [((0.0, 0.8), "feet"), ((0.12, 1.0), "head")])
def test_a_person_cut_off_by_the_frame_is_refused_naming_the_part(standing_render, crop, word):
    from tryon.perceive.person import PersonNotFound, find_person

    img, _ = standing_render
    h = img.shape[0]
    with pytest.raises(PersonNotFound, match=rf"cut\.png: the {word} .*outside the picture"):
        find_person(np.ascontiguousarray(img[int(crop[0] * h):int(crop[1] * h)]), "cut.png")


@pytest.mark.anny
def test_a_small_or_lying_person_or_an_empty_picture_is_refused(standing_render):
    from tryon.perceive.person import PersonNotFound, find_person

    img, _ = standing_render
    small = _canvas(1800, 1350)
    small[1200:1360, 500:620] = np.asarray(Image.fromarray(img).resize((120, 160)))
    with pytest.raises(PersonNotFound, match="far.png: .*too small|far.png: no person"):
        find_person(small, "far.png")
    with pytest.raises(PersonNotFound, match="lying.png: the person is not standing"):
        find_person(np.ascontiguousarray(np.rot90(img)), "lying.png")
    with pytest.raises(PersonNotFound, match="wall.png: no person found"):
        find_person(_canvas(640, 480), "wall.png")


@pytest.mark.anny
def test_of_two_people_the_larger_whole_one_is_used_and_the_note_says_so(standing_render):
    from tryon.perceive.person import find_person

    img, silhouette = standing_render
    two = _canvas(640, 960)
    two[:, :480] = img
    near = np.asarray(Image.fromarray(img).resize((336, 448)))
    two[160:608, 552:888] = near
    p = find_person(two, "two.png")
    assert p.people_found == 2 and "2 people" in p.notes[0]
    assert p.box[2] <= 480 + 10  # the full-size person on the left


@pytest.mark.anny
def test_exif_orientation_is_honoured(standing_render, tmp_path):
    from tryon.perceive.person import find_person_in_file

    img, _ = standing_render
    stored = Image.fromarray(img).transpose(Image.Transpose.ROTATE_90)  # as a phone held sideways stores it
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 degrees clockwise to view"
    stored.save(tmp_path / "phone.jpg", exif=exif.tobytes(), quality=92)
    assert load_photo(tmp_path / "phone.jpg").shape == img.shape
    assert find_person_in_file(tmp_path / "phone.jpg").people_found == 1


def test_unreadable_photos_get_one_clear_error_naming_the_file(tmp_path):
    (tmp_path / "notes.jpg").write_text("not a picture")
    Image.new("RGB", (400, 300), "white").save(tmp_path / "whole.jpg")
    (tmp_path / "cut.jpg").write_bytes((tmp_path / "whole.jpg").read_bytes()[:200])
    Image.new("RGB", (40, 30), "white").save(tmp_path / "tiny.png")
    Image.new("1", (12000, 7000)).save(tmp_path / "huge.png")
    cases = {"missing.jpg": "no such image file", "notes.jpg": "not a picture", "cut.jpg": "the picture is damaged or incomplete",
             "tiny.png": "40x30 pixels is too small a picture", "huge.png": "12000x7000 is too large a picture"}
    for name, words in cases.items():
        with pytest.raises(InputFileError, match=rf"{name}: {words}"):
            load_photo(tmp_path / name)


def test_odd_modes_become_rgb(tmp_path):
    rgba = Image.new("RGBA", (100, 80), (255, 0, 0, 0))
    rgba.save(tmp_path / "clear.png")
    assert (load_photo(tmp_path / "clear.png") == 255).all()  # transparent over white
    deep = Image.fromarray(np.full((80, 100), 4000, np.uint16))
    deep.save(tmp_path / "deep.png")
    out = load_photo(tmp_path / "deep.png")
    assert out.shape == (80, 100, 3) and out.dtype == np.uint8 and out.max() == 255


@pytest.mark.anny
def test_person_command_writes_overlays_and_names_the_refused(standing_render, tmp_path, capsys):
    import json

    from tryon.cli import main

    Image.fromarray(standing_render[0]).save(tmp_path / "front.png")
    Image.fromarray(_canvas(640, 480)).save(tmp_path / "wall.png")
    code = main(["person", str(tmp_path / "front.png"), str(tmp_path / "wall.png"), "--out", str(tmp_path / "out")])
    assert code == 1  # one photo refused
    assert "wall.png: no person found" in capsys.readouterr().out
    people = json.loads((tmp_path / "out" / "people.json").read_text())
    assert len(people["people"]) == 1 and len(people["refused"]) == 1
    assert (tmp_path / "out" / people["people"][0]["picture"]).is_file()
    assert set(people["people"][0]["keypoints_px"]) >= {"nose", "left_heel", "right_foot_index"}
    assert main(["person", str(tmp_path / "wall.png"), "--out", str(tmp_path / "out2")]) == 2  # nothing usable


def test_a_person_tile_is_centred_on_the_box_with_its_pad():
    from tryon.perceive.person import person_tile

    image = np.zeros((400, 300, 3), np.uint8)
    image[100:300, 120:180] = 255  # the person: 200 px high, 60 wide
    tile = person_tile(image, (120, 100, 180, 300), 120, aspect=0.5)
    assert tile.shape == (120, 60, 3)
    bright = np.argwhere(tile[..., 0] > 127)
    # 10 % of the height padded above and below: the person spans rows 10-110 of 120
    assert bright[:, 0].min() == pytest.approx(10, abs=1) and bright[:, 0].max() == pytest.approx(109, abs=1)
    assert bright[:, 1].mean() == pytest.approx(29.5, abs=1)  # centred across
    free = person_tile(image, (120, 100, 180, 300), 120)      # as wide as the padded box: 100 px of 240 high
    assert free.shape == (120, 50, 3)
