"""A plate raft on the native stepper (fmus/native/stepper.c's plate trace: the boundary block
[q, t, w], the contact d = Bc [q, t, w] through each node's few vertex weights, the soil on
[q, w] only) against the Python plate stepper (structure.plate_raft.PlateStepper), its reference.

Scene: the reactor sticks on a 2 m concrete plate (61 interface nodes, 80 plate vertices, the
held region within 10 m of the centre) over the rock's springs and dashpots with two Maxwell
terms, a pulse along x, y and z that lifts 87 % of the raft by up to 7 cm. "Equal": each history (raft, gap,
contact force, soil, nodes, energies and the plate's deflections at its vertices and nodes)
within max(1e-10, 100 x its round-off spread), the spread measured on the Python stepper under
the motion scaled by 1 + k 1e-14 (tests/helpers/roundoff.py); the Newton counts and the halved
steps identical. With Newton limited to 3 iterations, 5 steps are halved (the state saved and
restored, the soil's levels): the same steps (with 2 iterations a step at t = 0.94 s converges in
2 on one stepper and not on the other, a choice at round-off that no tolerance can follow). Bonded (contact off, linear): 1e-10 (measured
5e-12: the plate's stiff bending against the soil conditions the solves worse than a rigid raft's;
under test_cosim_plate.py's stronger pulse, pga 6 m/s^2, the two differ by 1.8e-9 on soil w, twice
that tolerance: the two steppers' per-step round-off, amplified by 88 % uplift).

About 50 s on two busy cores, most of it compiling the runtime three times (the in-process
library, the FMI 2.0 runtime of the cosim route, the FMI 3.0 one; each once per process or build);
the native runs take 0.3 s, the Python stepper's 1.3 s.
"""
import dataclasses

import numpy as np
import pytest

from helpers import pulse_motion, rel, soil_model
from helpers.roundoff import assert_within_spread, histories, roundoff_spread
from helpers.winkler import NU, R, RHO
from fmus import native_stepper
from fmus.native_build import stepper_records
from fmus.resources import soil_from_model
from orchestrator.routes.monolithic import run_monolithic
from orchestrator.scene import scene_from_dict
from structure.plate_raft import PlateStepper

PLATE = {"kind": "plate", "thickness": 2.0, "E": 30e9, "nu": 0.2, "rho": 2500.0}
RIGID = {
    "soil": {"halfspace": {"vs": 1600.0, "nu": NU, "rho": RHO}},
    "foundation": {"shape": "circle", "radius": R, "element_size": 4.6},
    "structure": {"model": "reactor", "damping": {"modal": 0.07}},
    "contact": {"enabled": True},
    "analysis": {"dt": 0.005, "routes": ["monolithic"]},
    "output": {"nodes": ["top_outer", "internals_37m"]},
}
SCENE = scene_from_dict({**RIGID, "foundation": {**RIGID["foundation"], "raft": PLATE}}, name="plate")
MODEL = soil_model(SCENE)
MOTION = pulse_motion(0.005, 1.0, pga=4.0, tp=0.5, y=0.5)

pytestmark = pytest.mark.skipif(native_stepper.library() is None, reason="no C compiler for the native stepper")


def plate_histories(res) -> dict:
    """The compared histories with the plate's deflections."""
    return {**histories(res), "plate_deflection": res.plate_deflection,
            "plate_vertex_deflection": res.plate_vertex_deflection}


def run(stepper, contact=None, ag=None):
    """The monolithic route on ``stepper`` (None: its default)."""
    sc = SCENE if contact is None else dataclasses.replace(SCENE, contact=contact)
    motion = MOTION if ag is None else dataclasses.replace(MOTION, acc=ag)
    return run_monolithic(sc, motion, MODEL, **({} if stepper is None else {"stepper": stepper}))


