"""Tests for tryon.fabric: Wang 2011 data as ARCSim applies it, the isotropic model, presets, files.

The reference implementations below follow FORMAT.md (and ARCSim's dde.cpp) one sample at
a time in plain Python / numpy, independently of the vectorised torch / numba code.
"""

from __future__ import annotations

import json
import math
import os
import random
from pathlib import Path

import numpy as np
import pytest
import torch

from tryon.errors import FabricError, TryonError
from tryon.fabric import (
    MEASURED_FABRICS,
    Fabric,
    IsotropicFabric,
    WangFabric,
    list_presets,
    load_fabric,
    mean_preset_fabric,
    preset_summaries,
    save_fabric,
)
from tryon.fabric.wang2011 import (
    DATA_DIR,
    _interpolate,
    grid_strains,
    lookup_stretching_table,
    scatter_to_table,
    trilinear_corners,
)

F64 = torch.float64
LAMBDA_SAT = 7.0 / 6.0

GRAY_ROW0 = [16.593832, -14.695990, 34.477123, 36.860302]
GRAY_BEND = [
    [23.191698e-6, 32.932217e-6, 34.406498e-6, 39.014420e-6, 23.382786e-6],
    [24.749964e-6, 18.651314e-6, 16.370552e-6, 25.095791e-6, 8.860165e-6],
    [14.267624e-6, 7.052906e-6, 14.515154e-6, 24.665127e-6, 19.383726e-6],
]


# --------------------------------------------------------------------------- references


def raw_data(name: str) -> dict:
    """The preset file, with full-line // comments dropped (independent of the package parser)."""
    lines = (DATA_DIR / f"{name}.json").read_text().splitlines()
    return json.loads("\n".join(line for line in lines if not line.strip().startswith("//")))


def ref_formula(G, rows) -> list[float]:
    """FORMAT.md stretching steps 1-4 for one strain, eigenvectors from numpy's eigh."""
    guu, gvv, guv = (float(x) for x in G)
    C = np.array([[1 + 2 * guu, 2 * guv], [2 * guv, 1 + 2 * gvv]])
    if guv == 0.0:  # ARCSim's branch: axis-aligned, u wins ties
        lam_max = max(C[0, 0], C[1, 1])
        v = (1.0, 0.0) if C[0, 0] >= C[1, 1] else (0.0, 1.0)
    else:
        vals, vecs = np.linalg.eigh(C)
        lam_max = vals[1]
        v = vecs[:, 1] if vecs[0, 1] >= 0 else -vecs[:, 1]  # ARCSim's vector has v0 = l1 - C_vv >= 0
    theta = float(np.arctan2(np.float32(v[1]), np.float32(v[0])))  # atan2f
    a = float(np.float32(abs(theta / math.pi)) * np.float32(8.0))
    a = min(max(a, 0.0), 4 - 1e-6)
    s = min(max(6.0 * (math.sqrt(lam_max) - 1.0), 0.0), 1 - 1e-6)
    r = int(a)
    t = a - r
    c = [(1 - s) * rows[0][m] + s * ((1 - t) * rows[1 + r][m] + t * rows[2 + r][m]) for m in range(4)]
    return [2.0 * max(x, 0.0) for x in c]


def ref_lookup(G, rows) -> list[float]:
    """ARCSim's trilinear lookup of the 30^3 grid, each corner evaluated with `ref_formula`."""
    n = 30

    def axis(x):
        x = min(max(x, 0.0), n - 1 - 1e-5)
        i = min(max(math.floor(x), 0), n - 2)
        return i, x - i

    ai, a = axis((float(G[0]) + 0.25) * n)
    bi, b = axis((float(G[1]) + 0.25) * n)
    ci, c = axis(float(np.float32(abs(np.float32(G[2]))) * np.float32(n)))
    k = [0.0] * 4
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                w = (a if di else 1 - a) * (b if dj else 1 - b) * (c if dk else 1 - c)
                node = (-0.25 + (ai + di) / 30.0, -0.25 + (bi + dj) / 30.0, (ci + dk) / 30.0)
                val = ref_formula(node, rows)
                k = [k[m] + w * val[m] for m in range(4)]
    return k


