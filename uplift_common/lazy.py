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

``defer_modules`` is the same idea for modules of other packages that something imports only to
list them: importing any part of scipy (>= 1.15, on numpy 2) runs its array-API shim, which takes
every name of ``numpy.__all__`` and so imports numpy's Fortran-wrapper generator and test
utilities (``UNUSED_NUMPY``) with what they import in turn (unittest, email, importlib.metadata,
charset_normalizer): about 0.2 s of a command's start that no computation of the project uses.
The command line defers them (``orchestrator.cli``): they load on first use, as before.
"""
from __future__ import annotations

import ast
import importlib
import importlib.util
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


#: numpy's submodules that the project's computations never use, but which importing scipy loads
#: (its array-API shim reads every name of ``numpy.__all__``): the Fortran-wrapper generator and
#: the test utilities
UNUSED_NUMPY = ("numpy.f2py", "numpy.testing")


def defer_modules(names=UNUSED_NUMPY) -> list[str]:
    """Make each module of ``names`` not imported yet load on first use (``importlib.util.LazyLoader``:
    the module object is in ``sys.modules`` and on its parent package, its code runs when one of
    its attributes is first read): a module that is only listed, never used, is never run. Its
    parent package is imported. Modules already imported (or not installed) are left as they are.
    Returns the names deferred. Only for modules a computation never uses: Python 3.11's lazy
    module is not safe against two threads making its first use at once."""
    done = []
    for name in names:
        if name in sys.modules:
            continue
        parent, _, child = name.rpartition(".")
        if parent:
            __import__(parent)                 # (as an import statement: ``-X importtime`` lists it)
        package = sys.modules[parent] if parent else None
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            continue
        spec.loader = importlib.util.LazyLoader(spec.loader)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)        # only arms the module: its code runs on first use
        if package is not None:
            setattr(package, child, module)    # ``package.child`` finds it (no __getattr__ import)
        done.append(name)
    return done
