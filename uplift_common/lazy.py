"""Package namespaces that load on first use (the lazy-loading pattern of scientific Python's
SPEC 1, as SciPy uses it).

A package ``__init__`` that imports every submodule to re-export its names makes importing any
one submodule import all of its siblings (Python runs the package's ``__init__`` first): the
command line pays for what it does not use, and every module's import chain runs through the
whole package. A package that declares its public names with ``lazy_exports`` instead imports a
submodule when one of its names is first asked for (``from soil_impedance import SoilProfile``,
``soil_impedance.SoilProfile``), and not before::

    __getattr__, __dir__, __all__ = lazy_exports(__name__, {
        "profile": ("SoilProfile", "SoilError"),     # submodule: the names it exports
    })

The mapping is a literal: ``exported_names`` reads it from the source, without importing, for
the tools that follow imports statically (the FMU bundler, the architecture tests).
"""
from __future__ import annotations

import ast
import importlib
import sys
from pathlib import Path


def lazy_exports(package: str, exports: dict[str, tuple[str, ...]]):
    """(``__getattr__``, ``__dir__``, ``__all__``) of ``package`` whose public names are
    ``exports``: {submodule (relative to the package): the names it defines}."""
    where = {name: sub for sub, names in exports.items() for name in names}

    def __getattr__(name: str):
        sub = where.get(name)
        if sub is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{sub}"), name)
        setattr(sys.modules[package], name, value)       # found once: later lookups skip this
        return value

    def __dir__():
        return sorted(set(where) | set(vars(sys.modules[package])))

    return __getattr__, __dir__, list(where)


def exported_names(init: Path) -> dict[str, str]:
    """{name: submodule} a package ``__init__.py`` declares with ``lazy_exports`` (read from its
    source), else {}."""
    for node in ast.walk(ast.parse(Path(init).read_text(encoding="utf-8"))):
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "lazy_exports":
            return {n: sub for sub, names in ast.literal_eval(node.args[1]).items() for n in names}
    return {}