def test_the_plate_s_records_are_its_trace():
    """The records the C stepper reads: the plate's DOFs in ns, its free vertices, each node's
    trace on [q, t] (at most 3 on q and 4 vertices), Bq3 unused (zero)."""
    pm = SCENE.plate_model()
    st = PlateStepper(pm, soil_from_model(MODEL, MOTION.dt), MOTION.dt, contact=SCENE.contact, external_soil=True)
    recs = stepper_records(st, [])
    assert recs["ns"] == pm.n_dof - pm.n_interface and recs["plate_nf"] == pm.nf
    col, val = recs["plate_trace_col"], recs["plate_trace_val"]
    assert col.shape[1] <= 7 and col.max() < 6 + pm.nf and not recs["Bq3"].any()
    Bc = np.zeros((pm.n_interface, pm.nb))
    for i in range(pm.n_interface):
        on = col[i] >= 0
        Bc[i, col[i, on]] = val[i, on]
        Bc[i, 6 + pm.nf + i] = -1.0
    assert np.array_equal(Bc, pm.boundary_trace.toarray())


def test_the_test_plate_takes_the_banded_interior():
    """stepper.c condenses a plate's interior (the sticks, the free vertices' rotations) by a
    banded Cholesky when Ks and Cs are symmetric and 4 (band + 1) <= ni (plate_band_init): this
    file's scene is such a plate, so the equalities below hold the banded path to the Python
    stepper (its sparse LU). The interior's two blocks do not couple and are narrow."""
    pm = SCENE.plate_model()
    st = PlateStepper(pm, soil_from_model(MODEL, MOTION.dt), MOTION.dt, contact=SCENE.contact, external_soil=True)
    recs = stepper_records(st, [])
    ns, nf = int(recs["ns"]), int(recs["plate_nf"])
    ni = ns - 6 - nf
    Ks, Cs = recs["Ks"], recs["Cs"]
    for A in (Ks, Cs):                                # symmetric to round-off (stepper.c's symmetric())
        assert np.abs(A - A.T).max() <= 1e-13 * np.abs(A).max()
    rows, cols = np.nonzero((Ks[:ni, :ni] != 0) | (Cs[:ni, :ni] != 0))
    band = int(np.max(rows - cols))
    assert 4 * (band + 1) <= ni, (band, ni)
    sticks = ni - 2 * nf                              # the sticks' DOFs, then the rotations
    assert not Ks[:sticks, sticks:ni].any() and not Cs[:sticks, sticks:ni].any()


@pytest.mark.parametrize("max_iter", [50, 3])          # 2 s each: the Python stepper's 4 runs (the spread)
def test_native_plate_stepper_equals_the_python_plate_stepper(max_iter):
    contact = dataclasses.replace(SCENE.contact, max_iter=max_iter, precheck=False)
    ref = run("python", contact)
    fast = run("native", contact)
    assert ref.info["stepper"] == "python" and fast.info["stepper"] == "native" and not fast.notes.warnings
    assert ref.converged and fast.converged and ref.max_uplift() > 1e-2
    halved = ref.info["subdivided_steps"]
    assert fast.info["subdivided_steps"] == halved and (halved > 0) == (max_iter == 3)
    assert np.array_equal(fast.newton_iters, ref.newton_iters)
    spread = roundoff_spread(lambda ag: plate_histories(run("python", contact, ag)), MOTION.acc,
                             base=plate_histories(ref))
    checks = assert_within_spread(plate_histories(fast), plate_histories(ref), spread)
    # measured 5e-10 (max_iter 50), 2.6e-8 (3: the halved steps' larger spread)
    assert checks["plate_vertex_deflection"][0] < (1e-8 if max_iter == 50 else 1e-6)
    assert fast.plate_vertices.shape == (SCENE.plate_model().n_vertices, 2)


def test_bonded_native_plate_equals_python_to_1e10():
    contact = dataclasses.replace(SCENE.contact, enabled=False)
    ref, fast = run("python", contact), run("native", contact)
    assert fast.info["stepper"] == "native"
    for name, a in plate_histories(ref).items():
        assert rel(plate_histories(fast)[name], a) <= 1e-10, name


