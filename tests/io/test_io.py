"""Tests for tryon.io: atomic outputs, OBJ/PLY/GLB meshes, frame sequences."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from tryon.errors import InputFileError, MeshError
from tryon.io.atomic import OWNER_MARKER
from tryon.io import (
    atomic_output_dir,
    atomic_write,
    load_frames_npz,
    read_obj,
    save_frames_npz,
    split_by_uv,
    write_glb,
    write_obj,
    write_obj_sequence,
    write_ply,
)


def _grid(n: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A wavy n x n grid: vertices [n*n, 3], faces, uv."""
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    verts = np.stack([u, v, 0.1 * np.sin(3 * u) * np.cos(2 * v)], -1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    uv = np.stack([u, v], -1).reshape(-1, 2) * 0.5
    return verts, faces, uv


def _leftovers(folder: Path, keep: set[str]) -> list[str]:
    return sorted(p for p in os.listdir(folder) if p not in keep)


# ----------------------------------------------------------------------------- OBJ


def test_obj_round_trip_with_uv(tmp_path: Path) -> None:
    verts, faces, uv = _grid()
    out = write_obj(tmp_path / "grid.obj", verts, faces, uv)
    mesh = read_obj(out)
    np.testing.assert_allclose(mesh.vertices, verts, rtol=1e-8, atol=1e-9)
    np.testing.assert_array_equal(mesh.faces, faces)
    assert mesh.faces.dtype == np.int64 and mesh.vertices.dtype == np.float64
    np.testing.assert_allclose(mesh.uv, uv, atol=1e-9)
    np.testing.assert_allclose(mesh.uv_coords[mesh.face_uv], uv[faces], atol=1e-9)
    assert _leftovers(tmp_path, {"grid.obj"}) == []


def test_obj_round_trip_torch_without_uv(tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    verts, faces, _ = _grid(3)
    write_obj(tmp_path / "t.obj", torch.tensor(verts), torch.tensor(faces))
    mesh = read_obj(tmp_path / "t.obj")
    np.testing.assert_allclose(mesh.vertices, verts, rtol=1e-8, atol=1e-9)
    assert mesh.uv is None and mesh.face_uv is None


def test_obj_polygons_negative_indices_and_normals(tmp_path: Path) -> None:
    text = "\n".join(
        [
            "# polygon forms",
            "o thing",
            "v 0 0 0",
            "v 1 0 0",
            "v 1 1 0",
            "v 0 1 0",
            "v 2 0.5 0   # trailing comment",
            "vn 0 0 1",
            "s off",
            "f 1//1 2//1 3//1 4//1",  # quad with v//vn
            "f -4 -3 -1",  # relative: 5 vertices so far -> 2 3 5
            "f 1//1 2//1 5//1 3//1 4//1",  # pentagon -> fan of 3
        ]
    )
    path = tmp_path / "poly.obj"
    path.write_text(text)
    mesh = read_obj(path)
    expected = [[0, 1, 2], [0, 2, 3], [1, 2, 4], [0, 1, 4], [0, 4, 2], [0, 2, 3]]
    np.testing.assert_array_equal(mesh.faces, expected)
    assert mesh.vertices.shape == (5, 3)
    assert mesh.uv is None


def test_obj_v_vt_vn_form(tmp_path: Path) -> None:
    path = tmp_path / "vtn.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1\n")
    mesh = read_obj(path)
    np.testing.assert_allclose(mesh.uv, [[0, 0], [1, 0], [0, 1]])


@pytest.mark.parametrize(
    ("lines", "bad_line", "error"),
    [
        (["v 0 0 0", "v 1 0 0", "v 1 x 0", "f 1 2 3"], 3, InputFileError),
        (["v 0 0 0", "v 1 0 0", "v 0 1 0", "f 1 2"], 4, InputFileError),
        (["v 0 0 0", "v 1 0 0", "v 0 1 0", "", "f 1 2 4"], 5, InputFileError),
        (["v 0 0 0", "v 1 0 0", "v 0 1 0", "f 0 1 2"], 4, InputFileError),
        (["v 0 0 0", "v 1 0 0", "v 0 1 0", "f -1 -2 -4"], 4, InputFileError),
        (["v 0 0 0", "v 1 nan 0", "v 0 1 0", "f 1 2 3"], 2, MeshError),
        (["v 0 0 0", "v 1 0 0", "v 0 1 0", "vt 0 0", "f 1/1 2/1 3"], 5, InputFileError),
        (["v 0 0 0", "v 1 0 0", "v 0 1 0", "vt 0 0", "f 1/1 2/1 3/2"], 5, InputFileError),
    ],
)
def test_obj_errors_name_file_and_line(tmp_path: Path, lines: list[str], bad_line: int, error: type) -> None:
    path = tmp_path / "bad.obj"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(error, match=rf"bad\.obj:{bad_line}:"):
        read_obj(path)


def test_obj_missing_file_and_no_faces(tmp_path: Path) -> None:
    with pytest.raises(InputFileError, match="does not exist"):
        read_obj(tmp_path / "nope.obj")
    (tmp_path / "pts.obj").write_text("v 0 0 0\nv 1 0 0\n")
    with pytest.raises(MeshError, match="no faces"):
        read_obj(tmp_path / "pts.obj")


def _cube_atlas_obj() -> str:
    """Unit cube; each of the 6 quads has its own square of the uv atlas (UV seams everywhere)."""
    corners = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    lines = [f"v {x} {y} {z}" for x, y, z in corners]
    square = [(0, 0), (1, 0), (1, 1), (0, 1)]
    for k in range(6):
        lines += [f"vt {(k + su) / 6:.6f} {sv}" for su, sv in square]
    for k, q in enumerate(quads):
        lines.append("f " + " ".join(f"{v + 1}/{4 * k + i + 1}" for i, v in enumerate(q)))
    return "\n".join(lines) + "\n"


def test_split_by_uv_cube_with_seams(tmp_path: Path) -> None:
    path = tmp_path / "cube.obj"
    path.write_text(_cube_atlas_obj())
    obj = read_obj(path)
    assert obj.faces.shape == (12, 3) and obj.vertices.shape == (8, 3)
    assert obj.uv is None  # every corner of the cube has 3 different uvs
    verts, faces, uv, source = split_by_uv(obj, return_index=True)
    assert verts.shape == (24, 3) and uv.shape == (24, 2) and faces.shape == (12, 3)
    # Geometry per corner is unchanged, and each corner keeps the uv the file gave it.
    np.testing.assert_allclose(verts[faces], obj.vertices[obj.faces])
    np.testing.assert_allclose(uv[faces], obj.uv_coords[obj.face_uv])
    np.testing.assert_allclose(verts, obj.vertices[source])
    assert np.bincount(source, minlength=8).tolist() == [3] * 8


def test_split_by_uv_merges_equal_uv_values(tmp_path: Path) -> None:
    # Two triangles sharing an edge, with duplicated but equal vt records: no split needed.
    path = tmp_path / "dup.obj"
    path.write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0 0\nvt 1 1\n"
        "f 1/1 2/2 3/3\nf 1/5 3/6 4/4\n"
    )
    obj = read_obj(path)
    np.testing.assert_allclose(obj.uv, [[0, 0], [1, 0], [1, 1], [0, 1]])
    verts, faces, uv = split_by_uv(obj)
    assert len(verts) == 4
    np.testing.assert_allclose(uv[faces], obj.uv_coords[obj.face_uv])


