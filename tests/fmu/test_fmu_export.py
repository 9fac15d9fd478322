"""The exported FMUs: model descriptions valid, outputs at initialisation, a failing step
reported (not a crash), roll back 10 steps through the FMU state and replay bit-identically."""
import zipfile
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from helpers import EXPORT_MOTION, small_scene
from orchestrator.master import CosimError, FmuSlave

SCENE = small_scene()
MOTION = EXPORT_MOTION                 # the motion of the shared ``exported`` pair (conftest)


def test_export_writes_the_five_files(exported):
    assert [p.name for p in exported.files] == ["structure.fmu", "soil.fmu", "coupled.fmu", "system.ssd",
                                                "system.ssp"]
    assert exported.dt == MOTION.dt
    ssd = exported.ssd.read_text()
    assert 'FixedStepAlgorithm baseStepSize="0.005"' in ssd
    with zipfile.ZipFile(exported.ssp) as z:
        assert set(z.namelist()) == {"SystemStructure.ssd", "resources/structure.fmu", "resources/soil.fmu"}
        assert 'source="resources/soil.fmu"' in z.read("SystemStructure.ssd").decode()


def test_model_descriptions_pass_fmpy_validation(exported):
    from fmpy.validation import validate_fmu
    for fmu in (exported.structure, exported.soil, exported.coupled):
        assert validate_fmu(str(fmu)) == []
        with zipfile.ZipFile(fmu) as z:
            md = ET.fromstring(z.read("modelDescription.xml"))
            names = set(z.namelist())
        cs = md.find("CoSimulation").attrib
        assert cs["canHandleVariableCommunicationStepSize"] == "false"
        assert cs["canGetAndSetFMUstate"] == cs["canSerializeFMUstate"] == "true"
        n_out = sum(v.get("causality") == "output" for v in md.find("ModelVariables"))
        for tag in ("Outputs", "InitialUnknowns"):
            unknowns = md.find("ModelStructure").find(tag)
            assert len(unknowns) == n_out and all(u.get("dependencies") == "" for u in unknowns)
        # self-contained: model data and the project's packages in resources/
        assert "resources/uplift_soil_model.npz" in names and "resources/requirements.txt" in names
        # the project's code under a private package name (a host's own modules cannot shadow it)
        private = {n.split("/")[1] for n in names if n.startswith("resources/_uplift_")}
        assert len(private) == 1
        pkg = f"resources/{private.pop()}"
        assert f"{pkg}/structure/newmark.py" in names and f"{pkg}/soil_impedance/convolution.py" in names
        # every Real variable has a unit, defined in UnitDefinitions; the default experiment is the record
        defined = {u.get("name") for u in md.find("UnitDefinitions")}
        units = [v.find("Real").get("unit") for v in md.find("ModelVariables") if v.find("Real") is not None]
        assert None not in units and set(units) <= defined
        ex = md.find("DefaultExperiment").attrib
        assert float(ex["stepSize"]) == MOTION.dt and float(ex["stopTime"]) == pytest.approx(0.6)


def test_outputs_computed_at_initialisation(exported):
    with FmuSlave(exported.structure, "s") as s, FmuSlave(exported.soil, "g") as g:
        s.initialize()
        g.initialize()
        P = s.get("P").copy()
        assert np.all(P > 0) and P.sum() == pytest.approx(
            9.81 * _total_mass(), rel=1e-6)                   # static contact forces carry the weight
        assert np.all(s.get("gap") == 0) and np.all(g.get("g") == 0)          # at rest


def _total_mass():
    return SCENE.model().total_mass


def test_failed_step_is_reported_not_a_crash(exported):
    with FmuSlave(exported.structure, "s") as s:
        s.initialize()
        with pytest.raises(CosimError, match="steps exactly 0.005 s per communication step"):
            s.do_step(0.0, 2 * MOTION.dt)                     # wrong communication step
        s.do_step(0.0, MOTION.dt)                             # the instance still works
        assert np.isfinite(s.get("x")).all()


def _gs_step(s, g, k, dt):
    s.set("g", "g_time", g.get("g", "g_time"))
    s.do_step((k - 1) * dt, dt)                           # internal (bundled) motion
    g.set("x", "xdot", "x_time", s.get("x", "xdot", "x_time"))
    g.do_step((k - 1) * dt, dt)
    return np.concatenate([s.get("x", "xdot", "P", "gap"), g.get("g", "f", "dissipated_energy")])


def test_rollback_ten_steps_and_replay_bit_identical(exported):
    dt = MOTION.dt
    with FmuSlave(exported.structure, "s") as s, FmuSlave(exported.soil, "g") as g:
        s.initialize()
        g.initialize()
        for k in range(1, 81):                                # into the uplift phase
            _gs_step(s, g, k, dt)
        saved = [f.serialize(f.get_state()) for f in (s, g)]  # full state, through bytes
        first = [_gs_step(s, g, k, dt) for k in range(81, 91)]
        for f, blob in zip((s, g), saved):
            f.set_state(f.deserialize(blob))
        replay = [_gs_step(s, g, k, dt) for k in range(81, 91)]
    assert np.abs(first[-1][:6]).max() > 0 and np.any(np.concatenate(first) != 0)
    for a, b in zip(first, replay):
        assert np.array_equal(a, b)                           # bit-identical


def test_fmus_of_one_export_open_one_after_another(exported):
    """Each FMU carries the same bundled code, loaded once per process: an FMU opened after
    another one was freed (its folder deleted) still loads and runs."""
    for path in (exported.soil, exported.structure, exported.coupled, exported.soil):
        with FmuSlave(path, path.stem) as f:
            f.initialize()
            f.do_step(0.0, MOTION.dt)
