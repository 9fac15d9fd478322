"""The exported FMUs give the monolithic route's answer in every engine that runs them:

- libcosim (Open Simulation Platform, through libcosimpy) on ``system.ssd`` as it is: its
  fixed-step algorithm steps both FMUs in parallel (Jacobi);
- fmpy's SSP runner (``simulate_ssp``) on ``system.ssp``: Jacobi too, with every connector
  starting at 0 (no exchange at initialisation);
- ``fmpy.simulate_fmu`` on ``coupled.fmu``, the whole system in one FMU.

Small scene (reactor stick on a 21-node raft over rock, a pulse along x, y and z at once that
lifts the raft by 52 mm and rocks it about both axes),
histories and the FMUs' headline outputs (running max uplift and raft rotation) to 1e-10.
"""
import numpy as np
import pytest

from helpers import pulse_motion, rel, rocks_about_both_axes, small_scene, soil_model
from orchestrator.export import export_scene
from orchestrator.routes.monolithic import run_monolithic

SCENE = small_scene()
MODEL = soil_model(SCENE)
MOTION = pulse_motion(T=1.0, y=0.5)          # x, y and z at once
N = SCENE.mesh.xy.shape[0]


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    exp = export_scene(SCENE, tmp_path_factory.mktemp("engines"), MODEL, motion=MOTION, kind="python")
    mono = run_monolithic(SCENE, MOTION, MODEL)
    assert mono.converged and mono.max_uplift() > 1e-2 and rocks_about_both_axes(mono)
    return exp, mono


def max_rotation(res):
    return np.hypot(res.raft[:, 3], res.raft[:, 4]).max()


def test_libcosim_on_the_ssd(case):
    libcosimpy = pytest.importorskip("libcosimpy", reason="libcosimpy is not installed (the 'test' extra)")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    exp, mono = case
    log_output_level(CosimLogLevel.WARNING)
    ex = CosimExecution.from_ssp_file(str(exp.ssd))          # step size from the SSD's algorithm
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    si = ex.slave_index_from_instance_name("structure")
    refs = {v.name.decode(): v.reference for v in ex.slave_variables(si)}
    vr = [refs[f"x[{i}]"] for i in range(6)] + [refs[f"gap[{i}]"] for i in range(N)] + \
        [refs["max_uplift"], refs["max_raft_rotation"]]
    out = []
    for _ in range(mono.nt - 1):
        assert ex.step(1)
        out.append(obs.last_real_values(si, vr))
    out = np.array(out)
    assert libcosimpy is not None
    assert rel(out[:, :6], mono.raft[1:]) <= 1e-10
    assert rel(out[:, 6:6 + N], mono.gap[1:]) <= 1e-10
    assert out[-1, -2] == pytest.approx(mono.max_uplift(), rel=1e-10)
    assert out[-1, -1] == pytest.approx(max_rotation(mono), rel=1e-10)


def test_fmpy_ssp_runner_on_the_ssp(case):
    from fmpy.ssp.simulation import simulate_ssp
    exp, mono = case
    res = simulate_ssp(str(exp.ssp), stop_time=exp.stop_time, step_size=exp.dt)
    assert res["structure.max_uplift"][-1] == pytest.approx(mono.max_uplift(), rel=1e-10)
    assert res["structure.max_raft_rotation"][-1] == pytest.approx(max_rotation(mono), rel=1e-10)
    assert rel(res["structure.x[0]"][:mono.nt - 1], mono.raft[1:, 0]) <= 1e-10


def test_fmpy_simulate_fmu_on_the_coupled_fmu(case):
    from fmpy import simulate_fmu
    exp, mono = case
    names = ["max_uplift", "max_raft_rotation"] + [f"x[{i}]" for i in range(6)]
    res = simulate_fmu(str(exp.coupled), output=names)          # DefaultExperiment: the record at dt
    assert res["time"][-1] == pytest.approx(exp.stop_time)
    assert res["max_uplift"][-1] == pytest.approx(mono.max_uplift(), rel=1e-10)
    assert res["max_raft_rotation"][-1] == pytest.approx(max_rotation(mono), rel=1e-10)
    raft = np.column_stack([res[f"x[{i}]"] for i in range(6)])
    assert raft.shape == mono.raft.shape and rel(raft, mono.raft) <= 1e-10


