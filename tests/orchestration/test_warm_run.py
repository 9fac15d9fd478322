"""What a plain ``uplift run`` loads: the modules of its command and of the reactor scene, and not
those it does not use (the design run's, with its site response; scipy.spatial for the mesh's
duplicate check), each costing a warm run start-up time (issue 41)."""
import os
import re
import subprocess
import sys

import pytest
from helpers import ROOT

#: modules a run of a scene without soil cases or design spectra does not need (numpy's Fortran
#: wrapper generator and test utilities: scipy's import lists them, the command defers them)
NOT_NEEDED = ("orchestrator.design", "orchestrator.site_response", "scipy.spatial", "scipy.constants",
              "scipy.sparse", "scipy.linalg", "scipy.fft._basic", "numpy.f2py.f2py2e", "numpy.testing._private.utils",
              "unittest")


def test_a_plain_run_loads_neither_the_design_run_nor_scipy_spatial(tmp_path):
    """``uplift run reactor`` into a folder that does not exist: the command imports what it
    uses and loads the scene (its mesh checked), then refuses the output path before computing."""
    proc = subprocess.run([sys.executable, "-X", "importtime", "-m", "orchestrator.cli", "run", "reactor", "-o",
                           str(tmp_path / "no-such-folder" / "x.h5")], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=tmp_path)
    names = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)\s*$", proc.stderr, re.M))
    assert proc.returncode == 2 and "no-such-folder" in proc.stderr, proc.stderr[-2000:]
    assert {"orchestrator.run", "orchestrator.results_file", "soil_impedance.mesh", "structure.newmark"} <= names
    assert not names & set(NOT_NEEDED), f"a plain run imported {sorted(names & set(NOT_NEEDED))}"


def test_deferred_modules_load_on_first_use_only():
    """``uplift_common.lazy.defer_modules`` in a fresh process: scipy's import (which lists every
    name of numpy) runs neither numpy.f2py nor numpy.testing; both work on first use, as imported
    (``from numpy.testing import ...``, ``numpy.f2py.<attr>``); a module loaded already is left as
    it is."""
    code = ("import sys\n"
            "from uplift_common.lazy import defer_modules\n"
            "print(defer_modules(('numpy.f2py', 'numpy.testing', 'os')))\n"
            "import numpy, scipy.linalg, scipy.sparse\n"
            "print(sorted(m for m in ('numpy.f2py.f2py2e', 'numpy.testing._private.utils', 'unittest') if m in sys.modules))\n"
            "from numpy.testing import assert_array_equal\n"
            "assert_array_equal(numpy.arange(3), [0, 1, 2])\n"
            "print(numpy.testing.assert_allclose.__name__, callable(numpy.f2py.run_main), 'numpy.f2py.f2py2e' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}).stdout.splitlines()
    assert out == ["['numpy.f2py', 'numpy.testing']", "[]", "assert_allclose True True"]


def test_is_design_is_the_design_modules():
    """``orchestrator.design.is_design`` (its old home) is the scene module's function."""
    from orchestrator import design, scene
    assert design.is_design is scene.is_design


def _stiff_tower(dt, E=3e12, **sections):
    """test_run's stiff tower on Winkler springs (10 ms does not resolve its contact, 5 ms does);
    E: its beam's Young's modulus (Pa)."""
    from helpers import changed, tower

    from orchestrator.scene import scene_from_dict
    beam = dict(tower()["structure"]["beams"][0], E=E, G=1.25e12)
    data = changed(tower(), soil={"winkler": {"kv": 5.0e9, "kh": 4.0e9}}, structure={"beams": [beam]},
                   motion={"pga_g": 0.6}, analysis={"dt": dt})
    return scene_from_dict(changed(data, **sections), name="stiff")


@pytest.mark.slow                  # the C runtime's compile, once per process (about 1 s after it)
def test_a_warm_step_check_builds_no_stepper_and_its_key_is_every_input(tmp_path, monkeypatch):
    """The check's cache key is taken from its inputs before any stepper is built: a warm check
    builds none and gives the cold answer (and the answer of a check without cache); a change of
    the structure, the springs, the contact, the step or the motion changes the key."""
    import shutil

    import structure
    from fmus.native_stepper import _folder, cache_folder, library

    from orchestrator.motion import make_motion
    from orchestrator.run import _dt_check_key, proxy_springs, step_doubling
    if library() is None:
        pytest.skip("no native stepper on this machine (the check is not cached without it)")
    shutil.copytree(_folder(None), cache_folder(tmp_path))     # the process's compiled runtime: not built again
    scene = _stiff_tower(0.005)
    model, springs = scene.model(), proxy_springs(scene, False)
    motion = make_motion(scene.motion, 0.005)
    built = []
    real = structure.NewmarkStepper
    monkeypatch.setattr(structure, "NewmarkStepper", lambda *a, **k: built.append(1) or real(*a, **k))
    cold = step_doubling(scene, model, springs, motion, tmp_path)
    assert len(built) == 2 and len(list(tmp_path.glob("dtcheck-*.h5"))) == 2
    built.clear()
    assert step_doubling(scene, model, springs, motion, tmp_path) == cold and not built
    assert step_doubling(scene, model, springs, motion) == cold and len(built) == 2      # no cache: stepped
    lib = library(cache_folder(tmp_path))
    key = _dt_check_key(lib, model, springs, scene.contact, motion)
    assert key == _dt_check_key(lib, _stiff_tower(0.005).model(), proxy_springs(_stiff_tower(0.005), False),
                                scene.contact, make_motion(scene.motion, 0.005))          # the same inputs, anew
    other = _stiff_tower(0.005, E=3.01e12)
    changed = {
        "structure": _dt_check_key(lib, other.model(), springs, scene.contact, motion),
        "springs": _dt_check_key(lib, model, proxy_springs(_stiff_tower(0.005, soil={"winkler": {
            "kv": 5.0e9, "kh": 4.1e9}}), False), scene.contact, motion),
        "contact": _dt_check_key(lib, model, springs, _stiff_tower(0.005, contact={"enabled": True,
                                                                                   "penalty": 2.0}).contact, motion),
        "step": _dt_check_key(lib, model, springs, scene.contact, motion.resampled(0.0025)),
        "motion": _dt_check_key(lib, model, springs, scene.contact, make_motion(_stiff_tower(
            0.005, motion={"pga_g": 0.55}).motion, 0.005)),
    }
    assert key not in changed.values() and len(set(changed.values())) == len(changed), changed
