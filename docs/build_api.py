"""Build kinredund's API reference from its docstrings (pdoc) and check its cross-references.

    python docs/build_api.py [--out docs/api]     # what `make docs` runs

The reference has one page per public module (every module of the package whose name has no part
starting with ``_``). Before writing it, every Sphinx-style cross-reference in a docstring
(``:func:`name```, ``:class:``, ``:meth:``, ``:attr:``, ``:data:``, ``:mod:``, ``:exc:``, ``:obj:``) that
names kinredund, in full or relative to its module or class, must resolve to an object that exists: a
reference to a renamed or moved name fails the build (exit code 1, each one listed). pdoc itself would
leave such a reference as plain text. References to other libraries (numpy, meshcat, ...) are not checked.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import re
import sys
from pathlib import Path

#: a Sphinx role with its target: :func:`~kinredund.sweep.sweep`, :class:`Progress`
ROLE = re.compile(r":(?:func|class|meth|attr|data|mod|exc|obj):`~?([A-Za-z_][\w.]*)`")


def public_modules(package: str = "kinredund") -> list[str]:
    """The dotted names of the package and its public modules and subpackages, sorted."""
    root = importlib.import_module(package)
    names = [package]
    for info in pkgutil.walk_packages(root.__path__, prefix=f"{package}."):
        if not any(part.startswith("_") for part in info.name.split(".")):
            names.append(info.name)
    return sorted(names)


def lookup(dotted: str):
    """The object a dotted name denotes (the longest importable module, then attributes), or raise LookupError."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            try:
                obj = getattr(obj, attr)
            except AttributeError:
                # a dataclass field or an annotated attribute without a class-level value
                fields = getattr(obj, "__dataclass_fields__", {}) or getattr(obj, "__annotations__", {})
                if attr not in fields:
                    raise LookupError(dotted) from None
                obj = None
        return obj
    raise LookupError(dotted)


def _resolves(target: str, module: str, owner: str | None) -> bool:
    """Whether ``target`` names an object: in full, or from ``owner`` (a class), its module, or kinredund."""
    if not target.startswith("kinredund.") and target != "kinredund":
        first = target.split(".")[0]
        bases = [b for b in (owner, module, "kinredund") if b]
        local = any(_try(f"{base}.{target}") for base in bases)
        if local:
            return True
        try:  # another library (numpy.ndarray, meshcat.Visualizer): not ours to check
            importlib.import_module(first)
            return True
        except ImportError:
            return first in {"pin", "np"}  # the usual aliases of pinocchio and numpy
    return _try(target)


def _try(dotted: str) -> bool:
    try:
        lookup(dotted)
    except LookupError:
        return False
    return True


def _docstrings(module_name: str):
    """(owner qualified name or None, docstring) of a module and of the classes, functions and methods it
    defines."""
    import inspect

    module = importlib.import_module(module_name)
    yield None, inspect.getdoc(module) or ""
    for name, obj in list(vars(module).items()):
        if getattr(obj, "__module__", None) != module_name or name.startswith("__"):
            continue
        if inspect.isclass(obj):
            owner = f"{module_name}.{obj.__qualname__}"
            yield owner, inspect.getdoc(obj) or ""
            for member in list(vars(obj).values()):
                func = getattr(member, "fget", None) or getattr(member, "__func__", None) or member
                if inspect.isfunction(func) and func.__doc__:
                    yield owner, inspect.getdoc(func) or ""
        elif inspect.isfunction(obj) and obj.__doc__:
            yield None, inspect.getdoc(obj) or ""


def broken_references(modules: list[str] | None = None) -> list[str]:
    """Every cross-reference to kinredund in the docstrings of ``modules`` that names nothing, as
    ``module: role target``."""
    out = []
    for name in modules or public_modules():
        for owner, doc in _docstrings(name):
            for target in ROLE.findall(doc):
                if not _resolves(target.rstrip("."), name, owner):
                    out.append(f"{owner or name}: {target}")
    return sorted(set(out))


def build(out: Path) -> Path:
    """Check the cross-references, then write the reference (HTML, one page per module) into ``out``.

    Raises:
        SystemExit: some references are broken (listed on standard error).
    """
    broken = broken_references()
    if broken:
        print("broken cross-references in docstrings:\n  " + "\n  ".join(broken), file=sys.stderr)
        raise SystemExit(1)
    import warnings

    import pdoc

    pdoc.render.configure(docformat="google", show_source=False)
    with warnings.catch_warnings():  # a subpackage brings its modules along: naming them too is not an error
        warnings.filterwarnings("ignore", message="The module specification .* adds a module named")
        # run from the checkout, the name is both the installed package and ./kinredund: the installed one is meant
        warnings.filterwarnings("ignore", message="'kinredund' may refer to either the installed Python module")
        pdoc.pdoc(*public_modules(), output_directory=out)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/api"), help="output folder (default docs/api)")
    args = parser.parse_args(argv)
    print(f"wrote the API reference into {build(args.out)}/ (open index.html)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
