"""The Python code inside a Python FMU: the project's modules the FMU runs, under a private
package name, and the third-party modules they need (``requirements.txt``).

``closure`` follows the imports of the project's packages (at any level of a module: a lazy
import is run too) from the FMU scripts and the soil factory, leaving out NEVER_RUN (reached
only through code an FMU never calls: the fit's plots). ``requirements_of`` lists the
third-party modules the bundled code imports at module level (plus LAZY_REQUIREMENTS, imported
in functions the FMU runs), from REQUIREMENTS; a module missing there stops the build.
"""
from __future__ import annotations

import ast
import hashlib
import re
import sys
from pathlib import Path

from uplift_common.lazy import exported_names

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("structure", "soil_impedance", "fmus", "uplift_common")
#: project modules a bundled module names but an FMU never runs
NEVER_RUN = ("soil_impedance.fit_plot",)
#: third-party module -> the requirement written to requirements.txt (pip format)
REQUIREMENTS = {"numpy": "numpy>=1.24", "scipy": "scipy>=1.10", "h5py": "h5py>=3.8",
                "threadpoolctl": "threadpoolctl>=3.1", "tomli": 'tomli>=2.0; python_version < "3.11"'}
#: imported inside functions an FMU runs (structure.spec reads the reactor's TOML with tomli on 3.10;
#: uplift_common.blas limits the BLAS threads with threadpoolctl when the first stepper is built)
LAZY_REQUIREMENTS = ("threadpoolctl", "tomli")
#: provided by the FMU's own wrapper (pythonfmu bundles its package in the FMU)
PROVIDED = ("pythonfmu",)


#: data packages the bundled modules read (structure.spec: the built-in structure tables)
DATA_PACKAGES = ("structure.data",)


def data_files() -> list:
    """The files of DATA_PACKAGES (their __init__.py and .toml / .json data)."""
    return sorted(p for pkg in DATA_PACKAGES for p in ROOT.joinpath(*pkg.split(".")).iterdir()
                  if p.suffix in (".py", ".toml", ".json"))


def lazy_target(name: str) -> str:
    """The module ``name`` stands for: a name a lazy package exports (``uplift_common.lazy``) is
    the submodule defining it; any other name is itself."""
    package, _, attr = name.rpartition(".")
    init = ROOT.joinpath(*package.split("."), "__init__.py")
    if package.split(".")[0] in PACKAGES and init.is_file() and attr in (lazy := exported_names(init)):
        return f"{package}.{lazy[attr]}"
    return name


def module_file(name: str):
    """The source file of the project module ``name`` (package: its __init__.py), or None."""
    if name.split(".")[0] not in PACKAGES:
        return None
    p = ROOT.joinpath(*name.split("."))
    if (p / "__init__.py").is_file():
        return p / "__init__.py"
    return p.with_suffix(".py") if p.with_suffix(".py").is_file() else None


