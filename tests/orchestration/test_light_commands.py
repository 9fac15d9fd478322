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