def ref_bending(alpha: float, d, rows) -> float:
    """FORMAT.md bending lookup for one edge."""
    beta = abs(math.degrees(math.atan2(d[1], d[0]))) / 45.0
    if beta > 4:
        beta = 8 - beta
    if beta > 2:
        beta = 4 - beta
    r = min(int(beta), 1)
    tb = beta - r
    x = min(alpha / 5.0, 4.0)
    j = min(max(int(x), 0), 3)  # C truncation toward zero
    tc = x - j
    row = [(1 - tb) * rows[r][c] + tb * rows[r + 1][c] for c in range(5)]
    return max((1 - tc) * row[j] + tc * row[j + 1], 0.0)


def stretch_along(direction_deg: float, lam: float) -> torch.Tensor:
    """Green strain of a uniaxial stretch lam along the given material direction."""
    n = np.array([math.cos(math.radians(direction_deg)), math.sin(math.radians(direction_deg))])
    G = 0.5 * (lam**2 - 1) * np.outer(n, n)
    return torch.tensor([G[0, 0], G[1, 1], G[0, 1]], dtype=F64)


@pytest.fixture(scope="module")
def gray() -> WangFabric:
    return WangFabric.from_preset("gray-interlock")


# --------------------------------------------------------------------------- presets and files


def test_all_presets_load_and_summarise():
    names = list_presets()
    assert len(names) == 12 and names[-2:] == ["paper", "aluminium"]
    assert tuple(names[:10]) == MEASURED_FABRICS
    for name in names:
        fabric = load_fabric(name)
        assert isinstance(fabric, WangFabric) and isinstance(fabric, Fabric)
        raw = raw_data(name)
        assert float(fabric.density) == raw["density"]
        assert fabric.parameters().shape == (40,)
        assert torch.equal(fabric.stretching_data, torch.tensor(raw["stretching"], dtype=F64))
        assert torch.equal(fabric.bending_data, torch.tensor(raw["bending"], dtype=F64))
    summaries = preset_summaries()
    json.dumps(summaries)
    assert [s["name"] for s in summaries] == names
    gray = summaries[names.index("gray-interlock")]
    assert gray["composition"] == "60% cotton / 40% polyester, t-shirt"
    assert gray["stretch_N_m"]["warp_u"] == pytest.approx(2 * 16.593832)
    assert gray["stretch_N_m"]["coupling"] == 0.0
    assert gray["stretch_N_m_at_16pct"]["weft_v"] == pytest.approx(2 * 405.872833, rel=1e-5)
    assert gray["bending_N_m"]["edge_along_v"] == pytest.approx(14.267624e-6)
    assert summaries[names.index("paper")]["composition"] == "ARCSim demo material, isotropic (not measured)"


def test_compositions_match_arcsim_readme():
    text = (DATA_DIR / "ARCSIM_MATERIALS_README.txt").read_text()
    seen = 0
    for line in text.splitlines():
        if ":" not in line or "%" not in line:
            continue
        name, rest = line.split(":", 1)
        garment, *fibres = rest.split()
        composition = WangFabric.from_preset(name.strip()).composition
        assert composition.endswith(", " + garment)
        assert " ".join(fibres) == composition.rsplit(",", 1)[0].replace(" /", "")
        seen += 1
    assert seen == 10
    assert (DATA_DIR / "NOTICE.txt").read_text().count("Wang") >= 2


def test_comment_files_parse(tmp_path):
    paper, aluminium = load_fabric("paper"), load_fabric("aluminium")
    assert float(paper.density) == 0.1 and float(aluminium.density) == 0.071
    assert float(paper.bending_data[1, 3]) == 0.4e-3
    assert float(aluminium.stretching_data[5, 0]) == 1.8e6
    # Trailing and block comments, and a '//' inside a string, are handled like jsoncpp.
    data = raw_data("gray-interlock")
    body = json.dumps(data, indent=1).replace('"density"', '/* areal */ "density"')
    body = body.replace("{", '{ "name": "my//fabric", // trailing comment\n', 1)
    path = tmp_path / "commented.json"
    path.write_text("// header\n" + body)
    fabric = load_fabric(path)
    assert fabric.name == "my//fabric"
    assert torch.equal(fabric.parameters(), load_fabric("gray-interlock").parameters())


def test_unknown_preset_names_valid_presets():
    with pytest.raises(FabricError) as info:
        load_fabric("grey-interlock")
    message = str(info.value)
    assert "grey-interlock" in message
    for name in list_presets():
        assert name in message
    with pytest.raises(FabricError, match="gray-interlock"):
        WangFabric.from_preset("denim")
    with pytest.raises(FabricError, match="valid presets"):
        load_fabric({"preset": "silk"})


