"""OMSimulator (OpenModelica's FMI and SSP host, its command-line ``OMSimulator``) runs the
exported FMUs of the small scene and gives the monolithic route's answer:

- ``coupled.fmu`` alone (OMSimulator takes the stop time and the step from its DefaultExperiment);
- ``system.ssp``, the pair connected (the step from the system's OMSimulator annotation; the
  command line's stop time, 1 s unless given, replaces the SSP's, so the SSP's is passed).

Both kinds of FMU: native, and pythonfmu's, whose binary needs the host to have loaded libpython
(OMSimulator does not: the test preloads this interpreter's). The running max uplift and raft
rotation at the end and the raft's history (x[0..5] every step) to 1e-8 of the monolithic route.
Runs only where an OMSimulator executable is found, on PATH or as $OMSIMULATOR
(benchmarks/omsimulator_build.sh builds one from source).
"""
import csv
import os
import shutil
import subprocess
import sys
import sysconfig
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest

from helpers import EXPORT_MOTION, small_scene, soil_model
from orchestrator.export import SSD
from orchestrator.routes.monolithic import run_monolithic


def _find_omsimulator():
    """(path, "") of the OMSimulator executable, or (None, why not)."""
    path = os.environ.get("OMSIMULATOR") or shutil.which("OMSimulator")
    if not path:
        return None, "no OMSimulator executable: none on PATH and $OMSIMULATOR is not set"
    if not (Path(path).is_file() and os.access(path, os.X_OK)):
        return None, f"OMSIMULATOR={path} is not an executable file"
    return path, ""


OMSIMULATOR, WHY_NOT = _find_omsimulator()
pytestmark = pytest.mark.skipif(OMSIMULATOR is None, reason=WHY_NOT)


@pytest.fixture(scope="module")
def mono():
    scene = small_scene()
    res = run_monolithic(scene, EXPORT_MOTION, soil_model(scene))
    assert res.converged and res.max_uplift() > 1e-3
    return res


def _libpython():
    name = sysconfig.get_config_var("LDLIBRARY") or ""
    path = Path(sysconfig.get_config_var("LIBDIR") or "") / name
    return path if ".so" in name and path.is_file() else None


def run_omsimulator(model, tmp_path, kind, *options):
    """Run ``model`` (an .fmu or .ssp) in OMSimulator; returns the CSV result's (header, rows)."""
    env = dict(os.environ)
    if kind == "python":
        lib = _libpython()
        if lib is None:
            pytest.skip("this Python has no shared libpython to preload: pythonfmu FMUs cannot load in OMSimulator")
        env["LD_PRELOAD"] = str(lib)
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)     # the FMU's interpreter finds numpy
    result = tmp_path / f"{Path(model).stem}_res.csv"
    proc = subprocess.run([OMSIMULATOR, str(model), f"--resultFile={result}", f"--tempDir={tmp_path}", *options],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log
    lines = log.splitlines()
    assert not [s for s in lines if s.startswith("error:")], log
    # a build whose install lacks share/OMSimulator/schema only skips validating the SSD
    assert not [s for s in lines if s.startswith("warning:") and "schema file" not in s], log
    with open(result, newline="") as f:
        reader = csv.reader(f, skipinitialspace=True)
        header = [h.strip() for h in next(reader)]
        rows = np.array([[float(v) for v in row if v] for row in reader])
    return header, rows


def per_step(header, rows, dt, prefix=""):
    """{name: (nt,) values} at t = k dt, k = 0, 1, ...: OMSimulator writes each time twice
    (before and after it updates the inputs) and may end with a sliver step (its time is the sum
    of its steps); the last row of each k is the state after step k."""
    k = np.rint(rows[:, 0] / dt).astype(int)
    assert np.abs(rows[:, 0] - k * dt).max() < 1e-6 * dt                   # steps of dt
    last = np.r_[k[1:] != k[:-1], True]
    assert np.array_equal(k[last], np.arange(k.max() + 1))
    col = {h: i for i, h in enumerate(header)}
    return {h[len(prefix):]: rows[last, i] for h, i in col.items() if h.startswith(prefix)}


def check(out, mono):
    raft = np.column_stack([out[f"x[{i}]"] for i in range(6)])
    rotation = np.hypot(mono.raft[:, 3], mono.raft[:, 4]).max()
    assert raft.shape == mono.raft.shape
    assert np.abs(raft - mono.raft).max() <= 1e-8 * np.abs(mono.raft).max()
    assert out["max_uplift"][-1] == pytest.approx(mono.max_uplift(), rel=1e-8)
    assert out["max_raft_rotation"][-1] == pytest.approx(rotation, rel=1e-8)


@pytest.mark.parametrize("kind", ["native", "python"])
def test_coupled_fmu_in_omsimulator(exported, exported_native, mono, tmp_path, kind):
    exp = {"python": exported, "native": exported_native}[kind]
    header, rows = run_omsimulator(exp.coupled, tmp_path, kind)
    assert rows[-1, 0] == pytest.approx(exp.stop_time, abs=1e-12)              # its DefaultExperiment
    check(per_step(header, rows, exp.dt), mono)


@pytest.mark.parametrize("kind", ["native", "python"])
def test_system_ssp_in_omsimulator(exported, exported_native, mono, tmp_path, kind):
    exp = {"python": exported, "native": exported_native}[kind]
    with zipfile.ZipFile(exp.ssp) as z:
        root = ET.fromstring(z.read("SystemStructure.ssd"))
    stop = float(root.find(f"{{{SSD}}}DefaultExperiment").get("stopTime"))
    assert stop == pytest.approx(exp.stop_time)
    header, rows = run_omsimulator(exp.ssp, tmp_path, kind, f"--stopTime={stop!r}")
    assert rows[-1, 0] == pytest.approx(stop, abs=1e-12)
    # OMSimulator names the signals <model>.<system>.<component>.<variable>
    prefix = next(h for h in header if h.endswith(".structure.max_uplift"))[:-len("max_uplift")]
    check(per_step(header, rows, exp.dt, prefix), mono)
