"""The package's layering (docs/ARCHITECTURE.md): the import-linter contract in
pyproject.toml, no import cycles (imports inside functions included), no private name
imported across packages, and time advancing only in the run loop."""

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import grimp
import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "tryon"


def _package(module: str) -> str:
    return ".".join(module.split(".")[:2])


def test_import_linter_contracts_hold():
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.fail("lint-imports is missing: install the test extra (pip install -e '.[test]')")
    r = subprocess.run([exe, "--config", str(SRC.parents[1] / "pyproject.toml")], capture_output=True, text=True,
                       cwd=SRC.parents[1])
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-1000:]


def _cycles(graph) -> list[list[str]]:
    """Strongly connected groups of modules (package __init__ re-exports left out)."""
    modules = sorted(graph.modules)
    packages = {m for m in modules if any(o.startswith(m + ".") for o in modules)}
    edges = {m: [w for w in graph.find_modules_directly_imported_by(m) if w not in packages] for m in modules}
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v: str) -> None:  # Tarjan
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for m in modules:
        if m not in packages and m not in index:
            visit(m)
    return found


def test_no_import_cycles():
    sys.setrecursionlimit(10000)
    assert _cycles(grimp.build_graph("tryon", cache_dir=None)) == []


def _imports(path: Path):
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("tryon"):
            yield node.module, [a.name for a in node.names], node.lineno


def test_no_private_name_is_imported_across_packages():
    bad = []
    for path in SRC.rglob("*.py"):
        here = _package(".".join(path.relative_to(SRC.parent).with_suffix("").parts))
        for module, names, line in _imports(path):
            if _package(module) != here:
                bad += [f"{path.relative_to(SRC.parent)}:{line} {module}.{n}" for n in names
                        if n.startswith("_") and not n.startswith("__")]
    assert bad == []


def test_time_advances_only_in_the_run_loop():
    """`solver.step(` appears only in the run loop and the solver itself (Newton's own
    solver in the optional comparison is another simulator)."""
    allowed = {"sim/loop.py", "sim/integrator.py", "bench/newton_ref.py"}
    bad = []
    for path in SRC.rglob("*.py"):
        rel = str(path.relative_to(SRC))
        if rel in allowed:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "step"
                    and len(node.args) >= 2):  # solver.step(state, dt), not an optimiser's step()
                bad.append(f"{rel}:{node.lineno}")
    assert bad == []


def _calls_steps(node: ast.AST) -> bool:
    return isinstance(node, ast.Call) and (
        (isinstance(node.func, ast.Name) and node.func.id in ("steps", "sim_steps"))
        or (isinstance(node.func, ast.Attribute) and node.func.attr == "steps"))


def test_no_hand_time_loops():
    """Runs use `run` (or `advance` for one step) with the loop's policies; iterating
    `steps(...)` by hand is left to the benches that time single steps and to the
    time-parallel segment, which hands control back between steps."""
    allowed = {"sim/loop.py", "bench/sim.py", "bench/robustness.py", "bench/parallel.py", "parallel/segment.py"}
    bad = []
    for path in SRC.rglob("*.py"):
        rel = str(path.relative_to(SRC))
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "next"
                    and node.args and _calls_steps(node.args[0]) and rel != "sim/loop.py"):
                bad.append(f"{rel}:{node.lineno} next(steps(...))")
            elif isinstance(node, (ast.For, ast.comprehension)) and _calls_steps(node.iter) and rel not in allowed:
                bad.append(f"{rel}:{node.iter.lineno} a loop over steps(...)")
    assert bad == []


def test_geometry_and_collision_are_used_by_their_public_names():
    """Outside `tryon.sim`, the geometry and the collision handling are imported from their
    packages (`from tryon.sim.geometry import push_outside`), never from their modules."""
    bad = []
    for path in SRC.rglob("*.py"):
        rel = path.relative_to(SRC)
        if rel.parts[0] == "sim":
            continue
        for module, _, line in _imports(path):
            if module.startswith(("tryon.sim.geometry.", "tryon.sim.collision.")):
                bad.append(f"{rel}:{line} {module}")
    assert bad == []