# ---- the plate's results on the native stepper: moments, raft points, pressures, its damping -----
POINTS = {"edge": (18.0, 0.0), "mid": (-10.0, 5.0)}


def results_scene(ratio):
    """SCENE with the plate's damping ``ratio`` (at 10 Hz) and two raft points."""
    return dataclasses.replace(SCENE, raft=dataclasses.replace(SCENE.raft, damping=ratio),
                               output=dataclasses.replace(SCENE.output, raft_points=POINTS))


def result_histories(res) -> dict:
    """The compared histories with the plate's deflections, moments (at the stick base, their
    peaks over the plate) and the raft points' acc and disp (in ``histories``)."""
    return {**plate_histories(res), "plate_moment": res.plate_moment, "plate_moment_peak": res.plate_moment_peak}


def test_native_plate_results_equal_the_python_ones_on_a_damped_plate():
    """The native run's moments (static part included), raft points and contact forces (the
    pressures' numerators) against the Python stepper's within the round-off criterion, on a plate
    with its own damping 0.05 at 10 Hz: the damping reaches the C runtime (the undamped plate
    differs from it by far more than the tolerance)."""
    sc = results_scene(0.05)
    contact = dataclasses.replace(sc.contact, precheck=False)
    sc = dataclasses.replace(sc, contact=contact)
    go = lambda stepper, ag=MOTION.acc: run_monolithic(sc, dataclasses.replace(MOTION, acc=ag), MODEL,
                                                       stepper=stepper)
    ref, fast = go("python"), go("native")
    assert fast.info["stepper"] == "native" and not fast.notes.warnings and fast.converged
    assert ref.max_uplift() > 1e-2 and fast.info["raft_points"] == ref.info["raft_points"]
    for name in ("plate_vertices", "plate_moment_cells", "plate_vertex_held"):
        assert np.array_equal(getattr(fast, name), getattr(ref, name)), name
    spread = roundoff_spread(lambda ag: result_histories(go("python", ag)), MOTION.acc, base=result_histories(ref))
    checks = assert_within_spread(result_histories(fast), result_histories(ref), spread)
    # measured: moments 2.1e-9 (tolerance 4.5e-9), raft point 'edge' acc 8.1e-9 (4.6e-8), contact force
    # 9.7e-9 (2.1e-8); the undamped plate's moments differ from the damped ones by 5.8e-2
    assert max(checks["plate_moment"][0], checks["acc.edge"][0], checks["contact_force"][0]) < 1e-7
    # the moments at rest are the static state's (independent: the moment operator on the static
    # solution), not zero
    pm = sc.plate_model()
    st = PlateStepper(pm, soil_from_model(MODEL, MOTION.dt), MOTION.dt, contact=contact)
    M0 = (pm.moment_operator @ st.static.u).reshape(-1, 3)[pm.base_cells]
    assert np.abs(M0).max() > 1e3 and rel(fast.plate_moment[0], M0) < 1e-10
    # the plate's damping is in the native run: undamped, the moments move by far more
    bare = run_monolithic(dataclasses.replace(sc, raft=SCENE.raft), MOTION, MODEL, stepper="native")
    assert rel(bare.plate_moment, fast.plate_moment) > 1e3 * checks["plate_moment"][1]


def test_raft_points_of_a_rigid_raft_are_refused_by_the_native_stepper():
    from structure import NewmarkStepper, StructureError
    sc = scene_from_dict({**RIGID, "output": {"nodes": ["top_outer"]}}, name="rigid")
    st = NewmarkStepper(sc.model(), soil_from_model(MODEL, MOTION.dt), MOTION.dt, contact=sc.contact,
                        external_soil=True)
    with pytest.raises(StructureError, match="raft points need a plate raft"):
        native_stepper.simulate_native(st, MOTION.acc[:10], ["top_outer"], raft_points={"e": (1.0, 0.0)})