@pytest.mark.parametrize(
    "content, pattern",
    [
        ("{ not json", "not valid JSON"),
        ('{"density": 0.1, "stretching": [[1,2,3,4]]}', "missing bending"),
        ('{"density": 0.1, "stretching": [[1,2,3,4]], "bending": [[1,2,3,4,5],[1,2,3,4,5],[1,2,3,4,5]]}', "6 rows"),
        ('{"density": 0.1, "stretching": [[1,2,3]]}', "missing bending"),
        ('{"density": "heavy", "stretching": [], "bending": []}', "density must be a number"),
        ('{"density": -0.1, "stretching": %s, "bending": %s}', "density must be > 0"),
        ('{"density": NaN, "stretching": %s, "bending": %s}', "NaN"),
        ('{"density": 0.1, "stretching": %s, "bending": %s, "type": "silk"}', "unknown fabric type"),
        ("[1, 2, 3]", "JSON object"),
    ],
)
def test_malformed_files_raise(tmp_path, content, pattern):
    if "%s" in content:
        content = content % (json.dumps([[1, 2, 3, 4]] * 6), json.dumps([[1, 2, 3, 4, 5]] * 3))
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(FabricError, match=pattern):
        load_fabric(path)
    with pytest.raises(TryonError):
        load_fabric(str(path))


def test_bad_specs_raise(tmp_path):
    with pytest.raises(FabricError, match="does not exist"):
        load_fabric(tmp_path / "missing.json")
    with pytest.raises(FabricError, match="unknown keys"):
        load_fabric({"preset": "gray-interlock", "thickness": 2})
    with pytest.raises(FabricError, match="thicken"):
        load_fabric({"preset": "gray-interlock", "thicken": 0})
    with pytest.raises(FabricError, match="stretching_mult"):
        WangFabric.from_preset("gray-interlock", stretching_mult=float("nan"))
    with pytest.raises(FabricError):
        load_fabric(42)
    with pytest.raises(FabricError, match="shape"):
        WangFabric(0.1, torch.ones(5, 4), torch.ones(3, 5))


def test_save_load_round_trip(tmp_path):
    wang = WangFabric.from_preset("camel-ponte-roma", thicken=2.0, bending_mult=0.3)
    path = tmp_path / "out" / "camel.json"
    save_fabric(wang, path)
    saved = json.loads(path.read_text())
    assert saved["density"] == float(wang.density)
    assert np.array(saved["stretching"]).shape == (6, 4) and np.array(saved["bending"]).shape == (3, 5)
    loaded = load_fabric(path)
    assert isinstance(loaded, WangFabric) and loaded.name == "camel-ponte-roma"
    assert loaded.composition == wang.composition
    assert torch.equal(loaded.parameters(), wang.parameters())
    iso = IsotropicFabric(2e6, 0.3, 5e-4, 1e-5, 0.2, name="felt", composition="wool felt")
    iso_path = tmp_path / "felt.json"
    save_fabric(iso, iso_path)
    assert json.loads(iso_path.read_text())["type"] == "isotropic"
    again = load_fabric(str(iso_path))
    assert isinstance(again, IsotropicFabric) and again.name == "felt" and again.composition == "wool felt"
    assert torch.allclose(again.parameters(), iso.parameters(), rtol=1e-15, atol=0)
    assert sorted(os.listdir(tmp_path)) == ["felt.json", "out"]
    assert os.listdir(tmp_path / "out") == ["camel.json"]
    # Multipliers on a file, and the dict forms.
    twice = load_fabric({"file": str(path), "thicken": 2})
    assert torch.allclose(twice.parameters(), 2 * wang.parameters(), rtol=1e-15)
    inline = load_fabric({"density": 0.2, "stretching": saved["stretching"], "bending": saved["bending"]})
    assert torch.equal(inline.parameters()[1:], wang.parameters()[1:])
    assert load_fabric(iso) is iso


def test_mean_preset_fabric():
    mean = mean_preset_fabric()
    stack = torch.stack([WangFabric.from_preset(name).parameters() for name in MEASURED_FABRICS])
    assert torch.allclose(mean.parameters(), stack.mean(0), rtol=1e-15, atol=0)
    densities = [raw_data(name)["density"] for name in MEASURED_FABRICS]
    assert float(mean.density) == pytest.approx(sum(densities) / 10, rel=1e-14)
    assert mean.name == "wang2011-mean"
    json.dumps(mean.summary())


