"""The project's shape: the dependency rule between the packages and the layers inside them
(the stepper and its driver, ensembles, the experimental timefreq solvers, the native host), no
import cycle in the orchestrator, function-local imports only with a reason, and a route added
in one place reaching every command."""
import ast
import json
from pathlib import Path

import numpy as np
import pytest

from orchestrator.routes import Route, register, route_names, unregister
from structure.results import RouteResult
from helpers import ROOT, tower, write_scene

from uplift_common.code import PACKAGES
from uplift_common.lazy import exported_names
#: what each package may import from the project (the dependency rule)
ALLOWED = {"uplift_common": {"uplift_common"},
           "soil_impedance": {"soil_impedance", "uplift_common"}, "structure": {"structure", "uplift_common"},
           "fmus": {"fmus", "soil_impedance", "structure", "uplift_common"}, "orchestrator": set(PACKAGES),
           "orchestrator.timefreq": {"orchestrator.timefreq", "soil_impedance", "structure", "uplift_common"}}
#: modules (and the names under them) that only some modules may import: module prefix ->
#: importer prefixes. The stepper does not know its driver (``simulate``): only the orchestrator
#: runs it, the FMUs run the stepper; only the commands above an ensemble know ensembles; the experimental timefreq
#: solvers are reached through the registry only; the in-process native host serves the
#: orchestrator's routes, not the FMUs.
IMPORTERS = {"structure.driver": {"structure.driver", "orchestrator"},
             "orchestrator.ensemble": {"orchestrator.ensemble", "orchestrator.cli", "orchestrator.report",
                                       "orchestrator.fragility"},
             "orchestrator.timefreq.experimental": {"orchestrator.timefreq.experimental",
                                                    "orchestrator.timefreq.methods"},
             "fmus.native_stepper": {"fmus.native_stepper", "orchestrator"}}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path):
    """[(imported module, is function-local, line, has comment)] of a source file, absolute names."""
    tree = ast.parse(path.read_text())
    lines = path.read_text().splitlines()
    here = _module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    out = []

    def visit(node, local):
        for child in ast.iter_child_nodes(node):
            inner = local or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            if isinstance(child, ast.Import):
                names = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    base = ".".join(package.split(".")[:len(package.split(".")) - child.level + 1] + ([base] if base else []))
                names = [f"{base}.{a.name}" for a in child.names] + [base]
            else:
                visit(child, inner)
                continue
            comment = "#" in lines[child.lineno - 1] or "#" in lines[child.lineno - 2]
            out.extend((n, local, child.lineno, comment) for n in names)

    visit(tree, False)
    return out


def _sources(package):
    return sorted((ROOT / package).rglob("*.py"))


KNOWN = {_module_name(p) for pkg in PACKAGES for p in _sources(pkg)}
#: {package: {name: submodule}} of the packages whose names load on first use
LAZY = {_module_name(p): names for pkg in PACKAGES for p in _sources(pkg)
        if p.name == "__init__.py" and (names := exported_names(p))}


def _project_module(name: str, known: set) -> str | None:
    """The project module ``name`` refers to (a module or a name inside one: a name a lazy
    package exports is its submodule's), or None."""
    package, _, attr = name.rpartition(".")
    if attr in LAZY.get(package, {}):
        return f"{package}.{LAZY[package][attr]}"
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


@pytest.mark.parametrize("package", PACKAGES)
def test_dependency_rule(package):
    bad = []
    for path in _sources(package):
        here = _module_name(path)
        rule = ALLOWED["orchestrator.timefreq"] if here.startswith("orchestrator.timefreq") else ALLOWED[package]
        for name, _, line, _ in _imports(path):
            target = _project_module(name, KNOWN)
            if target and not any(target == a or target.startswith(a + ".") for a in rule):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    assert not bad, "\n".join(bad)


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