# ---- the native FMUs of a plate ------------------------------------------------------------------
@pytest.fixture(scope="module")
def native_mono():
    """(the monolithic route's native run (its default for a plate too), its round-off spread on
    the native stepper)."""
    mono = run(None)
    assert mono.converged and mono.info["stepper"] == "native" and mono.max_uplift() > 1e-2
    return mono, roundoff_spread(lambda ag: plate_histories(run("native", None, ag)), MOTION.acc,
                                 base=plate_histories(mono))


@pytest.mark.slow            # the FMU runtime compiled for this machine (once per process), the pair's export
def test_cosim_route_runs_the_native_pair_on_a_plate(native_mono):
    from orchestrator.routes.cosim import run_cosim
    mono, spread = native_mono
    cos = run_cosim(SCENE, MOTION, MODEL, schedule="jacobi")
    assert cos.info["fmu_kind"] == "native" and cos.converged and not cos.notes.warnings
    checks = assert_within_spread(cos, mono, spread)
    assert max(d for d, _ in checks.values()) < 1e-9            # measured 1.9e-10 (contact force)
    assert np.array_equal(cos.newton_iters, mono.newton_iters)
    assert cos.info["fmu_max_uplift"] == pytest.approx(mono.max_uplift(), rel=1e-9)


@pytest.mark.slow            # three FMUs built (FMI 3.0: the runtime compiled for this machine), validated and run
@pytest.mark.parametrize("fmi_version", [2, 3])
def test_exported_native_fmus_of_a_plate_validate_and_equal_monolithic(native_mono, fmi_version, tmp_path):
    """The export's FMUs (``export_scene`` builds them so, for every platform) for this machine
    only: FMI 2.0 on the runtime the cosim route compiles and caches, FMI 3.0 compiled by cc."""
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu
    from fmus.native_build import build_native_fmus
    from orchestrator.export import fmu_data
    from orchestrator.master import cosimulate
    mono, spread = native_mono
    data = fmu_data(SCENE, MODEL, MOTION.dt, MOTION)
    if fmi_version == 2:
        bins = native_stepper.fmu_binaries()
        fmus = build_native_fmus(data, tmp_path, coupled=True, platforms=tuple(bins), binaries=bins)
    else:
        fmus = build_native_fmus(data, tmp_path, coupled=True, fmi_version=3, platforms=("x86_64-linux",),
                                 compiler="cc")
    for fmu in fmus.values():
        assert validate_fmu(str(fmu)) == [], fmu
    cos = cosimulate(fmus["structure"], fmus["soil"], MOTION.acc, MOTION.dt, schedule="gauss-seidel")
    assert cos.converged and np.array_equal(cos.newton_iters, mono.newton_iters)
    assert_within_spread(cos, mono, spread)
    # the coupled FMU (the plate and the soil in one FMU, its bundled motion): the monolithic route
    if fmi_version == 3:                      # the interface vectors are arrays
        res = simulate_fmu(str(fmus["coupled"]), output=["x_raft_u", "x_raft_r", "gap", "max_uplift"])
        raft, gap = np.hstack([res["x_raft_u"], res["x_raft_r"]]), res["gap"]
    else:
        N = SCENE.mesh.n
        res = simulate_fmu(str(fmus["coupled"]), output=["max_uplift"] + [f"x[{i}]" for i in range(6)]
                           + [f"gap[{i}]" for i in range(N)])
        raft = np.column_stack([res[f"x[{i}]"] for i in range(6)])
        gap = np.column_stack([res[f"gap[{i}]"] for i in range(N)])
    assert rel(raft, mono.raft) <= spread.tol("raft") and rel(gap, mono.gap) <= spread.tol("gap")
    assert res["max_uplift"][-1] == pytest.approx(mono.max_uplift(), rel=1e-9)