# --------------------------------------------------------------------------- stretching


def test_zero_strain_gives_twice_row0_clamped(gray):
    k = gray.stretching_stiffness_exact(torch.zeros(3, dtype=F64))
    expected = torch.tensor([2 * max(x, 0.0) for x in GRAY_ROW0], dtype=F64)
    assert torch.equal(k, expected)
    assert k[1] == 0.0 and k[3] == pytest.approx(2 * 36.860302)
    # The simulator sees the trilinear interpolant, which at G = 0 blends in strained nodes.
    lookup = gray.stretching_stiffness(torch.zeros(3, dtype=F64))
    reference = ref_lookup((0, 0, 0), raw_data("gray-interlock")["stretching"])
    assert torch.allclose(lookup, torch.tensor(reference, dtype=F64))
    assert lookup[0] > k[0]


@pytest.mark.parametrize("name", ["gray-interlock", "navy-sparkle-sweat", "11oz-black-denim", "tango-red-jet-set"])
def test_table_matches_reference_at_grid_nodes(name):
    fabric = WangFabric.from_preset(name)
    rows = raw_data(name)["stretching"]
    table = fabric.stretching_table()
    strains = grid_strains()
    rng = random.Random(7)
    nodes = [(rng.randrange(30), rng.randrange(30), rng.randrange(30)) for _ in range(300)]
    nodes += [(i, i, 0) for i in range(30)]  # degenerate C = c I: angle 0 (u wins the tie)
    nodes += [(i, j, 0) for i in (0, 7, 8, 29) for j in (0, 7, 8, 29)] + [(8, 8, k) for k in range(30)]
    for i, j, k in nodes:
        G = strains[i, j, k]
        assert G.tolist() == pytest.approx([-0.25 + i / 30, -0.25 + j / 30, k / 30], abs=1e-15)
        expected = torch.tensor(ref_formula(G, rows), dtype=F64)
        assert torch.allclose(table[i, j, k], expected, rtol=1e-7, atol=2e-4), (i, j, k)
        # Looking up exactly at a node returns the node value, except on the upper faces where
        # ARCSim clamps the coordinate to 29 - 1e-5 and keeps a 1e-5 share of node 28.
        looked_up = fabric.stretching_stiffness(G)
        assert torch.allclose(looked_up, torch.tensor(ref_lookup(G, rows), dtype=F64), rtol=1e-7, atol=2e-4)
        if max(i, j, k) < 29:
            assert torch.allclose(looked_up, expected, rtol=1e-7, atol=2e-4), (i, j, k)


def test_lookup_matches_reference_off_grid_and_outside(gray):
    rows = raw_data("gray-interlock")["stretching"]
    gen = torch.Generator().manual_seed(3)
    G = torch.rand(200, 3, generator=gen, dtype=F64) * torch.tensor([1.4, 1.4, 2.4], dtype=F64) - torch.tensor(
        [0.45, 0.45, 1.2], dtype=F64
    )
    k = gray.stretching_stiffness(G)
    expected = torch.tensor([ref_lookup(g, rows) for g in G], dtype=F64)
    assert torch.allclose(k, expected, rtol=1e-7, atol=2e-4)
    # Compiled kernels and the vectorised torch path (used off the CPU) agree, forward and adjoint.
    table, _ = gray._cached_table(G.device)
    assert torch.allclose(lookup_stretching_table(table, G, compiled=False), k, rtol=1e-12, atol=1e-9)
    grad_k = torch.randn(200, 4, dtype=F64, generator=gen)
    assert torch.allclose(
        scatter_to_table(G, grad_k, 27000, compiled=True), scatter_to_table(G, grad_k, 27000, compiled=False)
    )
    # The adjoint satisfies <lookup(table), grad_k> = <table, scatter(grad_k)>.
    assert float((k * grad_k).sum()) == pytest.approx(float((table * scatter_to_table(G, grad_k, 27000)).sum()))
    # A NaN strain component gives NaN stiffness for that face only, on both code paths.
    bad = torch.tensor([[0.1, float("nan"), 0.0], [0.1, 0.0, float("nan")], [0.1, 0.0, 0.0]], dtype=F64)
    for compiled in (True, False):
        k_bad = lookup_stretching_table(table, bad, compiled=compiled)
        assert bool(k_bad[:2].isnan().all()) and bool(k_bad[2].isfinite().all())
    # Batch shapes are kept; a wrong last dimension is an error.
    assert gray.stretching_stiffness(G.reshape(4, 50, 3)).shape == (4, 50, 4)
    with pytest.raises(FabricError, match=r"\[..., 3\]"):
        gray.stretching_stiffness(torch.zeros(5, 2, dtype=F64))


