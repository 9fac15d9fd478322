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

``lazy_module`` stands for a module of another package that a module uses in some functions only
(``sla = lazy_module("scipy.linalg")`` instead of ``import scipy.linalg as sla``): the module is
imported when one of its names is first read, so that a run whose path does not call it (a warm
run, its structure read from the cache) never imports it.
"""
from __future__ import annotations

import ast
import importlib
import importlib.util
import sys
import threading
import types
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


class lazy_module:                      # lower case: it stands for a module
    """A stand-in for the module ``name``: imported on the first read of one of its names
    (``importlib.import_module``, under the import lock: two threads import it once), each name
    then kept on the stand-in (later reads are plain attribute reads). defer: modules that ``name``
    imports at its top but whose names the caller's uses of it do not read (``defer_modules``,
    made just before ``name`` is imported: they run on their own first use)."""

    def __init__(self, name: str, defer: tuple[str, ...] = ()):
        object.__setattr__(self, "_lazy_name", name)
        object.__setattr__(self, "_lazy_defer", tuple(defer))

    def __getattr__(self, attr: str):
        if attr.startswith("__"):                    # copy, pickle, inspect: not the module's names
            raise AttributeError(attr)
        if self._lazy_defer and self._lazy_name not in sys.modules:
            defer_modules(self._lazy_defer)
        value = getattr(importlib.import_module(self._lazy_name), attr)
        object.__setattr__(self, attr, value)
        return value

    def __repr__(self) -> str:
        return f"<lazy module {self._lazy_name!r}{' (imported)' if self._lazy_name in sys.modules else ''}>"


#: numpy's submodules that the project's computations never use, but which importing scipy loads
#: (its array-API shim reads every name of ``numpy.__all__``): the Fortran-wrapper generator and
#: the test utilities
UNUSED_NUMPY = ("numpy.f2py", "numpy.testing")


class _Deferred(types.ModuleType):
    """A module whose code runs on the first read of a name it does not have yet (its import
    attributes ``__name__``, ``__spec__``, ``__path__``... are set when it is made, as
    ``importlib.util.module_from_spec`` sets them): an ``import`` statement that finds it in
    ``sys.modules`` binds it without running it (``importlib.util.LazyLoader``'s module runs on any
    attribute read, and Python 3.11's import statement reads ``__spec__``). Its first use runs
    under a lock (two threads run it once, the second waiting for the first); while it runs, a name
    it lacks is missing to the thread running it (the import system's ``hasattr`` of a submodule
    about to be imported)."""

    def __getattr__(self, attr: str):
        state = self.__dict__.get("_deferred_state")
        if state is None or state["runner"] == threading.get_ident():
            raise AttributeError(f"module {self.__name__!r} has no attribute {attr!r}")
        with state["lock"]:
            if not state["done"]:
                state["runner"] = threading.get_ident()
                try:
                    self.__spec__.loader.exec_module(self)
                finally:
                    state["runner"] = None
                state["done"] = True
        return getattr(self, attr) if attr in self.__dict__ else super().__getattribute__(attr)


def defer_modules(names=UNUSED_NUMPY) -> list[str]:
    """Make each module of ``names`` not imported yet load on first use (``_Deferred``: the module
    object is in ``sys.modules`` and on its parent package, its code runs when a name of it is
    first read): a module that is only listed, or imported and never used, is never run. Its
    parent package is imported. Modules already imported (or not installed) are left as they are.
    Returns the names deferred."""
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
        module = importlib.util.module_from_spec(spec)
        module.__class__ = _Deferred
        module.__dict__["_deferred_state"] = {"lock": threading.Lock(), "runner": None, "done": False}
        sys.modules[name] = module
        if package is not None:
            setattr(package, child, module)    # ``package.child`` finds it (no __getattr__ import)
        done.append(name)
    return done
