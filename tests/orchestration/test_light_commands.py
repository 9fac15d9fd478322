"""The light commands stay light: ``uplift --help``, ``uplift COMMAND --help`` and ``uplift scene``
(printed) load none of the numerical or FMU stacks. Each runs in a fresh process under
``python -X importtime``, whose report lists every module the process imported."""
import os
import re
import subprocess
import sys

import pytest

from helpers import ROOT

#: what a light command must not import (top-level names; scipy.linalg, the FMU stack and dask
#: above all, and with them numpy and h5py: none of these commands computes or reads a file)
HEAVY = {"scipy", "numpy", "h5py", "fmpy", "pythonfmu", "dask", "distributed", "threadpoolctl"}
COMMANDS = ("run", "scene", "impedance", "fit", "export", "compare", "report", "ensemble", "fragility",
            "pushover", "bench")


def _imported(*args):
    """(completed process, the set of modules it imported) of ``uplift ARGS`` in a fresh process."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-X", "importtime", "-m", "orchestrator.cli", *args], capture_output=True,
                          text=True, env=env, timeout=120)
    names = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)\s*$", proc.stderr, re.M))
    return proc, names


def _heavy(names):
    return sorted(n for n in names if n.split(".")[0] in HEAVY)


def test_the_importtime_report_lists_what_a_process_imports():
    """The probe itself: a command that computes (``uplift --version`` reads the metadata; a bad
    scene name loads the scene module) is seen importing what it imports."""
    proc, names = _imported("--version")
    assert proc.returncode == 0 and "importlib.metadata" in names
    proc, names = _imported("run", "no-such-scene", "-o", os.devnull)
    assert proc.returncode == 2 and "numpy" in names and "orchestrator.scene" in names


@pytest.mark.parametrize("args", [("--help",), *((c, "--help") for c in COMMANDS), ("scene", "reactor")],
                         ids=lambda a: " ".join(a))
def test_light_commands_load_no_numerical_or_fmu_stack(args):
    proc, names = _imported(*args)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip(), "the command printed nothing"
    assert "orchestrator.cli" in names or "orchestrator.scene_base" in names
    assert not _heavy(names), f"uplift {' '.join(args)} imported {_heavy(names)}"
    assert not any(n.startswith("orchestrator.routes.") and n != "orchestrator.routes.base" for n in names), \
        "a route's module was imported to list the route names"


def test_a_route_module_loads_when_its_route_is_asked_for():
    """The registry lists every built-in route without importing one; get_route imports that
    route's module only (winkler's imports monolithic's stepping); a built-in replaced before its
    first use stays replaced (its module registers first), and an unregistered one stays out."""
    code = ("import sys\n"
            "from orchestrator.routes import Route, get_route, register, route_names, unregister\n"
            "loaded = lambda: sorted(m.rpartition('.')[2] for m in sys.modules if m.startswith('orchestrator.routes.'))\n"
            "print(' '.join(route_names())); print(' '.join(loaded()))\n"
            "get_route('winkler'); print(' '.join(loaded()))\n"
            "register(Route(name='cosim', summary='mine', run=print)); print(get_route('cosim').summary)\n"
            "unregister('linear'); print(' '.join(route_names()))\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120,
                         check=True).stdout.splitlines()
    assert out[0] == "monolithic cosim linear timefreq winkler"
    assert out[1] == "base"
    assert out[2] == "base monolithic winkler"
    assert out[3] == "mine"
    assert out[4] == "monolithic cosim timefreq winkler"