def test_saturation_and_grid_clamping(gray):
    rows = raw_data("gray-interlock")["stretching"]
    # Formula: no extrapolation beyond lambda = 7/6 (s clamps to 1 - 1e-6).
    k_sat = gray.stretching_stiffness_exact(stretch_along(0.0, LAMBDA_SAT + 1e-3))
    for lam in (1.25, 1.5, 2.0):
        assert torch.equal(gray.stretching_stiffness_exact(stretch_along(0.0, lam)), k_sat)
    expected = torch.tensor([2 * max(x, 0.0) for x in rows[1]], dtype=F64)
    assert torch.allclose(k_sat, expected, rtol=1e-5)
    k_v = gray.stretching_stiffness_exact(stretch_along(90.0, 1.4))
    assert torch.allclose(k_v, torch.tensor([2 * max(x, 0.0) for x in rows[5]], dtype=F64), rtol=1e-5)
    # Compression uses row 0 only.
    k_c = gray.stretching_stiffness_exact(torch.tensor([-0.1, -0.05, 0.02], dtype=F64))
    assert torch.equal(k_c, gray.stretching_stiffness_exact(torch.zeros(3, dtype=F64)))
    # Table: strains beyond the grid take the boundary values; |G_uv| mirror symmetry.
    edge = torch.tensor([[-0.25 + 29 / 30 - 1e-9, 0.1, 0.2]], dtype=F64)
    far = torch.tensor([[0.9, 0.1, 0.2], [5.0, 0.1, 0.2]], dtype=F64)
    assert torch.allclose(gray.stretching_stiffness(far), gray.stretching_stiffness(edge).expand(2, 4), rtol=1e-6)
    low = gray.stretching_stiffness(torch.tensor([[-0.6, -0.9, 0.0], [-0.25, -0.25, 0.0]], dtype=F64))
    assert torch.equal(low[0], low[1])
    shear = gray.stretching_stiffness(torch.tensor([[0.1, 0.2, 1.5], [0.1, 0.2, 2.0], [0.1, 0.2, -1.5]], dtype=F64))
    assert torch.equal(shear[0], shear[1]) and torch.equal(shear[0], shear[2])


def test_stiff_v_axis(gray):
    along_v = gray.stretching_stiffness(stretch_along(90.0, LAMBDA_SAT))
    assert along_v[2] > 3.0 * along_v[0]
    along_u = gray.stretching_stiffness_exact(stretch_along(0.0, LAMBDA_SAT))
    assert along_u[2] > 5.0 * along_u[0]  # FORMAT.md: 261 against 46 (row 1)
    # Stretching along v is stiffer than along u (rows 5 vs 1).
    k_v, k_u = gray.stretching_stiffness(stretch_along(90.0, 1.2)), gray.stretching_stiffness(stretch_along(0.0, 1.2))
    assert k_v[2] > 5 * k_u[0]


def test_bias_angle_rows(gray):
    rows = raw_data("gray-interlock")["stretching"]
    for r, deg in enumerate((0.0, 22.5, 45.0, 67.5, 90.0)):
        k = gray.stretching_stiffness_exact(stretch_along(deg, 1.3))
        expected = torch.tensor([2 * max(x, 0.0) for x in rows[1 + r]], dtype=F64)
        assert torch.allclose(k, expected, rtol=1e-5, atol=1e-3), deg
    # Mirror symmetry about the u axis: -30 degrees behaves as +30 degrees.
    minus = gray.stretching_stiffness_exact(stretch_along(-30.0, 1.1))
    assert torch.allclose(minus, gray.stretching_stiffness_exact(stretch_along(30.0, 1.1)))


# --------------------------------------------------------------------------- bending


def bend(fabric, alphas, direction):
    alpha = torch.tensor(alphas, dtype=F64)
    dirs = torch.tensor([direction] * len(alphas), dtype=F64)
    return fabric.bending_stiffness(alpha, dirs)


