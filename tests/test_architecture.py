"""The package's shape (docs/architecture.md): imports follow the data flow, no private helper is
imported across modules, modules stay small. Read from the source with ``ast``, nothing is run."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "kinredund"

#: the layers in data-flow order; a module may import only from its own layer or earlier ones
LAYERS = [
    ("errors", "io"),
    ("kinematics",),
    ("indices", "paths"),
    ("tasks",),
    ("model",),
    ("geometry",),
    ("trajectory", "problems", "export"),
    ("ik", "closed_form", "tracking", "planning", "retime", "sweep"),
    ("thesis",),
    ("ui",),
]
#: the largest module (lines): about 400, as docs/architecture.md says
MAX_LINES = 420


def _modules() -> dict[str, Path]:
    out = {}
    for f in sorted(PACKAGE.rglob("*.py")):
        parts = list(f.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def _layer(module: str) -> int | None:
    """The layer of ``kinredund.X...`` by its first component X (None for the package itself)."""
    parts = module.split(".")
    if len(parts) < 2:
        return None
    for i, names in enumerate(LAYERS):
        if parts[1] in names:
            return i
    raise AssertionError(f"{module} belongs to no layer: add it to LAYERS and docs/architecture.md")


def _imports(path: Path, module: str) -> list[tuple[str, list[str], int]]:
    """(imported kinredund module, imported names, line) for every import in the file, lazy ones too."""
    tree = ast.parse(path.read_text())
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_pkg else module.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] == "kinredund":
                out.append((target, [a.name for a in node.names], node.lineno))
        elif isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names if a.name.split(".")[0] == "kinredund"]
    return out


MODULES = _modules()


def _back_edges(path: Path, module: str) -> list[str]:
    """What is wrong with the imports of ``module`` (its source at ``path``) against the data flow."""
    own, out = _layer(module), []
    for source, names, line in _imports(path, module):
        subs = [f"{source}.{n}" for n in names if f"{source}.{n}" in MODULES]  # `from kinredund.pkg import module`
        for target in subs or [source]:
            # `from kinredund import x` with x not a module: the package's exports sit above every layer
            if target == "kinredund":
                out.append(f"{module}:{line} imports {names} from the package root")
            elif _layer(target) > own:
                out.append(f"{module}:{line} imports {target}, a later layer ({LAYERS[_layer(target)]} after "
                           f"{LAYERS[own]})")
    return out


@pytest.mark.parametrize("module", [m for m in MODULES if m != "kinredund"])
def test_imports_follow_the_data_flow(module):
    assert _back_edges(MODULES[module], module) == []  # _layer also refuses a package that has no layer


@pytest.mark.parametrize("module", list(MODULES))
def test_no_private_helper_is_imported_across_modules(module):
    for target, names, line in _imports(MODULES[module], module):
        private = [n for n in names if n.startswith("_") and f"{target}.{n}" not in MODULES]
        assert not private, f"{module}:{line} imports private {private} from {target}"


def test_the_layer_check_sees_a_back_edge(tmp_path):
    """The checker itself: a kinematics module importing the tracker (lazily) or the package root is reported,
    a tracking module importing the kinematics is not."""
    f = tmp_path / "bad.py"
    f.write_text("import kinredund\nfrom kinredund import track\n"
                 "def f():\n    from kinredund.tracking.tracker import Tracker\n")
    found = _back_edges(f, "kinredund.kinematics.bad")
    assert len(found) == 3 and all("package root" in f for f in found[:2]) and "tracking.tracker" in found[2]
    ok = tmp_path / "ok.py"
    ok.write_text("from kinredund.kinematics.state import Kinematics\n")
    assert _back_edges(ok, "kinredund.tracking.ok") == []



@pytest.mark.parametrize("module", list(MODULES))
def test_modules_stay_small(module):
    lines = MODULES[module].read_text().count("\n")
    assert lines <= MAX_LINES, f"{module} has {lines} lines (at most about 400: split it by concept)"
