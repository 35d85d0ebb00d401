"""A graphic print on the front panel: the image is read and checked, placed on the
pattern the right way round, covers the faces its alpha covers, becomes a material region,
and is drawn on triangles fine enough for it."""

import json

import numpy as np
import pytest
from PIL import Image

from tryon.errors import InputFileError, TryonError
from tryon.garment.prints import GraphicPrint, panel_xy
from tryon.learn.model import load_shipped
from tryon.render.appearance import subdivide_faces


@pytest.fixture(scope="module")
def garment():
    return load_shipped("tshirt").reference_garment("female", "M")


def _png(path, rgba):
    Image.fromarray(np.asarray(rgba, np.uint8)).save(path)
    return path


def _halves(rows=40, cols=60):
    """Left half red, right half blue, opaque."""
    im = np.zeros((rows, cols, 4), np.uint8)
    im[:, : cols // 2] = (255, 0, 0, 255)
    im[:, cols // 2:] = (0, 0, 255, 255)
    return im


def test_bad_images_are_refused_by_name(tmp_path):
    with pytest.raises(InputFileError, match="does not exist"):
        GraphicPrint.load(tmp_path / "none.png")
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(InputFileError, match="cannot be read"):
        GraphicPrint.load(tmp_path / "text.png")
    with pytest.raises(InputFileError, match="transparent everywhere"):
        GraphicPrint.load(_png(tmp_path / "clear.png", np.zeros((8, 8, 4))))
    with pytest.raises(TryonError, match="print width"):
        GraphicPrint.load(_png(tmp_path / "ok.png", _halves()), width_cm=500)


def test_a_print_too_wide_for_the_panel_is_refused(tmp_path, garment):
    with pytest.raises(TryonError, match="does not fit"):
        GraphicPrint.load(_png(tmp_path / "p.png", _halves(10, 60)), width_cm=58).placed_on(garment.pattern)


def test_the_image_sits_centred_below_the_neckline_the_right_way_round(tmp_path, garment):
    pr = GraphicPrint.load(_png(tmp_path / "p.png", _halves()), width_cm=18).placed_on(garment.pattern)
    assert pr.origin[0] == pytest.approx(-0.09) and pr.height == pytest.approx(0.12)
    top = pr.origin[1]
    # image columns run along +x (the body's left, seen from the front), rows down -y
    left, right = pr.rgba_at(np.array([[-0.05, top - 0.06], [0.05, top - 0.06]]))
    assert np.allclose(left, (1, 0, 0, 1)) and np.allclose(right, (0, 0, 1, 1))
    assert pr.rgba_at(np.array([[0.0, top + 0.01], [0.0, top - 0.13], [0.1, top - 0.06]]))[:, 3].max() == 0.0
    # the neckline's lowest point is `top_below_neck` above the print
    neck = min(e.polyline(50)[:, 1].min() for e in garment.pattern.panel("front").edges if e.name.startswith("neck"))
    assert top == pytest.approx(neck - pr.top_below_neck)


def test_covered_faces_follow_the_alpha_and_lie_on_the_front(tmp_path, garment):
    square = np.full((50, 50, 4), 255, np.uint8)
    ring = square.copy()
    yy, xx = np.mgrid[:50, :50]
    ring[np.hypot(xx - 24.5, yy - 24.5) < 15, 3] = 0      # a hole of 60 % of the width
    full = GraphicPrint.load(_png(tmp_path / "sq.png", square), width_cm=15).placed_on(garment.pattern)
    holed = GraphicPrint.load(_png(tmp_path / "ring.png", ring), width_cm=15).placed_on(garment.pattern)
    faces = full.faces(garment)
    front = garment.pattern.panels.index(garment.pattern.panel("front"))
    assert (garment.face_panel[faces] == front).all()
    area = full.describe(garment)["area_cm2"]
    assert 0.8 * 225 < area < 1.2 * 225                   # a 15 cm square, to a 1.5 cm mesh's accuracy
    hole = np.pi * (0.3 * 15) ** 2
    assert holed.describe(garment)["area_cm2"] == pytest.approx(area - hole, rel=0.25)
    assert set(holed.faces(garment)) < set(faces)
    region = full.region(garment)
    assert region.added_density > 0 and region.stretch_scale > 1 and region.bend_scale > 1
    assert json.dumps(full.describe(garment))


def test_panel_xy_inverts_the_material_frame():
    from tryon.garment.triangulate import PanelMesh

    pts = np.random.default_rng(0).standard_normal((20, 2))
    for grain in ((0.0, 1.0), (0.6, 0.8)):
        uv = PanelMesh("p", pts, np.zeros((0, 3), int), {}, grain).material_uv()
        assert np.allclose(panel_xy(uv, grain), pts)


def test_subdivided_faces_cover_the_same_surface_once():
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.3], [2, 0, 0]], float)
    faces = np.array([[0, 1, 2], [1, 3, 2], [1, 4, 3]])
    for ids, n in (([0], 1), ([0, 1], 4), ([0, 1, 2], 3)):
        face_of, bary, out, new = subdivide_faces(faces, np.array(ids), len(x), n)
        pts = np.concatenate([x, np.einsum("pk,pkd->pd", bary, x[faces[face_of]])])
        area = lambda v, f: 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)  # noqa: E731
        assert area(pts, out).sum() == pytest.approx(area(x, faces).sum())
        assert new.sum() == len(ids) * n * n and (~new).sum() == len(faces) - len(ids)
        nrm = np.cross(pts[out[:, 1]] - pts[out[:, 0]], pts[out[:, 2]] - pts[out[:, 0]])
        assert (nrm[:, 2] > 0).all()                      # orientation kept
        # no point made twice: every new point is distinct
        assert len(np.unique(pts.round(12), axis=0)) == len(pts)
        assert np.allclose(bary.sum(1), 1.0) and (bary >= 0).all() and (bary < 1).all()