@pytest.mark.parametrize("restricted", sorted(IMPORTERS))
def test_who_imports_what_inside_the_packages(restricted):
    """Layers inside the packages (IMPORTERS), on every import of every module, by the name
    written (``from structure import simulate``) and by the module it resolves to."""
    bad = []
    for pkg in PACKAGES:
        for path in _sources(pkg):
            here = _module_name(path)
            if any(_under(here, a) for a in IMPORTERS[restricted]):
                continue
            for name, _, line, _ in _imports(path):
                if _under(name, restricted) or _under(_project_module(name, KNOWN) or "", restricted):
                    bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    assert not bad, f"only {sorted(IMPORTERS[restricted])} may import {restricted}:\n" + "\n".join(bad)


def test_the_rules_name_modules_that_exist():
    """A rule about a module that is not there any more checks nothing: every restricted
    prefix names a project module."""
    missing = [r for r in IMPORTERS if not any(_under(k, r) for k in KNOWN)]
    assert not missing, f"IMPORTERS names modules that do not exist: {missing}"


def test_orchestrator_imports_form_no_cycle():
    graph = {}
    for path in _sources("orchestrator"):
        here = _module_name(path)
        deps = {_project_module(n, KNOWN) for n, *_ in _imports(path)}
        graph[here] = {d for d in deps if d and d.startswith("orchestrator") and d != here}
    # a package imports its submodules' names through its __init__: an edge from a submodule to
    # its own package is the package's __init__, a real edge
    state, stack = {}, []

    def walk(node):
        state[node] = "open"
        stack.append(node)
        for dep in sorted(graph.get(node, ())):
            if state.get(dep) == "open":
                raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(dep):] + [dep]))
            if dep not in state:
                walk(dep)
        stack.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            walk(node)


#: the longest chain of module-level imports a module of the packages may start (``import_chain``)
MAX_IMPORT_CHAIN = 12


def import_graph() -> dict:
    """{module: the project modules importing it runs first}: its module-level imports (a name
    resolved to the module defining it) and their parent packages (importing ``a.b.c`` runs ``a``
    and ``a.b`` first), less its own parents (already imported before it)."""
    graph = {}
    for pkg in PACKAGES:
        for path in _sources(pkg):
            here = _module_name(path)
            deps = {_project_module(n, KNOWN) for n, local, *_ in _imports(path) if not local} - {None, here}
            deps |= {d.rsplit(".", k)[0] for d in deps for k in range(1, d.count(".") + 1)}
            graph[here] = {d for d in deps if d != here and not here.startswith(d + ".")}
    return graph


def import_chain(graph: dict, start: str) -> list:
    """The longest chain of imports from ``start`` in ``graph`` (module-level imports only: a
    function-local import runs when its function does, not at import)."""
    memo = {}

    def walk(node, path):
        if node in memo:
            return memo[node]
        best = [node]
        for dep in sorted(graph.get(node, ())):
            if dep not in path:
                chain = walk(dep, path | {node})
                if len(chain) + 1 > len(best):
                    best = [node, *chain]
        memo[node] = best
        return best

    return walk(start, frozenset())


def test_import_chains_are_short():
    """No module starts a chain of more than MAX_IMPORT_CHAIN module-level imports inside the
    packages (package namespaces load lazily, ``uplift_common.lazy``; a layer imports the modules
    it uses, not their packages' every sibling)."""
    graph = import_graph()
    longest = max((import_chain(graph, m) for m in sorted(graph)), key=len)
    assert len(longest) <= MAX_IMPORT_CHAIN, f"{len(longest)} modules: " + " -> ".join(longest)


#: module names that more than one package uses, each for the same concept in both
SHARED_NAMES = {"__init__": "every package",
                "errors": "error classes: the two families (uplift_common) and the structure's own",
                "winkler": "the Winkler mattress (structure) and the route that runs it (orchestrator.routes)",
                "linear": "the linear route (orchestrator.routes) and its solve, bonded.py, named after it "
                          "in the route only"}


def test_module_names_say_where_they_are():
    """No two modules of the packages share a name unless SHARED_NAMES says why."""
    seen = {}
    for pkg in PACKAGES:
        for path in _sources(pkg):
            seen.setdefault(path.stem, []).append(str(path.relative_to(ROOT)))
    repeated = {name: paths for name, paths in seen.items() if len(paths) > 1 and name not in SHARED_NAMES}
    assert not repeated, f"module names used twice: {repeated}"


