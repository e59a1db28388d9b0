"""docs/notation.md names real code: every backticked dotted name it gives resolves in kinredund.

What is checked, per backticked span of the page:

- a dotted name ``module.name`` or ``Class.attr`` (any depth), optionally followed by one call's
  parentheses and indexing (``Robot.fk(q)[:3, 3]`` checks ``Robot.fk``; the arguments are not read);
- a relative name ``.attr`` (``HDTable.alpha``, ``.a``, ``.b``): looked up on the owner of the last
  resolved dotted name in the same table cell (or line);
- a bare CamelCase name (``Target``, ``StageCount``): a class defined in kinredund.

The first part of a dotted name may be a module's short name (``closure`` for
kinredund.kinematics.closure), a path inside the package (``planning.spatial``), the full
``kinredund....`` path, or a class defined in kinredund. Attributes of a class count when they are class
attributes, dataclass fields, annotations or ``self.name = ...`` assignments in the class's methods
(instance attributes). A first part that is none of these must be one of :data:`LOCAL_ROOTS` (a
variable of the prose, such as ``s.omega`` or ``robot.nq``), else the name fails: a misspelt module
name is caught too. Other spans (arithmetic, file names, shell commands, lone lower-case locals) are
skipped.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import importlib
import re
from pathlib import Path
from types import ModuleType

import pytest

import kinredund

ROOT = Path(__file__).resolve().parent.parent
NOTATION = ROOT / "docs" / "notation.md"
PACKAGE = Path(kinredund.__file__).resolve().parent

#: variables the page uses as the first part of a dotted expression (not modules or classes)
LOCAL_ROOTS = frozenset({"np", "robot", "s"})
#: last parts that make a span a file name rather than a code name
FILE_SUFFIXES = frozenset({"py", "md", "txt", "json", "toml", "png", "pdf", "svg", "yaml", "yml", "urdf", "csv"})

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"
DOTTED = re.compile(rf"^(\.?{IDENT}(?:\.{IDENT})*)(.*)$", re.S)
CAMEL = re.compile(r"^[A-Z][A-Za-z0-9]*[a-z][A-Za-z0-9]*$")


# -- the package's modules and classes, found without importing everything ------------------------
@functools.cache
def modules() -> dict[str, list[str]]:
    """Every key by which a kinredund module may be named -> the dotted module names.

    A module kinredund.a.b.c is reachable as ``c``, ``b.c``, ``a.b.c`` and ``kinredund.a.b.c``.
    """
    out: dict[str, list[str]] = {}
    for f in PACKAGE.rglob("*.py"):
        rel = f.relative_to(PACKAGE).with_suffix("").parts
        if rel[-1] == "__init__":
            rel = rel[:-1]
        full = ".".join(("kinredund",) + rel)
        parts = full.split(".")
        for k in range(len(parts)):
            out.setdefault(".".join(parts[k:]), []).append(full)
    return out


@functools.cache
def module_source(name: str) -> ast.Module | None:
    base = PACKAGE.joinpath(*name.split(".")[1:])
    for f in (base.with_suffix(".py"), base / "__init__.py"):
        if f.is_file():
            return ast.parse(f.read_text())
    return None


@functools.cache
def classes() -> dict[str, list[str]]:
    """Class name -> the modules that define a top-level class of that name (read with ast)."""
    out: dict[str, list[str]] = {}
    for names in modules().values():
        for name in names:
            tree = module_source(name)
            for node in tree.body if tree else ():
                if isinstance(node, ast.ClassDef) and name not in out.get(node.name, []):
                    out.setdefault(node.name, []).append(name)
    return out


def instance_attributes(cls: type) -> set[str]:
    """Dataclass fields, annotations, slots and ``self.x = ...`` targets of cls and its kinredund bases."""
    found: set[str] = set()
    for base in cls.__mro__:
        found |= set(getattr(base, "__annotations__", {}))
        slots = getattr(base, "__slots__", ())
        found |= {slots} if isinstance(slots, str) else set(slots)
        if not base.__module__.startswith("kinredund"):
            continue
        tree = module_source(base.__module__)
        for node in ast.walk(tree) if tree else ():
            if isinstance(node, ast.ClassDef) and node.name == base.__name__:
                for sub in ast.walk(node):
                    if (isinstance(sub, ast.Attribute) and isinstance(sub.ctx, ast.Store)
                            and isinstance(sub.value, ast.Name) and sub.value.id == "self"):
                        found.add(sub.attr)
    if dataclasses.is_dataclass(cls):
        found |= {f.name for f in dataclasses.fields(cls)}
    return found


# -- resolution ------------------------------------------------------------------------------------
class UnresolvedNameError(Exception):
    pass


def attribute(owner, name: str):
    """owner.name for a module (submodules included) or a class (instance attributes included).

    Returns the attribute, or ``None`` for an instance attribute (it has no value on the class).

    Raises:
        UnresolvedNameError: it does not exist.
    """
    if isinstance(owner, ModuleType):
        if hasattr(owner, name):
            return getattr(owner, name)
        try:
            return importlib.import_module(f"{owner.__name__}.{name}")
        except ModuleNotFoundError as err:
            raise UnresolvedNameError(f"module {owner.__name__} has no {name!r}") from err
    if isinstance(owner, type):
        if hasattr(owner, name):
            return getattr(owner, name)
        if name in instance_attributes(owner):
            return None
        raise UnresolvedNameError(f"class {owner.__module__}.{owner.__qualname__} has no attribute {name!r}")
    if owner is not None and hasattr(owner, name):
        return getattr(owner, name)
    raise UnresolvedNameError(f"{owner!r} has no attribute {name!r} (or its type is not known to the check)")


def starts(first: str) -> list:
    """The objects a dotted name's first part may denote (modules by any suffix path, classes)."""
    out = []
    for mod in modules().get(first, []):
        out.append(importlib.import_module(mod))
    for mod in classes().get(first, []):
        out.append(getattr(importlib.import_module(mod), first))
    return out