def test_bending_rows_and_columns(gray):
    b = GRAY_BEND
    cases = [(0, (1.0, 0.0)), (1, (1.0, 1.0)), (2, (0.0, 1.0)), (0, (-2.0, 0.0)), (2, (0.0, -3.0)), (1, (-1.0, 1.0))]
    for row, direction in cases:
        ke = bend(gray, [0.0, 5.0, 10.0, 15.0, 20.0], direction)
        assert torch.allclose(ke, torch.tensor(b[row], dtype=F64), rtol=1e-6, atol=0), direction
    # Column interpolation and alpha > 20 saturation on row 0.
    ke = bend(gray, [2.5, 7.5, 17.5, 20.0, 25.0, 1000.0], (1.0, 0.0))
    expected = [
        0.5 * (b[0][0] + b[0][1]),
        0.5 * (b[0][1] + b[0][2]),
        0.5 * (b[0][3] + b[0][4]),
        b[0][4],
        b[0][4],
        b[0][4],
    ]
    assert torch.allclose(ke, torch.tensor(expected, dtype=F64), rtol=1e-12)
    # Direction interpolation at 22.5 degrees (beta = 0.5), alpha = 0.
    ke = bend(gray, [0.0], (math.cos(math.pi / 8), math.sin(math.pi / 8)))
    assert float(ke[0]) == pytest.approx(0.5 * (b[0][0] + b[1][0]), rel=1e-6)


def test_bending_negative_alpha_quirk(gray):
    b0, b1 = 23.191698e-6, 32.932217e-6  # row 0: b1 > b0, negative folds soften
    ke = bend(gray, [-2.5, -5.0, -10.0, -11.9, -12.0, -20.0, -100.0], (1.0, 0.0))
    hand = [b0 + (b0 - b1) * a / 5.0 for a in (2.5, 5.0, 10.0, 11.9, 12.0, 20.0, 100.0)]
    hand = [max(x, 0.0) for x in hand]
    assert torch.allclose(ke, torch.tensor(hand, dtype=F64), rtol=1e-12, atol=1e-20)
    assert float(ke[1]) == pytest.approx(13.451179e-6, rel=1e-7)
    assert float(ke[3]) > 0.0 and float(ke[4]) == 0.0  # zero crossing at |alpha| ~ 11.9
    # Row 2 has b1 < b0: negative folds get stiffer.
    ke_v = bend(gray, [-5.0], (0.0, 1.0))
    assert float(ke_v[0]) == pytest.approx(2 * 14.267624e-6 - 7.052906e-6, rel=1e-9)


def test_bending_matches_reference_random(gray):
    rng = np.random.default_rng(11)
    alpha = rng.uniform(-30, 40, 300)
    dirs = rng.normal(size=(300, 2))
    ke = gray.bending_stiffness(torch.tensor(alpha), torch.tensor(dirs))
    expected = [ref_bending(a, d, GRAY_BEND) for a, d in zip(alpha, dirs)]
    assert torch.allclose(ke, torch.tensor(expected, dtype=F64), rtol=1e-6, atol=1e-11)
    with pytest.raises(FabricError, match="edge_dir_uv"):
        gray.bending_stiffness(torch.zeros(3, dtype=F64), torch.zeros(3, 3, dtype=F64))


# --------------------------------------------------------------------------- multipliers


def test_multipliers(gray):
    G = torch.tensor([[0.05, 0.1, 0.03], [-0.1, 0.3, 0.2], [0.4, -0.02, 0.0]], dtype=F64)
    alpha = torch.tensor([1.0, -3.0, 30.0], dtype=F64)
    dirs = torch.tensor([[1.0, 0.2], [0.3, 1.0], [1.0, 1.0]], dtype=F64)
    base_k, base_ke = gray.stretching_stiffness(G), gray.bending_stiffness(alpha, dirs)
    thick = WangFabric.from_preset("gray-interlock", thicken=2.0)
    assert float(thick.density) == pytest.approx(2 * 0.187, rel=1e-15)
    assert torch.allclose(thick.stretching_stiffness(G), 2 * base_k, rtol=1e-14)
    assert torch.allclose(thick.bending_stiffness(alpha, dirs), 2 * base_ke, rtol=1e-14)
    mults = {"density_mult": 3.0, "stretching_mult": 0.5, "bending_mult": 4.0, "thicken": 2.0}
    mixed = WangFabric.from_preset("gray-interlock", **mults)
    assert float(mixed.density) == pytest.approx(6 * 0.187, rel=1e-15)
    assert torch.allclose(mixed.stretching_stiffness(G), base_k, rtol=1e-14)
    assert torch.allclose(mixed.bending_stiffness(alpha, dirs), 8 * base_ke, rtol=1e-14)
    assert mixed.summary()["multipliers"] == mults
    via_dict = load_fabric({"preset": "gray-interlock", **mults})
    assert torch.equal(via_dict.parameters(), mixed.parameters())


