"""Tests for tryon.render: offscreen rendering (OpenGL and numpy fallback), colour maps, legends, GIF."""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from tryon.errors import MeshError, TryonError
from tryon.render import (
    Camera,
    RenderMesh,
    add_colorbar,
    opengl_available,
    render_meshes,
    save_png,
    scalar_to_rgb,
    write_gif,
    write_mp4,
)
from tryon.render.colormap import colormap_lut

SIZE = 160
WHITE = (1.0, 1.0, 1.0)

needs_gl = [pytest.mark.gl, pytest.mark.skipif(not opengl_available(), reason="no offscreen OpenGL context on this machine")]
BACKENDS = [pytest.param("gl", marks=needs_gl), "numpy"]


@pytest.fixture(scope="module")
def sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=3)


def _mask(img: np.ndarray) -> np.ndarray:
    """Foreground = pixels that differ from the white background."""
    return (img < 250).any(axis=2)


def _luma(img: np.ndarray) -> np.ndarray:
    return img.astype(np.float64) @ np.array([0.299, 0.587, 0.114])


def _quad(normal_towards_camera: bool) -> tuple[np.ndarray, np.ndarray]:
    """A square in the XZ plane; winding gives normal -Y (towards a front camera) or +Y."""
    verts = np.array([[-0.5, 0, -0.5], [0.5, 0, -0.5], [0.5, 0, 0.5], [-0.5, 0, 0.5]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return verts, (faces if normal_towards_camera else faces[:, ::-1].copy())


@pytest.mark.parametrize("backend", BACKENDS)
def test_sphere_front_render(sphere: trimesh.Trimesh, backend: str) -> None:
    img = render_meshes([RenderMesh(sphere.vertices, sphere.faces, color=(0.8, 0.3, 0.3))], SIZE, SIZE, backend=backend)
    assert img.shape == (SIZE, SIZE, 3) and img.dtype == np.uint8
    mask = _mask(img)
    coverage = mask.mean()
    assert 0.2 < coverage < 0.7
    ys, xs = np.nonzero(mask)
    assert abs(xs.mean() - (SIZE - 1) / 2) < 0.02 * SIZE
    assert abs(ys.mean() - (SIZE - 1) / 2) < 0.02 * SIZE
    # Round: the silhouette is as wide as it is tall.
    assert abs((xs.max() - xs.min()) - (ys.max() - ys.min())) <= 2
    luma = _luma(img)[mask]
    assert luma.std() > 8.0  # shaded, not flat
    assert not (img[mask] < 10).all(axis=1).any()  # no black artefacts
    # The key light comes from the upper left: that quadrant of the sphere is brighter.
    h = SIZE // 2
    upper_left = _luma(img[:h, :h])[mask[:h, :h]].mean()
    lower_right = _luma(img[h:, h:])[mask[h:, h:]].mean()
    assert upper_left > lower_right + 10


@pytest.mark.parametrize("backend", BACKENDS)
def test_face_colors_left_red_right_blue(sphere: trimesh.Trimesh, backend: str) -> None:
    centroids = sphere.vertices[sphere.faces].mean(axis=1)
    face_colors = np.where(centroids[:, :1] < 0, [[0.9, 0.1, 0.1]], [[0.1, 0.1, 0.9]])
    mesh = RenderMesh(sphere.vertices, sphere.faces, face_colors=face_colors)
    img = render_meshes([mesh], SIZE, SIZE, backend=backend)
    rgb = img.astype(np.int64)
    red = (rgb[..., 0] > 2 * rgb[..., 2]) & (rgb[..., 0] > 80)
    blue = (rgb[..., 2] > 2 * rgb[..., 0]) & (rgb[..., 2] > 80)
    assert red.sum() > 0.05 * SIZE**2 and blue.sum() > 0.05 * SIZE**2
    # Front camera at -Y with Z up: world -X is on the image's left.
    h = SIZE // 2
    assert red[:, :h].sum() > 10 * red[:, h:].sum()
    assert blue[:, h:].sum() > 10 * blue[:, :h].sum()


@pytest.mark.gl
@pytest.mark.skipif(not opengl_available(), reason="no offscreen OpenGL context on this machine")
def test_numpy_fallback_matches_opengl(sphere: trimesh.Trimesh) -> None:
    body = trimesh.creation.capsule(height=1.0, radius=0.25)
    meshes = [
        RenderMesh(body.vertices, body.faces, color=(0.85, 0.7, 0.6), two_sided=False),
        RenderMesh(0.4 * sphere.vertices + [0.2, -0.4, 0.3], sphere.faces, color=(0.2, 0.4, 0.8), smooth=False),
    ]
    cam = Camera.fit(meshes, "three_quarter")
    gl = render_meshes(meshes, SIZE, SIZE, camera=cam, backend="gl")
    fallback = render_meshes(meshes, SIZE, SIZE, camera=cam, backend="numpy")
    a, b = _mask(gl), _mask(fallback)
    assert (a & b).sum() / (a | b).sum() > 0.95
    both = a & b
    assert np.abs(gl.astype(np.int64) - fallback)[both].mean() < 4.0


def test_environment_variable_forces_fallback(sphere: trimesh.Trimesh, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TRYON_RENDER_BACKEND", "numpy")
    mesh = RenderMesh(sphere.vertices, sphere.faces)
    assert np.array_equal(render_meshes([mesh], 64, 64), render_meshes([mesh], 64, 64, backend="numpy"))
    monkeypatch.setenv("TRYON_RENDER_BACKEND", "vulkan")
    with pytest.raises(TryonError, match="unknown render backend"):
        render_meshes([mesh], 64, 64)


@pytest.mark.parametrize("backend", BACKENDS)
def test_two_sided_lighting(backend: str) -> None:
    lum = {}
    for towards in (True, False):
        for two_sided in (True, False):
            verts, faces = _quad(towards)
            mesh = RenderMesh(verts, faces, color=(0.7, 0.7, 0.7), two_sided=two_sided, smooth=False)
            img = render_meshes([mesh], 96, 96, camera=Camera(eye=(0, -3, 0), target=(0, 0, 0)), backend=backend)
            mask = _mask(img)
            assert mask.mean() > 0.1
            lum[towards, two_sided] = _luma(img)[mask].mean()
    # A two-sided sheet looks the same from either side; a one-sided one seen from behind gets only ambient light.
    assert abs(lum[True, True] - lum[False, True]) < 1.0
    assert abs(lum[True, True] - lum[True, False]) < 1.0
    assert lum[False, False] < lum[True, True] - 40


@pytest.mark.parametrize("backend", BACKENDS)
def test_wireframe_draws_dark_edges(backend: str) -> None:
    verts, faces = _quad(True)
    cam = Camera(eye=(0, -3, 0), target=(0, 0, 0))
    grey = (0.9, 0.9, 0.9)
    plain, wire = (
        render_meshes([RenderMesh(verts, faces, color=grey, wireframe=w)], 96, 96, camera=cam, backend=backend)
        for w in (False, True)
    )
    dark_plain = (_luma(plain) < 90).sum()
    dark_wire = (_luma(wire) < 90).sum()
    assert dark_plain == 0 and dark_wire > 40  # the diagonal and the border


def test_camera_fit_views_follow_convention() -> None:
    # A box long along X (2 m), thin along Y (0.2 m), 1 m tall.
    box = trimesh.creation.box(extents=(2.0, 0.2, 1.0))
    mesh = RenderMesh(box.vertices, box.faces)
    widths = {}
    for view in ("front", "side", "top"):
        img = render_meshes([mesh], 120, 120, camera=Camera.fit([mesh], view), backend="numpy")
        ys, xs = np.nonzero(_mask(img))
        widths[view] = (xs.max() - xs.min(), ys.max() - ys.min())
    assert widths["front"][0] > 1.6 * widths["front"][1]  # sees X across, Z up
    assert widths["side"][1] > 2.5 * widths["side"][0]  # sees Y across (thin), Z up
    assert widths["top"][0] > 5 * widths["top"][1]  # sees X across, Y up
    front = Camera.fit([mesh], "front")
    assert front.eye[1] < -1.0 and abs(front.eye[0]) < 1e-9
    assert Camera.fit([mesh], "back").eye[1] > 1.0
    assert Camera.fit([mesh], "side").eye[0] > 1.0
    assert Camera.fit([mesh], "top").eye[2] > 1.0


def test_camera_fit_fills_the_frame_with_margin() -> None:
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    cam = Camera.fit([box.vertices], "front", margin=1.0)
    right, up, forward = cam.basis()
    rel = box.vertices - cam.eye
    depth = rel @ forward
    half = np.tan(np.radians(cam.fov_deg) / 2)
    extent = np.maximum(np.abs(rel @ right), np.abs(rel @ up)) / depth
    assert extent.max() == pytest.approx(half, rel=1e-9)  # tight with margin 1


def test_render_mesh_validation() -> None:
    verts, faces = _quad(True)
    with pytest.raises(MeshError, match="face indices"):
        RenderMesh(verts, faces + 10)
    with pytest.raises(MeshError, match="NaN"):
        RenderMesh(np.full((4, 3), np.nan), faces)
    with pytest.raises(MeshError, match="not both"):
        RenderMesh(verts, faces, vertex_colors=np.zeros((4, 3)), face_colors=np.zeros((2, 3)))
    with pytest.raises(MeshError, match="vertex_colors"):
        RenderMesh(verts, faces, vertex_colors=np.zeros((3, 3)))
    with pytest.raises(TryonError, match="unknown view"):
        Camera.fit([verts], "diagonal")


def test_save_png_round_trip(tmp_path: Path, sphere: trimesh.Trimesh) -> None:
    img = render_meshes([RenderMesh(sphere.vertices, sphere.faces)], 64, 48, backend="numpy")
    assert img.shape == (48, 64, 3)
    path = save_png(tmp_path / "s.png", img)
    assert np.array_equal(np.asarray(Image.open(path)), img)
    with pytest.raises(TryonError):
        save_png(tmp_path / "bad.png", img.astype(np.float32))
    assert sorted(os.listdir(tmp_path)) == ["s.png"]


# ----------------------------------------------------------------------------- colour maps


def test_scalar_to_rgb_matches_matplotlib() -> None:
    from matplotlib import colormaps

    values = np.array([-1.0, 0.0, 0.25, 0.5, 1.0, 2.0, np.nan])
    for name in ("viridis", "turbo", "coolwarm"):
        rgb = scalar_to_rgb(values, 0.0, 1.0, name, nan_color=(0.1, 0.2, 0.3))
        ref = colormaps[name](np.clip(values[:-1], 0, 1))[:, :3]
        np.testing.assert_allclose(rgb[:-1], ref, atol=2.0 / 255)
        np.testing.assert_allclose(rgb[-1], [0.1, 0.2, 0.3])
    lut = colormap_lut("viridis")
    np.testing.assert_allclose(scalar_to_rgb([5.0, 7.0], 5.0, 7.0), lut[[0, -1]])
    # Default range is the data range; shapes are preserved.
    grid = scalar_to_rgb(np.arange(6.0).reshape(2, 3))
    assert grid.shape == (2, 3, 3)
    np.testing.assert_allclose(grid[1, 2], lut[-1])
    with pytest.raises(TryonError, match="unknown colour map"):
        scalar_to_rgb([0.0], 0, 1, "no-such-map")
    with pytest.raises(TryonError, match="vmin <= vmax"):
        scalar_to_rgb([0.0], 1, 0)


def test_add_colorbar_draws_legend() -> None:
    img = np.full((200, 200, 3), 255, dtype=np.uint8)
    out = add_colorbar(img, 0.0, 8.0, "turbo", label="strain %", ticks=[0, 2, 4, 6, 8])
    assert out.shape[0] == 200 and out.shape[1] > 200
    assert np.array_equal(out[:, :200], img)  # the picture itself is untouched
    panel = out[:, 200:]
    assert (panel != 255).any(axis=2).mean() > 0.05
    lut = colormap_lut("turbo")
    # Sample the middle column of the bar: top ~ vmax colour, bottom ~ vmin colour.
    cols = np.nonzero((np.abs(panel.astype(int) - np.rint(lut[-1] * 255)).sum(axis=2) < 30).any(axis=0))[0]
    assert cols.size > 3
    bar_col = panel[:, cols[cols.size // 2]].astype(int)
    colored = np.nonzero((np.abs(bar_col - 255).sum(axis=1) > 0) & (bar_col.std(axis=1) > 5))[0]
    np.testing.assert_allclose(bar_col[colored[1]], lut[-1] * 255, atol=30)
    np.testing.assert_allclose(bar_col[colored[-2]], lut[0] * 255, atol=30)
    # Drawn over the image when not extending, on a dark background with light ink.
    dark = np.zeros((200, 200, 3), dtype=np.uint8)
    over = add_colorbar(dark, -1.0, 1.0, "coolwarm", label="x", extend=False)
    assert over.shape == dark.shape and (over[:, 150:] > 200).all(axis=2).any()
    with pytest.raises(TryonError):
        add_colorbar(img.astype(np.float32), 0, 1)


# ----------------------------------------------------------------------------- animation


def test_write_gif_frame_count(tmp_path: Path) -> None:
    frames = []
    for k in range(5):
        f = np.full((40, 50, 3), 255, dtype=np.uint8)
        f[5:15, 5 + 8 * k : 13 + 8 * k] = (200, 30, 30)
        frames.append(f)
    path = write_gif(tmp_path / "a.gif", frames, fps=10)
    with Image.open(path) as im:
        assert im.n_frames == 5 and im.size == (50, 40)
        assert im.info["duration"] == 100
        im.seek(3)
        np.testing.assert_allclose(np.asarray(im.convert("RGB"), dtype=int), frames[3], atol=8)
    with pytest.raises(TryonError, match="frame 1"):
        write_gif(tmp_path / "b.gif", [frames[0], frames[1][:10]], fps=10)
    with pytest.raises(TryonError, match="no frames"):
        write_gif(tmp_path / "b.gif", [], fps=10)
    assert sorted(os.listdir(tmp_path)) == ["a.gif"]


def test_write_mp4_or_clear_error(tmp_path: Path) -> None:
    frames = [np.full((31, 41, 3), 20 * k, dtype=np.uint8) for k in range(4)]
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        with pytest.raises(TryonError, match="write_gif"):
            write_mp4(tmp_path / "a.mp4", frames, fps=10)
        assert os.listdir(tmp_path) == []
    else:
        path = write_mp4(tmp_path / "a.mp4", frames, fps=10)
        assert path.stat().st_size > 0


def test_missing_opengl_falls_back_with_one_warning(
    sphere: trimesh.Trimesh, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    from tryon.render import offscreen

    def no_egl() -> None:
        raise OSError("libEGL.so.1: cannot open shared object file")

    monkeypatch.setattr(offscreen, "_THREAD", threading.local())
    monkeypatch.setattr(offscreen, "_GL_FAILURE", None)
    monkeypatch.setattr(offscreen, "_GLState", no_egl)
    monkeypatch.delenv("TRYON_RENDER_BACKEND", raising=False)
    mesh = RenderMesh(sphere.vertices, sphere.faces)
    with caplog.at_level(logging.WARNING, logger="tryon.render.offscreen"):
        first = render_meshes([mesh], 64, 64)
        second = render_meshes([mesh], 64, 64)
    assert np.array_equal(first, render_meshes([mesh], 64, 64, backend="numpy"))
    assert np.array_equal(first, second)
    warnings = [r for r in caplog.records if "numpy rasteriser" in r.getMessage()]
    assert len(warnings) == 1 and "libEGL" in warnings[0].getMessage()
    with pytest.raises(TryonError, match="backend='numpy'"):
        render_meshes([mesh], 64, 64, backend="gl")


@pytest.mark.gl
@pytest.mark.skipif(not opengl_available(), reason="no offscreen OpenGL context on this machine")
def test_rendering_from_another_thread(sphere: trimesh.Trimesh) -> None:
    mesh = RenderMesh(sphere.vertices, sphere.faces)
    here = render_meshes([mesh], 64, 64, backend="gl")
    result: list[np.ndarray] = []
    worker = threading.Thread(target=lambda: result.append(render_meshes([mesh], 64, 64, backend="gl")))
    worker.start()
    worker.join()
    assert len(result) == 1 and np.array_equal(result[0], here)