def walk(obj, parts: list[str]):
    """(the module or class that holds the last part, the last part's value) following parts from obj.

    The value is None for an instance attribute; it is the owner itself when it is a module or class.
    """
    owner = current = obj
    for part in parts:
        if current is None:
            raise UnresolvedNameError(f"cannot look up {part!r} on an instance attribute (its type is not known)")
        value = attribute(current, part)
        if isinstance(current, (type, ModuleType)):
            owner = current
        current = value
    if isinstance(current, (type, ModuleType)):
        owner = current
    return owner, current


def resolve(name: str):
    """The owner (module or class) on which the last part of a dotted name was found.

    Returns:
        The owner, or the string ``"local"`` when the first part is a variable of the prose.

    Raises:
        UnresolvedNameError: the name does not exist.
    """
    parts = name.split(".")
    errors = []
    # the longest module prefix first (``planning.spatial.scaled_p15``), then shorter ones
    for k in range(len(parts), 0, -1):
        for start in starts(".".join(parts[:k])):
            try:
                return walk(start, parts[k:])[0]
            except UnresolvedNameError as err:
                errors.append(str(err))
    if parts[0] in LOCAL_ROOTS:
        return "local"
    if errors:
        raise UnresolvedNameError(f"`{name}`: " + "; ".join(dict.fromkeys(errors)))
    raise UnresolvedNameError(f"`{name}`: {parts[0]!r} is neither a kinredund module, a kinredund class nor one of "
                     "LOCAL_ROOTS (add it there if the page uses it as a variable)")


def code_name(span: str) -> str | None:
    """The name a backticked span gives, or None for a span that is not one (see the module docstring)."""
    span = span.strip()
    m = DOTTED.match(span)
    if not m:
        return None
    name, rest = m.group(1), m.group(2)
    if "." not in name.lstrip("."):
        relative = name.startswith(".")
        if not relative and not (CAMEL.match(name) and rest == ""):
            return None
    if rest and not rest.startswith(("(", "[")):
        return None  # arithmetic, a path, a shell command...
    if name.rsplit(".", 1)[-1] in FILE_SUFFIXES:
        return None
    return name


def cells(text: str):
    """(line number, cell text) of every table cell, and of every other line, of a Markdown page."""
    for lineno, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("|"):
            for cell in re.split(r"(?<!\\)\|", line.strip().strip("|")):  # an escaped \| stays in its cell
                yield lineno, cell
        else:
            yield lineno, line


def check_page(text: str) -> tuple[list[str], int]:
    """(failures, number of names checked) for a Markdown page."""
    failures, checked = [], 0
    for lineno, cell in cells(text):
        owner = None
        for span in re.findall(r"`([^`]+)`", cell):
            name = code_name(span)
            if name is None:
                continue
            checked += 1
            try:
                if name.startswith("."):
                    if owner in (None, "local"):
                        continue  # no owner in this cell: nothing to resolve it against
                    walk(owner, name[1:].split("."))
                else:
                    if CAMEL.match(name) and name not in classes():
                        raise UnresolvedNameError(f"`{name}` is not a class defined in kinredund")
                    owner = resolve(name)
            except UnresolvedNameError as err:
                failures.append(f"docs/notation.md:{lineno}: {err}")
    return failures, checked


# -- the tests -------------------------------------------------------------------------------------
def test_every_code_name_in_notation_md_exists():
    failures, checked = check_page(NOTATION.read_text())
    assert checked > 100, f"only {checked} names found: the parser no longer reads the page's tables"
    assert not failures, "names in docs/notation.md that do not exist:\n" + "\n".join(failures)


GOOD = """
| theta | joint vector | `closure.natural_invariants(Q)`, `HDTable.alpha`, `.a`, `Trajectory.q` | rad |
| x | target | `kinredund.closed_form.ClosedFormIK.solve_all`, `ArmGeometry.from_hd`, `planning.spatial.H` | m |
| K | Jacobian | `K[:3] @ thetadot`, `np.concatenate([s.omega, s.v])`, `theta - reference`, `M` | 1 |
| f | files | `tasks/axis.py`, `positioning.py`, `kinredund reproduce 3.2`, `Target` | 1 |
| z | slots and self | `TaskTerms.J`, `ClosedFormIK.geometry`, `RedundancySolution.multiplier` | 1 |
"""


def test_the_check_accepts_real_names_and_skips_code_fragments():
    failures, checked = check_page(GOOD)
    assert failures == []
    assert checked == 12  # np.concatenate counts (a local root); fragments, files and the lone M do not


@pytest.mark.parametrize("bad", [
    "`closure.natural_invariantz(Q)`",  # misspelt function of a module
    "`ClosedFormIK.solve_alll`",  # misspelt method
    "`RedundancySolution.multiplyer`",  # misspelt dataclass field
    "`HDTable.alpha`, `.aa`",  # misspelt relative attribute
    "`closurr.vect`",  # misspelt module (not a local either)
    "`kinredund.closed_form.positioning.ArmGeometri`",  # full path, misspelt class
    "`TargetX`",  # a CamelCase class that does not exist
    "`planning.spatial.GAMA`",  # misspelt constant under a package path
])
def test_the_check_catches_a_misspelt_name(bad):
    failures, checked = check_page(f"| x | y | {bad} | 1 |\n")
    assert checked >= 1
    assert len(failures) == 1, failures