def test_coupled_fmu_takes_a_multiple_of_its_step(case):
    """fmpy.simulate_fmu doubles its communication step while a run has more than 1000 of them:
    the coupled FMU then steps its own dt inside, with the same answer."""
    from fmpy import simulate_fmu
    exp, mono = case
    res = simulate_fmu(str(exp.coupled), output=["max_uplift"], output_interval=4 * exp.dt)
    assert res["time"][-1] == pytest.approx(exp.stop_time)
    assert res["max_uplift"][-1] == pytest.approx(mono.max_uplift(), rel=1e-10)


def test_pair_fmu_refuses_another_step(case):
    """The pair exchanges its coupling every dt: a structure FMU driven with 2 dt says so."""
    from fmpy import simulate_fmu
    exp, _ = case
    with pytest.raises(Exception, match="fmi2DoStep failed with status 4"):
        simulate_fmu(str(exp.structure), output=["max_uplift"], output_interval=2 * exp.dt)


@pytest.fixture(scope="module")
def mono_export_motion():
    from helpers import EXPORT_MOTION
    return run_monolithic(SCENE, EXPORT_MOTION, MODEL)


@pytest.mark.parametrize("kind", ["python", "native"])
@pytest.mark.parametrize("drift", [0.0, -1e-13])
def test_omsimulator_stepping_of_the_ssp(exported, exported_native, mono_export_motion, tmp_path, kind, drift):
    """What OMSimulator does with system.ssp (its fixed-step master, read from the annotation):
    the stop time given to fmi2SetupExperiment, both FMUs stepped from the outputs at t
    (Jacobi), the time accumulated by repeated addition of its step h and the last step
    min(h, stop - t). With h = dt the accumulated time overshoots by round-off; with
    h = dt (1 - 1e-13) (a host whose step is dt to round-off, as OMSimulator's accumulated time
    2.499999999999969 s at a stop of 2.5 s) each step is taken as dt and the run ends with a
    sliver step of about 6e-14 s, a no-op. The structure's outputs: the monolithic route to 1e-8."""
    import xml.etree.ElementTree as ET
    import zipfile
    from orchestrator.export import OMS, SSC, SSD
    from orchestrator.master import FmuSlave

    exp = {"python": exported, "native": exported_native}[kind]
    mono = mono_export_motion
    with zipfile.ZipFile(exp.ssp) as z:
        z.extractall(tmp_path)
    root = ET.parse(tmp_path / "SystemStructure.ssd").getroot()
    master = root.find(f"./{{{SSD}}}System/{{{SSD}}}Annotations/{{{SSC}}}Annotation/{{{OMS}}}Annotations/"
                       f"{{{OMS}}}SimulationInformation/{{{OMS}}}FixedStepMaster")
    h = float(master.get("stepSize")) * (1 + drift)
    assert master.get("description") == "oms-ma" and h == pytest.approx(exp.dt, rel=1e-12)
    stop = float(root.find(f"{{{SSD}}}DefaultExperiment").get("stopTime"))
    sources = {c.get("name"): tmp_path / c.get("source") for c in root.iter(f"{{{SSD}}}Component")}
    links = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
             for c in root.iter(f"{{{SSD}}}Connection")]
    slaves = {name: FmuSlave(src, name) for name, src in sources.items()}
    try:
        for s in slaves.values():
            s.initialize(stop_time=stop)
        t, rows, slivers = 0.0, [slaves["structure"].get("x").copy()[:6]], 0
        while t < stop:
            step = min(h, stop - t)
            values = [slaves[a].fmu.getReal([slaves[a].vars[va].valueReference])[0] for a, va, _, _ in links]
            for (_, _, b, vb), value in zip(links, values):                    # outputs at t to inputs
                slaves[b].fmu.setReal([slaves[b].vars[vb].valueReference], [value])
            for s in slaves.values():
                s.do_step(t, step)
            slivers += step < 1e-6 * exp.dt
            t += step
            if step >= 1e-6 * exp.dt:
                rows.append(slaves["structure"].get("x").copy()[:6])
        final = slaves["structure"].get("max_uplift", "max_raft_rotation").copy()
    finally:
        for s in slaves.values():
            s.close()
    assert slivers == (1 if drift else 0)
    assert rel(np.array(rows), mono.raft) <= 1e-8
    assert final[0] == pytest.approx(mono.max_uplift(), rel=1e-8, abs=1e-15)
    assert final[1] == pytest.approx(max_rotation(mono), rel=1e-8)
