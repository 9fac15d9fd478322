"""What a plain ``uplift run`` loads: the modules of its command and of the reactor scene, and not
those it does not use (the design run's, with its site response; scipy.spatial for the mesh's
duplicate check), each costing a warm run start-up time (issue 41)."""
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from helpers import ROOT

#: modules a run of a scene without soil cases or design spectra does not need (numpy's Fortran
#: wrapper generator and test utilities: scipy's import lists them, the command defers them)
NOT_NEEDED = ("orchestrator.design", "orchestrator.site_response", "scipy.spatial", "scipy.constants",
              "scipy.sparse", "scipy.linalg", "scipy.fft._basic", "numpy.f2py.f2py2e", "numpy.testing._private.utils",
              "unittest", "scipy", "soil_impedance.fastsolve", "orchestrator.soil_cases", "orchestrator.design_spectra",
              "soil_impedance.mesh_file", "socket")


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


def _datasets(path) -> dict:
    """{name: value} of every dataset of an HDF5 file."""
    import h5py
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


@pytest.mark.slow                  # the C runtime's compile, once per process (about 3 s of two runs after it)
def test_a_warm_monolithic_run_imports_no_scipy_and_writes_the_cold_run_s_bits(tmp_path):
    """``uplift run`` of a small reactor with the monolithic route, twice in fresh processes on one
    cache folder: the warm run reads the fit, the time-step check's frequency and answers and the
    rigid raft stepper's records, and imports no scipy module at all, nor the fast solver's (the
    solver's checks of its cache keys and memory guard are ``soil_impedance.solvers``); every
    dataset of its results file equals the cold run's, to the bit."""
    import json
    import shutil

    from fmus.native_stepper import _folder, cache_folder, library
    from helpers.scenes import small_reactor, write_scene
    if library() is None:
        pytest.skip("no native stepper on this machine")
    cache = tmp_path / "cache"
    shutil.copytree(_folder(None), cache_folder(cache))        # the process's compiled runtime: not built again
    scene = write_scene(tmp_path / "small.toml", small_reactor(motion={"duration_s": 1.0}))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "UPLIFT_CACHE": str(cache)}
    run = lambda out: [sys.executable, "-c",
                       "import json, runpy, sys\n"
                       f"sys.argv = ['uplift', 'run', {str(scene)!r}, '--route', 'monolithic', '-o', {str(out)!r}]\n"
                       "try:\n    runpy.run_module('orchestrator.cli', run_name='__main__')\n"
                       "except SystemExit as exc:\n    assert not exc.code, exc.code\n"
                       "print('SCIPY', json.dumps(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'\n"
                       "                                 or m == 'soil_impedance.fastsolve')))\n"]
    found = []
    for name in ("cold.h5", "warm.h5"):
        proc = subprocess.run(run(tmp_path / name), capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        found.append(set(json.loads(proc.stdout.split("SCIPY ")[-1])))
    assert {"scipy.linalg", "scipy.sparse"} <= found[0]             # the cold run assembles and solves
    assert {p.name.split("-")[0] for p in cache.glob("*.h5")} >= {"fit", "modes", "dtcheck", "stepper"}
    assert not found[1], sorted(found[1])
    cold, warm = _datasets(tmp_path / "cold.h5"), _datasets(tmp_path / "warm.h5")
    assert cold.keys() == warm.keys() and len(cold) > 20
    for name, value in cold.items():                                # the bits (NaN where a direction is not excited)
        a, b = np.asarray(value), np.asarray(warm[name])
        bits = (lambda v: v.tolist()) if a.dtype.kind == "O" else (lambda v: v.tobytes())    # labels: their text
        assert (a.dtype, a.shape, bits(a)) == (b.dtype, b.shape, bits(b)), name


def test_the_rigid_stepper_s_records_read_back_are_its_bytes_and_keyed_on_its_inputs(tmp_path):
    """``fmus.native_stepper.rigid_stepper`` with a cache folder: the first call builds the
    NewmarkStepper and keeps its records, the second reads a CachedStepper whose encoded run (the
    C runtime's input) is the stepper's, byte for byte, with other output nodes too; the key changes
    with the structure, the soil, the step, the contact, the damping and alpha; a damaged entry is
    recomputed with a CacheWarning and written again."""
    import structure
    from fmus.native_stepper import CachedStepper, encode_run, rigid_stepper, springs_soil, stepper_key
    from soil_impedance.cache import CacheWarning
    scene = _stiff_tower(0.005)
    model, springs = scene.model(), _stiff_springs(scene)
    soil = springs_soil(springs, 0.005)
    args = (model, soil, 0.005, scene.contact)
    first = rigid_stepper(*args, ag0=(0.1, 0.0, 0.0), cache_dir=tmp_path)
    again = rigid_stepper(*args, ag0=(0.2, 0.0, 0.0), cache_dir=tmp_path)    # ag0: the state, not the records
    assert isinstance(first, structure.NewmarkStepper) and isinstance(again, CachedStepper)
    for nodes in ((), ("top",), ("top", "top")):
        assert encode_run(again, nodes) == encode_run(first, nodes)
    assert (again.static.settlement, again.N, again.alpha) == (first.static.settlement, first.N, first.alpha)
    key = stepper_key(model, soil, 0.005, scene.contact, None, 0.0)
    other = _stiff_tower(0.005, E=3.01e12)
    stiffer = springs_soil(_stiff_springs(_stiff_tower(0.005, soil={"winkler": {"kv": 5.0e9, "kh": 4.1e9}})), 0.005)
    changed = [stepper_key(other.model(), soil, 0.005, scene.contact, None, 0.0),
               stepper_key(model, stiffer, 0.005, scene.contact, None, 0.0),
               stepper_key(model, soil, 0.0025, scene.contact, None, 0.0),
               stepper_key(model, soil, 0.005, _stiff_tower(0.005, contact={"penalty": 2.0}).contact, None, 0.0),
               stepper_key(model, soil, 0.005, scene.contact, 0.02, 0.0),
               stepper_key(model, soil, 0.005, scene.contact, None, -0.05)]
    assert key not in changed and len(set(changed)) == len(changed)
    (entry,) = tmp_path.glob("stepper-*.h5")
    raw = bytearray(entry.read_bytes())
    raw[len(raw) // 2] ^= 0x01
    entry.write_bytes(bytes(raw))
    with pytest.warns(CacheWarning, match="damaged cache entry"):
        redone = rigid_stepper(*args, cache_dir=tmp_path)
    assert isinstance(redone, structure.NewmarkStepper) and encode_run(redone, ("top",)) == encode_run(first, ("top",))
    assert isinstance(rigid_stepper(*args, cache_dir=tmp_path), CachedStepper)


def _stiff_springs(scene):
    from orchestrator.run import proxy_springs
    return proxy_springs(scene, False)


def test_the_first_frequency_is_kept_and_read_back(tmp_path):
    """``orchestrator.run.first_frequency`` with a cache folder: the modes' first frequency, kept
    and read back (not solved again), keyed on the structure and the springs; a damaged entry is
    solved again with a CacheWarning."""
    from soil_impedance.cache import CacheWarning
    from structure.winkler import modes_on_soil

    import orchestrator.run as run
    scene = _stiff_tower(0.005)
    model, springs = scene.model(), _stiff_springs(scene)
    f1 = float(modes_on_soil(model, springs).freq[0])
    assert run.first_frequency(model, springs, tmp_path) == f1 == run.first_frequency(model, springs)
    (entry,) = tmp_path.glob("modes-*.h5")
    solved = []
    real = run.modes_on_soil
    run.modes_on_soil = lambda *a: solved.append(1) or real(*a)
    try:
        assert run.first_frequency(model, springs, tmp_path) == f1 and not solved
        softer = _stiff_springs(_stiff_tower(0.005, soil={"winkler": {"kv": 2.0e9, "kh": 4.0e9}}))
        assert run.first_frequency(model, softer, tmp_path) == float(real(model, softer).freq[0]) < f1
        assert len(solved) == 1 and len(list(tmp_path.glob("modes-*.h5"))) == 2
        entry.write_bytes(entry.read_bytes()[:-64])                  # a half-written entry
        with pytest.warns(CacheWarning, match="damaged cache entry"):
            assert run.first_frequency(model, springs, tmp_path) == f1
        assert len(solved) == 2
    finally:
        run.modes_on_soil = real


def test_the_solver_constants_load_without_the_fast_solver_and_lazy_modules_on_first_use():
    """In a fresh process: the sweep's solver constants (``soil_impedance.solvers``) load without
    the fast solver's module or scipy.fft, and are the names that module gives; a ``lazy_module``
    stand-in imports on the first read of a name, and a deferred module bound by an import
    statement does not run before a name of it is read (four threads reading one at once get it,
    the module run once)."""
    code = ("import sys\n"
            "from uplift_common.lazy import defer_modules, lazy_module\n"
            "import soil_impedance.solvers as s\n"
            "names = ('SOLVERS', 'DEFAULT_TOL', 'TOL_RANGE', 'AUTO_NODES', 'check_solver', 'resolve_solver')\n"
            "read = tuple(getattr(s, n) for n in names)\n"
            "print('soil_impedance.fastsolve' in sys.modules, 'scipy' in sys.modules)\n"
            "sla = lazy_module('scipy.linalg')\n"
            "print('scipy.linalg' in sys.modules)\n"
            "defer_modules(('numpy.testing',))\n"
            "import numpy.testing\n"
            "print(sla.cholesky.__module__.startswith('scipy.linalg'), 'scipy.linalg' in sys.modules)\n"
            "print('numpy.testing._private.utils' in sys.modules)\n"
            "import threading\n"
            "seen = []\n"
            "threads = [threading.Thread(target=lambda: seen.append(numpy.testing.assert_array_equal)) for _ in range(4)]\n"
            "[t.start() for t in threads]; [t.join() for t in threads]\n"
            "assert len(seen) == 4 and len(set(seen)) == 1, seen        # four first uses at once: it ran once\n"
            "import soil_impedance.fastsolve as f\n"
            "print(read == tuple(getattr(f, n) for n in names), read)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}).stdout.splitlines()
    assert out[:5] == ["False False", "False", "True True", "False", out[4]]
    assert out[4].startswith("True (('auto', 'dense', 'fast'), 0.0001, (1e-12, 0.01), 500, ")