# --------------------------------------------------------------------------- isotropic


def test_isotropic_energy_is_stvk():
    E, nu, h = 3.0e6, 0.32, 4.0e-4
    fabric = IsotropicFabric(E, nu, h, 2e-5, 0.15)
    G = torch.randn(50, 3, dtype=F64, generator=torch.Generator().manual_seed(1)) * 0.1
    k = fabric.stretching_stiffness(G)
    guu, gvv, guv = G.unbind(-1)
    energy = 0.5 * (k[:, 0] * guu**2 + 2 * k[:, 1] * guu * gvv + k[:, 2] * gvv**2 + 2 * k[:, 3] * guv**2)
    lam = E * h * nu / (1 - nu**2)
    mu = E * h / (2 * (1 + nu))
    GG = guu**2 + gvv**2 + 2 * guv**2
    assert torch.allclose(energy, mu * GG + 0.5 * lam * (guu + gvv) ** 2, rtol=1e-13)
    # Plane-stress uniaxial check: the stress-free transverse strain is -nu times the axial one (small strain).
    assert float(-k[0, 1] / k[0, 2]) == pytest.approx(-nu, rel=1e-12)
    ke = fabric.bending_stiffness(torch.tensor([-3.0, 0.0, 50.0], dtype=F64), torch.ones(3, 2, dtype=F64))
    assert torch.equal(ke, torch.full((3,), 2e-5, dtype=F64))
    summary = fabric.summary()
    json.dumps(summary)
    assert summary["stretch_N_m"]["shear"] == pytest.approx(2 * mu) and summary["youngs_modulus_pa"] == pytest.approx(E)


@pytest.mark.parametrize(
    "kwargs, pattern",
    [
        ({"youngs_modulus_pa": 0.0}, "youngs_modulus_pa"),
        ({"poisson_ratio": 0.5}, "poisson_ratio"),
        ({"poisson_ratio": -0.1}, "poisson_ratio"),
        ({"thickness_m": 0.0}, "thickness_m"),
        ({"bending_stiffness_nm": -1e-6}, "bending_stiffness_nm"),
        ({"density_kg_m2": 0.0}, "density_kg_m2"),
        ({"density_kg_m2": float("nan")}, "finite"),
    ],
)
def test_isotropic_validation(kwargs, pattern):
    args = {
        "youngs_modulus_pa": 1e6,
        "poisson_ratio": 0.3,
        "thickness_m": 1e-3,
        "bending_stiffness_nm": 1e-5,
        "density_kg_m2": 0.2,
    }
    args.update(kwargs)
    with pytest.raises(FabricError, match=pattern):
        IsotropicFabric(**args)
    with pytest.raises(FabricError, match="missing"):
        load_fabric({"type": "isotropic", "youngs_modulus_pa": 1e6})


# --------------------------------------------------------------------------- parameters and gradients


def test_parameters_round_trip(gray):
    p = gray.parameters()
    assert p.dtype == F64 and p.shape == (40,)
    assert float(p[0]) == 0.187 and float(p[1]) == 16.593832 and float(p[1 + 4 * 4 + 3]) == -174.43853
    assert float(p[25 + 5 * 2]) == 14.267624e-6
    clone = gray.with_parameters(p.clone())
    assert torch.equal(clone.parameters(), p) and clone.name == gray.name
    G = torch.tensor([[0.02, 0.15, 0.07]], dtype=F64)
    assert torch.equal(clone.stretching_stiffness(G), gray.stretching_stiffness(G))
    iso = IsotropicFabric(2e6, 0.25, 1e-3, 3e-5, 0.3)
    assert torch.allclose(iso.parameters(), torch.tensor([0.3, 2e3, 0.25, 3e-5], dtype=F64), rtol=1e-15)
    assert torch.equal(iso.with_parameters(iso.parameters()).parameters(), iso.parameters())
    with pytest.raises(FabricError, match="40 parameters"):
        gray.with_parameters(torch.zeros(39, dtype=F64))
    with pytest.raises(FabricError, match="density"):
        gray.with_parameters(torch.cat([torch.tensor([-1.0], dtype=F64), p[1:]]))


