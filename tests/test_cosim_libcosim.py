"""The exported system (system.ssd) runs as it is in an independent engine, libcosim (Open
Simulation Platform, through libcosimpy), and matches our master's Jacobi schedule (libcosim's
fixed-step algorithm steps all FMUs in parallel) to 1e-10; its difference to our default
Gauss-Seidel schedule is the one-step coupling lag, reported here."""
import numpy as np
import pytest

libcosimpy = pytest.importorskip(
    "libcosimpy", reason="libcosimpy is not installed (optional: pip install libcosimpy, or the "
                         "'cosim' extra); it is the independent engine this test runs the SSP in")

from cosim_cases import pulse_motion, small_scene, soil_model            # noqa: E402
from orchestrator.export import export_scene                            # noqa: E402
from orchestrator.master import cosimulate                              # noqa: E402

SCENE = small_scene()
MOTION = pulse_motion(T=1.0)


def run_libcosim(ssd, nt):
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.WARNING)
    ex = CosimExecution.from_ssp_file(str(ssd))          # step size from the SSP's algorithm
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    si = ex.slave_index_from_instance_name("structure")
    refs = {v.name.decode(): v.reference for v in ex.slave_variables(si)}
    vr = [refs[f"x[{i}]"] for i in range(6)] + [refs[f"gap[{i}]"] for i in range(SCENE.mesh.xy.shape[0])]
    out = []
    for _ in range(nt - 1):
        assert ex.step(1)
        out.append(obs.last_real_values(si, vr))
    return np.array(out)


def test_ssp_in_libcosim_matches_jacobi(tmp_path):
    exp = export_scene(SCENE, tmp_path, soil_model(SCENE), motion=MOTION)
    nt = MOTION.acc.shape[0]
    lc = run_libcosim(exp.ssd, nt)
    jac = cosimulate(exp.structure, exp.soil, MOTION.acc, MOTION.dt, schedule="jacobi")
    gs = cosimulate(exp.structure, exp.soil, MOTION.acc, MOTION.dt)
    ref = np.hstack([jac.raft, jac.gap])[1:]
    assert jac.max_uplift() > 1e-2
    assert np.abs(lc - ref).max() <= 1e-10 * np.abs(ref).max()
    d_gs = np.abs(lc[:, :6] - gs.raft[1:]).max() / np.abs(gs.raft).max()
    print(f"libcosim (Jacobi) vs Gauss-Seidel: raft {d_gs:.3e} relative; max uplift "
          f"{lc[:, 6:].max():.5f} vs {gs.max_uplift():.5f} m")
    assert d_gs > 1e-6                  # Jacobi is not Gauss-Seidel: the lag is visible