def imported_names(path: Path, module: str, top_level: bool) -> list:
    """Absolute names imported by a module (``from a import b`` gives a and a.b; ``lazy_module("a",
    defer=("b",))`` gives a and b): anywhere in it, or at module level only (also inside module-level
    try/if blocks)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    if top_level:
        nodes = [n for stmt in tree.body for n in (ast.walk(stmt) if isinstance(stmt, (ast.Try, ast.If)) else [stmt])]
    else:
        nodes = list(ast.walk(tree))
    out = []
    for node in nodes:
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Call):
            node = node.value                                   # sla = lazy_module("scipy.linalg") at module level
        if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "lazy_module":
            out += [c.value for c in ast.walk(node) if isinstance(c, ast.Constant) and isinstance(c.value, str)]
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package
                for _ in range(node.level - 1):
                    parent = parent.rpartition(".")[0]
                base = f"{parent}.{node.module}" if node.module else parent
            out += [base] + [f"{base}.{a.name}" for a in node.names]
    return out


def closure(entry_modules) -> dict:
    """{module name: source file} of the project modules reached from ``entry_modules`` (with
    their parent packages), NEVER_RUN left out."""
    seen, todo = {}, list(entry_modules)
    while todo:
        name = lazy_target(todo.pop())
        path = module_file(name)
        if path is None or name in seen or name in NEVER_RUN:
            continue
        seen[name] = path
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]
        todo += imported_names(path, name, top_level=False)
    return seen


def third_party(folder: Path) -> set:
    """Top-level names of the third-party modules the .py files under ``folder`` import at
    module level."""
    out = set()
    for f in folder.rglob("*.py"):
        for name in imported_names(f, "", top_level=True):
            top = name.split(".")[0]
            if top and top not in sys.stdlib_module_names and top != "__future__" and not top.startswith("_uplift_"):
                out.add(top)
    return out - set(PACKAGES) - set(PROVIDED)


def requirements_of(package: Path) -> list:
    """The requirements.txt lines of a bundled package (its module-level third-party imports and
    LAZY_REQUIREMENTS)."""
    needed = third_party(package) | set(LAZY_REQUIREMENTS)
    missing = needed - set(REQUIREMENTS)
    if missing:
        raise ValueError(f"the FMU's code imports {sorted(missing)}: add them to fmus.bundle.REQUIREMENTS")
    return [REQUIREMENTS[m] for m in sorted(needed)]


#: __init__.py of the private package: ``adopt`` is called by each FMU script before its
#: imports and by each instance (fmus.resources.adopt_resources)
PACKAGE_INIT = '''"""The uplift code bundled in this FMU (a private package)."""
import os
import sys


def adopt(resources):
    """Point this package and its loaded subpackages at ``resources``. Python modules are shared
    by every FMU instance in a process, the resources folders are not: the folder the package
    was first loaded from may be gone (a host deletes it when it frees that instance) when a
    later instance imports a submodule not needed yet."""
    for name, module in list(sys.modules.items()):
        if (name == __name__ or name.startswith(__name__ + ".")) and hasattr(module, "__path__"):
            module.__path__ = [os.path.join(resources, *name.split("."))]
'''

#: the project's packages as imported by the bundled code (rewritten to the private package)
IMPORT = re.compile(r"^(\s*)(from|import) (structure|soil_impedance|fmus|uplift_common)\b", re.M)


def bundle(folder: Path, extra, entry_modules) -> tuple[Path, object]:
    """Copy the project's modules an FMU runs (``closure(entry_modules)``) and the packages or
    modules ``extra`` (paths: a custom soil factory) into a private package
    ``folder/_uplift_<digest>`` with their imports of the project's packages rewritten to it, so
    that a host's own ``structure`` (or another copy of the project) can never shadow the FMU's
    code. The digest is that of the sources: two versions in one process do not share modules.
    Returns (the package folder, a function writing an FMU script with the same rewrite)."""
    files, entries = [], list(entry_modules)
    for src in extra:
        src = Path(src)
        base = src.parent
        for f in sorted(src.rglob("*") if src.is_dir() else [src]):
            if f.is_file() and "__pycache__" not in f.parts and f.suffix in (".py", ".toml", ".json"):
                files.append((f.relative_to(base), f.read_bytes()))
                if f.suffix == ".py":
                    entries += imported_names(f, "", top_level=False)
    files += [(p.relative_to(ROOT), p.read_bytes()) for p in closure(entries).values()]
    files += [(p.relative_to(ROOT), p.read_bytes()) for p in data_files()]
    digest = hashlib.sha1(b"".join(str(r).encode() + b"\0" + data for r, data in files)).hexdigest()[:12]
    name = f"_uplift_{digest}"
    rewrite = lambda text: IMPORT.sub(rf"\1\2 {name}.\3", text)
    pkg = folder / name
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(PACKAGE_INIT)
    for rel, data in files:
        dest = pkg / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        if rel.suffix == ".py":
            dest.write_text(rewrite(data.decode("utf-8")), encoding="utf-8")
        else:
            dest.write_bytes(data)

    def script_of(script: Path) -> Path:
        """The FMU script, its imports rewritten, and first of all the bundled package pointed
        at this FMU's resources (``adopt`` of PACKAGE_INIT): an FMU of another role from the
        same export may have loaded it from a folder its host has deleted since. The script's
        name carries the digest: pythonfmu imports it by name, and an FMU of another export
        loaded in the same process must not reuse it."""
        text = rewrite(script.read_text(encoding="utf-8"))
        future = "from __future__ import annotations\n"
        head, _, body = text.partition(future)
        adopt = f"import os as _os\nimport {name}\n{name}.adopt(_os.path.dirname(_os.path.abspath(__file__)))\n"
        dest = folder / f"{script.stem}_{digest}.py"        # its module name: one per bundle
        dest.write_text(head + future + adopt + body, encoding="utf-8")
        return dest

    return pkg, script_of


