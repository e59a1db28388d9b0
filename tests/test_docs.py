"""For the people who carry the code on: the API reference builds and its cross-references resolve, the
CHANGELOG's moves point at modules that exist, and the benchmarks' help cites no internal issue."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _build_api():
    spec = importlib.util.spec_from_file_location("build_api", ROOT / "docs" / "build_api.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_broken_reference_is_found(tmp_path, monkeypatch):
    """A docstring naming something that does not exist (a renamed function, a class of another module)
    is reported; names that exist, in full or relative to their module, are not."""
    (tmp_path / "probe_docs.py").write_text('''"""Probe: :func:`kinredund.sweep.sweep`, :func:`helper`,
:class:`~kinredund.ui.progress.Progress`."""


def helper():
    """Calls :func:`kinredund.sweep.no_such_function` and :class:`Progress` (not imported here), and
    :meth:`helper.nothing`; :func:`numpy.linalg.solve` is another library's."""
''')
    monkeypatch.syspath_prepend(str(tmp_path))
    broken = _build_api().broken_references(["probe_docs"])
    assert broken == ["probe_docs: Progress", "probe_docs: helper.nothing",
                      "probe_docs: kinredund.sweep.no_such_function"]
    sys.modules.pop("probe_docs", None)


@pytest.mark.slow  # ~20 s: pdoc renders 120 modules
def test_api_reference_builds_with_every_reference_resolved(tmp_path):
    api = _build_api()
    assert api.broken_references() == []
    out = api.build(tmp_path / "api")
    pages = {p.relative_to(out).with_suffix("").as_posix().replace("/", ".") for p in out.rglob("*.html")}
    missing = [m for m in api.public_modules() if m not in pages]
    assert not missing, f"no page for {missing}"
    sweep = (out / "kinredund" / "sweep" / "run.html").read_text()
    assert "placement" in sweep and 'id="sweep"' in sweep  # a function's docstring, with its anchor


def test_changelog_moves_point_at_modules_that_exist():
    text = (ROOT / "CHANGELOG.md").read_text()
    version = re.search(r'^version = "([^"]+)"', (ROOT / "pyproject.toml").read_text(), flags=re.M).group(1)
    assert f"## [{version}]" in text
    table = text.split("### Moved modules", 1)[1].split("###", 1)[0]
    rows = [line.split("|")[1:3] for line in table.splitlines() if line.startswith("| `")]
    assert len(rows) >= 20
    lookup = _build_api().lookup
    for before, now in rows:
        for name in re.findall(r"`(kinredund[\w.]*)`", now):
            lookup(name)  # a module or an object in one: LookupError if the changelog points at nothing
        moved_names = " in `" in before  # names moved out of a module that stays (cli.py's option helpers)
        for name in [] if moved_names else re.findall(r"`(kinredund[\w.]*)`", before):
            try:
                spec = importlib.util.find_spec(name)
            except ModuleNotFoundError:
                spec = None
            # gone, or a package now (kinredund.ik, kinredund.kinematics, kinredund.paths keep their names)
            assert spec is None or spec.submodule_search_locations is not None, f"{name} still exists"


def test_benchmark_help_cites_no_internal_issue():
    """`python benchmarks/X.py --help` shows the docstring's first line and every option's help."""
    cited = []
    for script in sorted((ROOT / "benchmarks").glob("*.py")):
        tree = ast.parse(script.read_text())
        texts = [(ast.get_docstring(tree) or "").splitlines()[0]]
        texts += [kw.value.value for node in ast.walk(tree) if isinstance(node, ast.Call) for kw in node.keywords
                  if kw.arg in ("help", "description") and isinstance(kw.value, ast.Constant)
                  and isinstance(kw.value.value, str)]
        cited += [f"{script.name}: {t}" for t in texts if re.search(r"\bissues?\b", t, flags=re.I)]
    assert not cited, cited


def test_files_the_docs_name_exist():
    """Every repository file or folder the README and docs/ name in backticks (`kinredund/tasks/pose.py`)
    exists: a module moved or split by a merge leaves the prose pointing nowhere. NAME-like placeholders
    (`benchmarks/NAME.py`) are skipped."""
    pattern = re.compile(r"`((?:kinredund|benchmarks|tests|examples|docs|robots|notebooks)/[\w/.\-]+)`")
    missing = []
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for name in pattern.findall(doc.read_text()):
            if not re.search(r"/[A-Z]+\.", name) and not (ROOT / name).exists():
                missing.append(f"{doc.name}: {name}")
    assert not missing, missing
