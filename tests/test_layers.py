"""The package's layers (docs/architecture.md, docs/design.md section 2): every import, function-local ones included,
points to the same layer or one below. Read with `ast`, so an import inside a function counts as much as
one at the top of a module; a test plants an upward import to show the check bites."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "samp"

# Bottom to top. Modules of one layer may import each other; nothing imports a layer above its own.
LAYERS = [
    {"names", "paths", "config_overlay", "yaml_files", "meshes", "cli", "provenance", "device", "integrity", "console", "remote", "tracking", "tracking_faults", "__init__"},  # base modules, no samp imports of their own but these
    {"robot", "scene"},
    {"sim", "viz"},
    {"expert", "data", "perception"},
    {"robot_sdf"},
    {"policy"},
    {"eval"},
    {"runs"},
    {"train"},
]
RANK = {unit: rank for rank, layer in enumerate(LAYERS) for unit in layer}


def unit_of(module: str) -> str | None:
    """'samp.eval.report' -> 'eval', 'samp.names' -> 'names', 'samp' -> '__init__'; None outside samp."""
    parts = module.split(".")
    if parts[0] != "samp":
        return None
    return parts[1] if len(parts) > 1 else "__init__"


def module_name(path: Path, root: Path) -> str:
    rel = path.relative_to(root.parent).with_suffix("")
    parts = list(rel.parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path, root: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every import in the file, anywhere in it."""
    name = module_name(path, root)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            # `from samp import eval` imports the subpackage, `from samp import __version__` the package itself
            targets = [f"samp.{a.name}" if (root / a.name).is_dir() or (root / f"{a.name}.py").is_file() else "samp"
                       for a in node.names] if module == "samp" else [module]
            out += [(node.lineno, t) for t in targets]
    return out


def upward_imports(root: Path = PACKAGE) -> list[str]:
    """'file:line imports X (layer a above b)' for each import that points up; also any unit not in LAYERS."""
    problems = []
    for path in sorted(root.rglob("*.py")):
        me = unit_of(module_name(path, root))
        if me not in RANK:
            problems.append(f"{path.relative_to(root.parent)}: subpackage {me!r} has no layer; add it to LAYERS")
            continue
        for line, target in imports(path, root):
            other = unit_of(target)
            if other is None or other == me:
                continue
            if other not in RANK:
                problems.append(f"{path.relative_to(root.parent)}:{line} imports {target}, which has no layer")
            elif RANK[other] > RANK[me]:
                problems.append(f"{path.relative_to(root.parent)}:{line} imports {target} "
                                f"({other!r}, layer {RANK[other]}, is above {me!r}, layer {RANK[me]})")
    return problems


def test_no_module_imports_a_layer_above_its_own():
    problems = upward_imports()
    assert not problems, "upward imports:\n" + "\n".join(problems)


def test_a_planted_upward_import_is_named(tmp_path):
    import shutil

    copy = tmp_path / "samp"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    target = copy / "robot" / "config.py"
    target.write_text(target.read_text() + "\n\ndef _planted():\n    from samp.eval.report import grid_source\n")
    problems = upward_imports(copy)
    assert len(problems) == 1 and "robot/config.py" in problems[0] and "samp.eval.report" in problems[0], problems
    (copy / "policy" / "planted.py").write_text("from ..train import recipe\n")  # relative imports count too
    assert any("policy/planted.py:1 imports samp.train" in p for p in upward_imports(copy))


def test_the_subpackage_graph_has_no_cycle():
    """Stronger than the layer order: no two subpackages import each other, even within one layer."""
    edges: dict[str, set[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        me = unit_of(module_name(path, PACKAGE))
        edges.setdefault(me, set()).update(u for _, t in imports(path, PACKAGE)
                                           if (u := unit_of(t)) not in (None, me))
    mutual = sorted(f"{a} <-> {b}" for a in edges for b in edges[a] if a < b and a in edges.get(b, ()))
    assert not mutual, f"import cycles between subpackages: {mutual}"


@pytest.mark.parametrize("unit", sorted(RANK))
def test_every_layer_unit_exists(unit):
    assert (PACKAGE / unit).is_dir() or (PACKAGE / f"{unit}.py").is_file(), f"LAYERS names {unit!r}, which is gone"