def test_split_by_uv_requires_uv(tmp_path: Path) -> None:
    verts, faces, _ = _grid(3)
    write_obj(tmp_path / "g.obj", verts, faces)
    with pytest.raises(MeshError, match="texture"):
        split_by_uv(read_obj(tmp_path / "g.obj"))


def test_write_obj_rejects_bad_mesh_and_leaves_no_file(tmp_path: Path) -> None:
    verts, faces, _ = _grid(3)
    bad = verts.copy()
    bad[2, 1] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        write_obj(tmp_path / "x.obj", bad, faces)
    with pytest.raises(MeshError, match="face indices"):
        write_obj(tmp_path / "x.obj", verts, faces + 100)
    with pytest.raises(MeshError, match="uv"):
        write_obj(tmp_path / "x.obj", verts, faces, uv=np.zeros((2, 2)))
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------------------- atomic


def test_atomic_write_failure_keeps_previous_content(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("previous")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_write(target) as fh:
            fh.write("half of the new cont")
            raise RuntimeError("boom")
    assert target.read_text() == "previous"
    assert _leftovers(tmp_path, {"out.txt"}) == []


def test_atomic_write_failure_creates_nothing_and_success_replaces(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "new.bin"
    with pytest.raises(KeyboardInterrupt):
        with atomic_write(target, "wb") as fh:
            fh.write(b"\x00\x01")
            raise KeyboardInterrupt
    assert not target.exists() and os.listdir(tmp_path / "sub") == []
    with atomic_write(target, "wb") as fh:
        fh.write(b"\x00\x01\x02")
    assert target.read_bytes() == b"\x00\x01\x02"
    with atomic_write(target, "wb") as fh:
        fh.write(b"\x07")
    assert target.read_bytes() == b"\x07"
    assert _leftovers(tmp_path / "sub", {"new.bin"}) == []
    umask = os.umask(0)
    os.umask(umask)
    assert (target.stat().st_mode & 0o777) == (0o666 & ~umask)


def test_atomic_output_dir(tmp_path: Path) -> None:
    out = tmp_path / "run"
    with atomic_output_dir(out) as tmp:
        assert tmp != out and not out.exists()
        (tmp / "a.txt").write_text("1")
    assert (out / "a.txt").read_text() == "1"

    with pytest.raises(ValueError):
        with atomic_output_dir(out) as tmp:
            (tmp / "b.txt").write_text("partial")
            raise ValueError("simulation diverged")
    assert sorted(os.listdir(out)) == [OWNER_MARKER, "a.txt"]  # the old complete output is untouched
    assert _leftovers(tmp_path, {"run"}) == []

    with atomic_output_dir(out) as tmp:
        (tmp / "c.txt").write_text("3")
    assert sorted(os.listdir(out)) == [OWNER_MARKER, "c.txt"]  # replaced as a whole on success
    assert _leftovers(tmp_path, {"run"}) == []


def test_atomic_output_dir_refuses_file(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputFileError, match="is a file"):
        with atomic_output_dir(tmp_path / "f"):
            pass


# ----------------------------------------------------------------------------- frames


def test_frames_npz_round_trip(tmp_path: Path) -> None:
    verts, faces, uv = _grid(4)
    rng = np.random.default_rng(0)
    positions = verts[None] + 0.01 * rng.standard_normal((6, len(verts), 3))
    times = np.arange(6) / 30.0
    energy = rng.random(6)
    path = save_frames_npz(tmp_path / "seq.npz", positions, faces, uv=uv, times=times, energy=energy)
    data = load_frames_npz(path)
    assert set(data) == {"positions", "faces", "uv", "times", "energy"}
    np.testing.assert_array_equal(data["positions"], positions)
    np.testing.assert_array_equal(data["faces"], faces)
    np.testing.assert_array_equal(data["uv"], uv)
    np.testing.assert_array_equal(data["times"], times)
    np.testing.assert_array_equal(data["energy"], energy)


def test_frames_npz_errors(tmp_path: Path) -> None:
    verts, faces, _ = _grid(3)
    with pytest.raises(MeshError, match="times"):
        save_frames_npz(tmp_path / "a.npz", verts[None].repeat(3, 0), faces, times=[0.0, 1.0])
    bad = verts[None].repeat(3, 0)
    bad[1, 0, 0] = np.inf
    with pytest.raises(MeshError, match="frame 1"):
        save_frames_npz(tmp_path / "a.npz", bad, faces)
    with pytest.raises(MeshError, match=r"\[T, N, 3\]"):
        save_frames_npz(tmp_path / "a.npz", verts, faces)
    assert os.listdir(tmp_path) == []
    with pytest.raises(InputFileError, match="does not exist"):
        load_frames_npz(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(InputFileError, match="positions"):
        load_frames_npz(tmp_path / "other.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputFileError, match="not a readable"):
        load_frames_npz(tmp_path / "junk.npz")


def test_write_obj_sequence(tmp_path: Path) -> None:
    verts, faces, uv = _grid(3)
    positions = np.stack([verts + [0, 0, 0.1 * t] for t in range(3)])
    paths = write_obj_sequence(tmp_path / "objs", positions, faces, uv=uv)
    assert [p.name for p in paths] == ["frame_0000.obj", "frame_0001.obj", "frame_0002.obj"]
    assert sorted(os.listdir(tmp_path / "objs")) == [p.name for p in paths]
    frame2 = read_obj(paths[2])
    np.testing.assert_allclose(frame2.vertices, positions[2], atol=1e-9)
    np.testing.assert_allclose(frame2.uv, uv, atol=1e-9)
    other = write_obj_sequence(tmp_path / "objs", positions[:1], faces, prefix="cloth_")
    assert [p.name for p in other] == ["cloth_0000.obj"]


# ----------------------------------------------------------------------------- PLY / GLB


def test_ply_round_trip_with_colors(tmp_path: Path) -> None:
    verts, faces, _ = _grid(4)
    colors = np.random.default_rng(1).random((len(verts), 3))
    path = write_ply(tmp_path / "g.ply", verts, faces, vertex_colors=colors)
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    mesh = trimesh.load(path, process=False)
    np.testing.assert_allclose(mesh.vertices, verts, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, faces)
    np.testing.assert_array_equal(mesh.visual.vertex_colors[:, :3], np.rint(colors * 255).astype(np.uint8))


def test_ply_without_colors_size(tmp_path: Path) -> None:
    verts, faces, _ = _grid(4)
    path = write_ply(tmp_path / "g.ply", verts, faces)
    header_end = path.read_bytes().index(b"end_header\n") + len(b"end_header\n")
    assert path.stat().st_size - header_end == len(verts) * 12 + len(faces) * 13


def test_glb_scene_loads_back(tmp_path: Path) -> None:
    body = trimesh.creation.icosphere(subdivisions=2)
    body.vertices[:, 2] *= 3.0  # tall along Z
    verts, faces, _ = _grid(5)
    colors = np.random.default_rng(2).random((len(verts), 4))
    items = [(body.vertices, body.faces, (0.8, 0.6, 0.5), "body"), (verts, faces, colors, "shirt")]
    path = write_glb(tmp_path / "scene.glb", items)
    scene = trimesh.load(path, process=False)
    assert isinstance(scene, trimesh.Scene)
    assert sorted(scene.geometry) == ["body", "shirt"]
    assert len(scene.geometry["body"].vertices) == len(body.vertices)
    assert len(scene.geometry["shirt"].vertices) == len(verts)
    assert len(scene.geometry["shirt"].faces) == len(faces)
    np.testing.assert_allclose(scene.geometry["body"].visual.material.baseColorFactor[:3], [204, 153, 128], atol=1)
    # Z-up content appears Y-up in the glTF scene: the tall axis of the body becomes Y.
    placed = scene.dump(concatenate=False)
    body_world = next(m for m in placed if len(m.vertices) == len(body.vertices))
    extent = body_world.bounds[1] - body_world.bounds[0]
    assert extent[1] == pytest.approx(6.0, rel=1e-6) and extent[2] == pytest.approx(2.0, rel=1e-6)


def test_glb_rejects_bad_input(tmp_path: Path) -> None:
    verts, faces, _ = _grid(3)
    with pytest.raises(MeshError, match="no meshes"):
        write_glb(tmp_path / "e.glb", [])
    with pytest.raises(MeshError, match="colour"):
        write_glb(tmp_path / "e.glb", [(verts, faces, np.zeros((2, 3)), "x")])
    assert os.listdir(tmp_path) == []


def test_read_npz_some_keys(tmp_path: Path) -> None:
    from tryon.io.npz import read_npz

    path = tmp_path / "a.npz"
    np.savez_compressed(path, unit=np.arange(3), x=np.ones((3, 4)))
    got = read_npz(path, "dataset shard", keys=("unit",))
    assert list(got) == ["unit"] and got["unit"].tolist() == [0, 1, 2]
    assert sorted(read_npz(path, "dataset shard")) == ["unit", "x"]
    with pytest.raises(InputFileError, match="dataset shard .*a.npz has no 'split'"):
        read_npz(path, "dataset shard", keys=("unit", "split"))
