"""The wheel a user installs: built from the tracked files only (as a clean clone builds it),
it carries every module and data file of the four import packages, the `uplift` command, and
nothing of the tests. (.ci/wheel-smoke installs it outside the checkout and runs it.)"""
import shutil
import subprocess
import sys
import zipfile

import pytest

from helpers import ROOT

from uplift_common.code import PACKAGES


def tracked_files():
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the tracked files are unknown")
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [p for p in out.decode().split("\0") if p]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """The wheel built from a copy of the tracked files (nothing untracked can ride along)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    for rel in tracked_files():
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, src / rel)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(tmp / "dist"), str(src)],
                   check=True, capture_output=True, timeout=600)
    (path,) = (tmp / "dist").glob("*.whl")
    return path


@pytest.mark.slow
def test_wheel_carries_every_package_file_and_no_test(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = {n for n in names if ".dist-info/" not in n}
    expected = {p for p in tracked_files() if p.split("/")[0] in PACKAGES}
    assert sorted(expected - shipped) == []                  # every module, scene, structure data, C source
    assert sorted(shipped - expected) == []                  # nothing untracked or generated
    packages = {str(p.parent.relative_to(ROOT)) for pkg in PACKAGES for p in (ROOT / pkg).rglob("__init__.py")}
    assert {n.rsplit("/", 1)[0] for n in shipped if n.endswith("/__init__.py")} == packages
    assert not [n for n in shipped if n.startswith("tests/") or "/test_" in n or n.endswith("host.c")]


def test_wheel_metadata(wheel):
    """A distribution name of its own (not the index's unrelated `uplift`) and the `uplift` command."""
    z = zipfile.ZipFile(wheel)
    meta = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
    text = z.read(meta).decode()
    assert "\nName: uplift-ssi\n" in text
    entry = z.read(next(n for n in z.namelist() if n.endswith(".dist-info/entry_points.txt"))).decode()
    assert "uplift = orchestrator.cli:main" in entry


def test_start_up_loads_no_fmu_or_cluster_stack():
    """`uplift --help`, a scene load and the route registry import neither fmpy, pythonfmu nor dask
    (they load when an export, a co-simulation or an ensemble runs)."""
    code = ("import sys, contextlib, io\n"
            "from orchestrator.cli import main\n"
            "from orchestrator.scene import load_scene\n"
            "from orchestrator.routes import route_names, get_route\n"
            "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
            "    main(['--help'])\n"
            "load_scene('reactor'); [get_route(r) for r in route_names()]\n"
            "print(' '.join(sorted({m.split('.')[0] for m in sys.modules} & {'fmpy', 'pythonfmu', 'dask', 'distributed'})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip() == ""
