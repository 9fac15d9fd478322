"""What a plain ``uplift run`` loads: the modules of its command and of the reactor scene, and not
those it does not use (the design run's, with its site response; scipy.spatial for the mesh's
duplicate check), each costing a warm run start-up time (issue 41)."""
import os
import re
import subprocess
import sys

from helpers import ROOT

#: modules a run of a scene without soil cases or design spectra does not need
NOT_NEEDED = ("orchestrator.design", "orchestrator.site_response", "scipy.spatial", "scipy.constants")


def test_a_plain_run_loads_neither_the_design_run_nor_scipy_spatial(tmp_path):
    """``uplift run reactor`` into a folder that does not exist: the command imports what it
    uses and loads the scene (its mesh checked), then refuses the output path before computing."""
    proc = subprocess.run([sys.executable, "-X", "importtime", "-m", "orchestrator.cli", "run", "reactor", "-o",
                           str(tmp_path / "no-such-folder" / "x.h5")], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=tmp_path)
    names = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)\s*$", proc.stderr, re.M))
    assert proc.returncode == 2 and "no-such-folder" in proc.stderr, proc.stderr[-2000:]
    assert {"orchestrator.run", "orchestrator.results_file", "soil_impedance.mesh", "scipy.sparse"} <= names
    assert not names & set(NOT_NEEDED), f"a plain run imported {sorted(names & set(NOT_NEEDED))}"


def test_is_design_is_the_design_modules():
    """``orchestrator.design.is_design`` (its old home) is the scene module's function."""
    from orchestrator import design, scene
    assert design.is_design is scene.is_design