def test_function_local_imports_say_why():
    """Function-local imports only where an optional dependency or a start-up cost justifies
    them, each with a comment on its line (or the line above)."""
    bad = [f"{p.relative_to(ROOT)}:{line} {name}" for p in _sources("orchestrator")
           for name, local, line, comment in _imports(p) if local and not comment]
    assert not bad, "function-local imports without a comment:\n" + "\n".join(sorted(set(bad)))


# --- a toy route, registered in one place, reaches run, the summary, compare and bench ---

TOY_SCENE = tower(soil={"halfspace": None}, foundation={"element_size": 5.0}, contact=None,
                  motion={"pga_g": 0.2, "duration_s": 1.0, "seed": None})


def _toy_run(ctx, progress=None):
    """A rigid structure glued to the ground: zero relative motion, the ground's acceleration."""
    t = ctx.motion.time
    n = ctx.scene.mesh.n
    acc = dict.fromkeys(ctx.scene.output.nodes, ctx.motion.acc)
    return RouteResult(route="toy", time=t, gap=np.zeros((t.size, n)), acc=acc, xy=ctx.scene.mesh.xy,
                       wall_s=1e-3, notes={"skipped": ("everything: it is a toy",)})


@pytest.fixture
def toy_route():
    register(Route(name="toy", summary="rigid structure glued to the ground (a test route)", run=_toy_run,
                   tables=lambda scene: (), bench={"toy-scene": {"dt": (0.02, 0.01)}}))
    yield
    unregister("toy")


def test_a_registered_route_reaches_every_command(toy_route, tmp_path, capsys):
    from orchestrator.bench import bench_config
    from orchestrator.cli import main

    assert "toy" in route_names()
    scene = tmp_path / "toy.toml"
    write_scene(scene, TOY_SCENE)
    out = tmp_path / "r.h5"
    assert main(["run", str(scene), "--route", "toy", "--route", "winkler", "-o", str(out), "--json"]) == 0
    summ = json.loads(capsys.readouterr().out)["routes"]
    assert summ["toy"]["max_uplift_m"] == 0.0 and summ["toy"]["skipped"] == ["everything: it is a toy"]
    assert main(["compare", str(out), "--reference", "toy", "--json"]) == 0
    cmp = json.loads(capsys.readouterr().out)
    assert cmp["reference"] == "toy" and "winkler" in cmp["differences"]
    assert main(["report", str(out), "-o", str(tmp_path / "rep")]) == 0
    assert "rigid structure glued to the ground" in (tmp_path / "rep" / "report.html").read_text()
    assert bench_config()["toy-scene"] == {"toy": {"dt": [0.02, 0.01]}}


def test_architecture_page_names_files_that_exist():
    """ARCHITECTURE.md names the files on the data's way: each one it names is in the tree (a
    path from the root, or a file name found in the package the paragraph is about)."""
    import re
    text = (ROOT / "ARCHITECTURE.md").read_text()
    names = set(re.findall(r"`([\w./]+\.(?:py|c|h|toml|md))`", text)) | set(re.findall(r"`([\w/]+/)`", text))
    files = [p for p in ROOT.rglob("*") if ".git" not in p.parts]
    missing = [n for n in sorted(names) if not (ROOT / n).exists()
               and not any(p.name == n.rstrip("/") for p in files)]
    assert len(names) > 40 and not missing, f"ARCHITECTURE.md names what is not there: {missing}"


def test_tests_import_one_way():
    """Test modules share code through tests/helpers only (``from helpers import ...``): none
    imports another test module or the tests folder as a package, and no folder under tests/
    is named like a project package (``tests`` is on the path: it would shadow the package
    wherever that is only reachable through an editable install)."""
    tests = ROOT / "tests"
    bad = []
    for path in sorted(tests.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            bad += [f"{path.relative_to(ROOT)} imports {n}" for n in names
                    if n.split(".")[0] == "tests" or n.split(".")[0].startswith(("test_", "conftest"))]
    shadows = [p.name for p in tests.iterdir() if p.is_dir() and p.name in PACKAGES]
    assert not bad and not shadows, "\n".join(bad) + f"\nfolders named like packages: {shadows}"