def _loss(fabric: Fabric, G, alpha, dirs, wk, wb) -> torch.Tensor:
    return (
        (wk * fabric.stretching_stiffness(G)).sum()
        + 1e5 * (wb * fabric.bending_stiffness(alpha, dirs)).sum()
        + 10.0 * fabric.density
    )


def test_gradients_match_finite_differences():
    base = WangFabric.from_preset("white-swim-solid")
    gen = torch.Generator().manual_seed(5)
    G = torch.rand(400, 3, generator=gen, dtype=F64) * 0.6 - 0.2
    wk = torch.rand(400, 4, generator=gen, dtype=F64)
    alpha = torch.rand(100, generator=gen, dtype=F64) * 50 - 15
    dirs = torch.randn(100, 2, generator=gen, dtype=F64)
    wb = torch.rand(100, generator=gen, dtype=F64)
    args = (G, alpha, dirs, wk, wb)
    p = base.parameters().clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(_loss(base.with_parameters(p), *args), p)
    assert bool((grad != 0).any()) and grad[0] == 10.0
    for index in (1, 4, 1 + 4 * 2 + 2, 1 + 4 * 5 + 3, 25, 25 + 5 * 1 + 3):
        h = 1e-6 * abs(float(p[index].detach()))
        plus, minus = p.detach().clone(), p.detach().clone()
        plus[index] += h
        minus[index] -= h
        fd = (_loss(base.with_parameters(plus), *args) - _loss(base.with_parameters(minus), *args)) / (2 * h)
        assert float(grad[index]) == pytest.approx(float(fd), rel=1e-6, abs=1e-9), index
    # The custom backward equals autograd through a freshly built table.
    fabric = base.with_parameters(p)
    table = fabric.stretching_table().reshape(-1, 4)
    idx, w = trilinear_corners(G)
    (auto,) = torch.autograd.grad((wk * _interpolate(table, idx, w)).sum(), p)
    (custom,) = torch.autograd.grad((wk * fabric.stretching_stiffness(G)).sum(), p)
    assert torch.allclose(custom, auto, rtol=1e-10, atol=1e-12)
    # One fabric object serves several independent backward passes.
    (again,) = torch.autograd.grad((wk * fabric.stretching_stiffness(G)).sum(), p)
    assert torch.equal(again, custom)


def test_cache_follows_in_place_parameter_updates():
    p = WangFabric.from_preset("gray-interlock").parameters().clone().requires_grad_(True)
    fabric = WangFabric.from_preset("gray-interlock").with_parameters(p)
    G = torch.tensor([[0.1, 0.05, 0.02]], dtype=F64)
    before = fabric.stretching_stiffness(G).detach()
    with torch.no_grad():
        p[1:25] *= 3.0  # e.g. an optimiser step on the leaf
    after = fabric.stretching_stiffness(G).detach()
    assert torch.allclose(after, 3.0 * before, rtol=1e-13)


def test_isotropic_gradient():
    iso = IsotropicFabric(2e6, 0.3, 1e-3, 3e-5, 0.3)
    p = iso.parameters().clone().requires_grad_(True)
    G = torch.rand(10, 3, dtype=F64)
    wk = torch.rand(10, 4, dtype=F64)
    alpha, dirs, wb = torch.zeros(4, dtype=F64), torch.ones(4, 2, dtype=F64), torch.ones(4, dtype=F64)
    args = (G, alpha, dirs, wk, wb)
    (grad,) = torch.autograd.grad(_loss(iso.with_parameters(p), *args), p)
    for index in (1, 2):
        h = 1e-6 * float(p[index].detach())
        plus, minus = p.detach().clone(), p.detach().clone()
        plus[index] += h
        minus[index] -= h
        fd = (_loss(iso.with_parameters(plus), *args) - _loss(iso.with_parameters(minus), *args)) / (2 * h)
        assert float(grad[index]) == pytest.approx(float(fd), rel=1e-6)
    assert float(grad[3]) == pytest.approx(4e5) and float(grad[0]) == 10.0


def test_data_dir_is_complete():
    files = sorted(path.name for path in Path(DATA_DIR).iterdir())
    assert [f"{name}.json" for name in sorted(list_presets())] == [f for f in files if f.endswith(".json")]
    assert "NOTICE.txt" in files and "ARCSIM_MATERIALS_README.txt" in files
