"""The monolithic route's fast path: the C runtime in process (fmus/native_stepper.py) against the
Python stepper (structure.simulate), its readable reference.

"Equal" is sensitivity-aware (tests/helpers/roundoff.py): where the raft lifts, each history is
held to max(1e-10, 100 x its round-off spread), the spread measured on the Python stepper's run
repeated with the ground motion scaled by 1 + k 1e-14 (k = 1, -1, 2); the bonded raft (linear:
no amplification) is held to a fixed 1e-10.

- the bonded raft: raft, gap, contact force, soil, node accelerations and displacements and
  every energy history to 1e-10 of their largest value;
- a run with uplift, forced through Newton at every step (precheck off): every history within
  its round-off spread; the same with step halving (Newton limited to 2 iterations): the same
  steps halved;
- ``run_monolithic``'s default (native) against ``stepper="python"`` (whose linear pre-check
  runs the closed-contact recursion until the contact opens): within the spread;
- a soil model whose E is not symmetric (the dense products, not the packed ones): within the
  spread;
- a step that cannot converge: the same step and message as the Python stepper, the samples
  before it (to 1e-10) returned with status STOPPED;
- the run stepped in chunks of 1, 7 and nt samples: the same bits as ``up_simulate``'s one
  call (with step halving, and up to a step that fails); the gaps-only run of the time-step check;
- the winkler route on the native stepper (the springs as a rational model without pole) for
  every calibration (rigid or nodal springs, RCC-G or dashpots, explicit moduli) against its
  Python stepper, with uplift: within the spread;
- without a compiler the monolithic and winkler routes run the Python stepper and say so (a
  warning, not an error);
- the library's vector width does not change a bit of the answer (baseline SSE2 build against
  the one with AVX2/AVX-512 kernels); the widest kernels the CPU has are the ones that run, built
  by the system compiler and by zig's (whose runtime's CPU test reports no feature);
- the cosim route runs the native pair by default (the Python pair as an option): the native
  pair equals the monolithic route to 1e-10 (the same C stepper), the Python pair within the
  spread;
- the run's step-doubling check on the proxy springs (the native stepper where available):
  its two max uplifts equal the Python stepper's to 1e-10.

About 20 s on an idle machine (the library is compiled once per content hash into the cache
folder); the spreads' 9 x 3 perturbed runs of the Python stepper add 14 s on 2 busy cores.
"""
import ctypes
import dataclasses
import shutil
import subprocess
import sys

import numpy as np
import pytest

from helpers import pulse_motion, rel, small_reactor, small_scene, soil_model
from helpers.native import seed_native
from helpers.roundoff import assert_within_spread, roundoff_spread
from fmus import native_stepper
from fmus.native_build import NATIVE, NativeBuildError, encode_resources, soil_records, stepper_records
from fmus.resources import soil_from_model
from fmus.schema import ENERGY_TERMS, row_slices, row_width
from orchestrator.routes.monolithic import STEPPERS, run_monolithic
from orchestrator.run import prepare_run, run_scene
from orchestrator.scene import scene_from_dict
from structure import ConvergenceError, NewmarkStepper, simulate
from structure.results import Status

SCENE = small_scene()
MODEL = soil_model(SCENE)
MOTION = pulse_motion(T=1.0)
DT = MOTION.dt

pytestmark = pytest.mark.skipif(native_stepper.library() is None, reason="no C compiler for the native stepper")


def assert_same_histories(res, ref, tol=1e-10):
    """Every history of ``res`` to ``tol`` of ``ref`` (a fixed tolerance: the mild scenes)."""
    assert res.time.shape == ref.time.shape
    for name in ("raft", "gap", "contact_force", "soil_w"):
        assert rel(getattr(res, name), getattr(ref, name)) <= tol, name
    for nm in ref.acc:
        assert rel(res.acc[nm], ref.acc[nm]) <= tol and rel(res.disp[nm], ref.disp[nm]) <= tol, nm
    for key in ref.energy:
        assert rel(res.energy[key], ref.energy[key]) <= tol, key


def python_run(contact, model=MODEL):
    """ag -> the Python stepper's run of SCENE on ``model`` under ag with these contact settings."""
    return lambda ag: simulate(SCENE.model(), soil_from_model(model, DT), ag, DT, contact=contact,
                               output_nodes=SCENE.output.nodes)


def both(contact, lib=None):
    """(native, python) results of SCENE on MODEL under MOTION with these contact settings."""
    st = NewmarkStepper(SCENE.model(), soil_from_model(MODEL, DT), DT, contact=contact, external_soil=True,
                        ag0=MOTION.acc[0])
    fast = native_stepper.simulate_native(st, MOTION.acc, SCENE.output.nodes, lib=lib)
    return fast, python_run(contact)(MOTION.acc)


def test_native_stepper_equals_the_python_stepper_on_the_bonded_raft():
    """The mild scene: no contact to open, nothing amplifies round-off; a fixed 1e-10."""
    fast, ref = both(dataclasses.replace(SCENE.contact, enabled=False))
    assert ref.max_uplift() == 0.0 and np.abs(ref.raft).max() > 0
    assert_same_histories(fast, ref)


@pytest.mark.parametrize("max_iter", [50, 2])
def test_native_stepper_equals_the_python_stepper(max_iter):
    contact = dataclasses.replace(SCENE.contact, max_iter=max_iter, precheck=False)
    fast, ref = both(contact)
    assert ref.max_uplift() > 1e-3                                 # the raft lifts off
    assert_within_spread(fast, ref, roundoff_spread(python_run(contact), MOTION.acc, base=ref))
    halved = ref.info["subdivided_steps"]
    assert fast.info["subdivided_steps"] == halved and (halved > 0) == (max_iter == 2)
    assert fast.info["stepper"] == "native"


def python_route(ag):
    """The monolithic route's Python stepper on SCENE, MODEL under ag (with its linear pre-check)."""
    return run_monolithic(SCENE, dataclasses.replace(MOTION, acc=ag), MODEL, stepper="python")


@pytest.fixture(scope="module")
def route_spread():
    """The round-off spread of the monolithic route's Python run of SCENE under MOTION."""
    return roundoff_spread(python_route, MOTION.acc)


def test_route_default_equals_the_python_route(route_spread):
    fast = run_monolithic(SCENE, MOTION, MODEL)
    ref = run_monolithic(SCENE, MOTION, MODEL, stepper="python")
    assert fast.info["stepper"] == "native" and ref.info["stepper"] == "python"
    assert fast.route == ref.route == "monolithic" and fast.converged
    assert_within_spread(fast, ref, route_spread)


def test_a_soil_model_without_symmetry_runs_the_dense_products():
    """E made slightly unsymmetric (a skew part: its quadratic form, so passivity, unchanged): the
    system's matrices held dense, not packed; the same answer as the Python stepper."""
    rng = np.random.default_rng(1)
    A = 1e-6 * np.abs(MODEL.E).max() * rng.standard_normal(MODEL.E.shape)
    model = dataclasses.replace(MODEL, E=MODEL.E + (A - A.T))
    assert not np.array_equal(model.E, model.E.T)
    contact = dataclasses.replace(SCENE.contact, precheck=False)
    st = NewmarkStepper(SCENE.model(), soil_from_model(model, DT), DT, contact=contact, external_soil=True,
                        ag0=MOTION.acc[0])
    fast = native_stepper.simulate_native(st, MOTION.acc, SCENE.output.nodes)
    ref = python_run(contact, model)(MOTION.acc)
    assert ref.max_uplift() > 1e-3
    assert_within_spread(fast, ref, roundoff_spread(python_run(contact, model), MOTION.acc, base=ref))

def test_a_step_that_cannot_converge_stops_where_the_python_stepper_stops():
    contact = dataclasses.replace(SCENE.contact, max_iter=1, max_subdiv=2, precheck=False)
    st = NewmarkStepper(SCENE.model(), soil_from_model(MODEL, DT), DT, contact=contact, external_soil=True,
                        ag0=MOTION.acc[0])
    with pytest.raises(ConvergenceError) as fast:
        native_stepper.simulate_native(st, MOTION.acc, SCENE.output.nodes)
    with pytest.raises(ConvergenceError) as ref:
        simulate(SCENE.model(), soil_from_model(MODEL, DT), MOTION.acc, DT, contact=contact,
                 output_nodes=SCENE.output.nodes)
    f, r = fast.value.result, ref.value.result
    assert str(fast.value) == str(ref.value) and f.status == Status.STOPPED and f.nt == r.nt > 1
    assert_same_histories(f, r)


def one_call(st, ag, nodes):
    """(rows, iters, stats, rc) of ``up_simulate``: the whole run in one call of the C runtime."""
    model = st.model
    dofs = [model.dofs(model.node_by_name(nm).id)[:3] for nm in nodes]
    blob = encode_resources({**soil_records(st.soil.model, st.dt), **stepper_records(st, dofs)})
    nt = ag.shape[0]
    rows, iters, stats = np.zeros((nt, row_width(st.N, len(dofs)))), np.zeros(nt, np.int64), np.zeros(3, np.int64)
    ag = np.ascontiguousarray(ag)
    rc = native_stepper.library().up_simulate(blob, len(blob), ag.ctypes.data, nt, rows.ctypes.data, iters.ctypes.data,
                                           stats.ctypes.data, ctypes.create_string_buffer(1024))
    return rows, iters, stats, rc


@pytest.mark.parametrize("max_iter, max_subdiv", [(2, 20), (1, 2)])      # halved steps; a step that fails
def test_chunks_give_the_same_bits_as_one_call(max_iter, max_subdiv):
    contact = dataclasses.replace(SCENE.contact, max_iter=max_iter, max_subdiv=max_subdiv, precheck=False)
    nodes = SCENE.output.nodes

    def stepper():
        return NewmarkStepper(SCENE.model(), soil_from_model(MODEL, DT), DT, contact=contact, external_soil=True,
                              ag0=MOTION.acc[0])
    rows, iters, stats, rc = one_call(stepper(), MOTION.acc, nodes)
    nt, N = MOTION.acc.shape[0], stepper().N
    assert rc == (0 if max_subdiv == 20 else 1) and (stats[2] > 0 if rc == 0 else 1 < stats[0] < nt)
    k = int(stats[0])
    for chunk in (1, 7, nt):
        try:
            res = native_stepper.simulate_native(stepper(), MOTION.acc, nodes, chunk=chunk)
        except ConvergenceError as exc:
            res = exc.result
        assert res.nt == k and res.info["subdivided_steps"] == stats[2]
        assert np.array_equal(res.raft, rows[:k, :6]) and np.array_equal(res.gap, rows[:k, 6:6 + N])
        assert np.array_equal(res.contact_force, rows[:k, 6 + N:6 + 2 * N])
        assert np.array_equal(res.soil_w, rows[:k, 6 + 2 * N:6 + 3 * N])
        for j, nm in enumerate(nodes):
            node = rows[:k, 6 + 3 * N + 6 * j:6 + 3 * N + 6 * j + 6]
            assert np.array_equal(res.acc[nm], node[:, :3]) and np.array_equal(res.disp[nm], node[:, 3:])
        assert list(res.energy) == list(ENERGY_TERMS)
        assert np.array_equal(np.column_stack(list(res.energy.values())), rows[:k, row_slices(N, len(nodes))["energy"]])
        assert np.array_equal(res.newton_iters, iters[:k])
    top = native_stepper.native_max_uplift(stepper(), MOTION.acc)       # the gaps only: NaN after a failed step
    assert (np.isnan(top) if rc else top == rows[:, 6:6 + N].max())


@pytest.mark.parametrize("nodes", [(), ("top_outer", "internals_37m")])
def test_the_row_layout_is_the_schemas(nodes):
    """The row width the C runtime writes (simulate.c: UP_ROW_WIDTH of uplift_schema.h) is the
    schema's, read from the compiled library."""
    st = NewmarkStepper(SCENE.model(), soil_from_model(MODEL, DT), DT, contact=SCENE.contact, external_soil=True,
                        ag0=MOTION.acc[0])
    blob, lib = native_stepper.encode_run(st, nodes), native_stepper.library()
    handle = lib.up_sim_open(blob, len(blob), np.ascontiguousarray(MOTION.acc).ctypes.data,
                             ctypes.create_string_buffer(1024))
    assert handle
    try:
        assert lib.up_sim_width(handle) == row_width(st.N, len(nodes)) == 6 + 3 * st.N + 6 * len(nodes) + 7
    finally:
        lib.up_sim_close(handle)


@pytest.mark.parametrize("winkler", [
    {"springs": "rigid"},                                              # rocking matched, RCC-G damping
    {"springs": "rigid", "match": "vertical", "damping": "dashpots"},
    {"springs": "nodal"},
    {"springs": "nodal", "damping": "dashpots"},
    {"kv": 2.0e9, "kh": 1.5e9, "cv": 5.0e6, "ch": 4.0e6},                 # explicit moduli: the model's damping
])
def test_winkler_route_native_equals_python(winkler):
    scene = scene_from_dict(small_reactor(soil={"winkler": winkler}, impedance={"range_hz": [0.0, 20.0, 5]},
                                          analysis={"routes": ["winkler"]}), name="wk")
    shared = prepare_run(scene)

    def run(stepper, ag=MOTION.acc):
        return run_scene(scene, motion=dataclasses.replace(MOTION, acc=ag), shared=shared,
                         options={"winkler": {"stepper": stepper}})[0]["winkler"]
    fast, ref = (run(stepper) for stepper in STEPPERS)
    assert fast.info["stepper"] == "native" and ref.info["stepper"] == "python"
    assert fast.converged and ref.converged and ref.max_uplift() > 1e-3 and ref.route == fast.route == "winkler"
    assert_within_spread(fast, ref, roundoff_spread(lambda ag: run("python", ag), MOTION.acc, base=ref))
    assert fast.notes.warnings == ref.notes.warnings


def test_without_a_compiler_the_python_stepper_runs_with_a_note(monkeypatch, tmp_path):
    def no_compiler(folder):
        raise NativeBuildError("no C compiler: neither $CC / cc nor the ziglang package")

    monkeypatch.setenv("UPLIFT_CACHE", str(tmp_path))
    monkeypatch.setattr(native_stepper, "_build", no_compiler)
    mono = run_monolithic(SCENE, MOTION, MODEL, cache_dir=tmp_path)
    scene = scene_from_dict(small_reactor(soil={"winkler": {"kv": 2.0e9, "kh": 1.5e9}}, impedance=None,
                                          analysis={"routes": ["winkler"]}), name="wk")
    wink = run_scene(scene, cache_dir=tmp_path, motion=MOTION)[0]["winkler"]
    for res in (mono, wink):
        assert res.converged and res.info["stepper"] == "python"
        assert any("native stepper is not available" in w and "Python stepper ran" in w for w in res.notes.warnings)


def test_an_unknown_stepper_is_refused_with_the_choices(tmp_path):
    scene = scene_from_dict(small_reactor(soil={"winkler": {"kv": 2.0e9, "kh": 1.5e9}}, impedance=None,
                                          analysis={"routes": ["winkler"]}), name="wk")
    res = run_scene(scene, cache_dir=seed_native(tmp_path), motion=MOTION,
                    options={"winkler": {"stepper": "fast"}})[0]["winkler"]
    assert res.status is Status.REFUSED and "stepper = 'fast'" in res.message and "native, python" in res.message


@pytest.mark.skipif(shutil.which("cc") is None, reason="needs the system compiler")
@pytest.mark.parametrize("narrow", ["-DUP_BASELINE_ONLY", "-DUP_MAX_LEVEL=1"])   # the baseline, at most AVX2
def test_the_vector_width_does_not_change_the_answer(tmp_path, narrow):
    """The library at the widest width this CPU has against a build held to a narrower one: the
    same bits (on an AVX-512 machine the three widths are compared)."""
    contact = dataclasses.replace(SCENE.contact, precheck=False)
    lib = tmp_path / "narrow.so"
    subprocess.run(["cc", "-std=c99", "-O3", "-ffp-contract=off", "-fvisibility=hidden", "-fPIC", "-shared",
                    narrow, f"-I{NATIVE / 'include'}", "-o", str(lib),
                    *(str(NATIVE / s) for s in native_stepper.HOST_SOURCES), "-lm"], check=True)
    other = native_stepper.declare(ctypes.CDLL(str(lib)))
    wide, _ = both(contact)
    base, _ = both(contact, lib=other)
    assert np.array_equal(wide.raft, base.raft) and np.array_equal(wide.gap, base.gap)
    assert all(np.array_equal(wide.acc[nm], base.acc[nm]) for nm in wide.acc)


def _cpu_flags() -> set:
    try:
        with open("/proc/cpuinfo") as f:
            return next((set(line.split(":", 1)[1].split()) for line in f if line.startswith("flags")), set())
    except OSError:
        return set()


@pytest.mark.skipif(not _cpu_flags(), reason="needs Linux x86-64 (/proc/cpuinfo)")
@pytest.mark.parametrize("compiler", ["cc", "zig"])
def test_the_wide_kernels_run_where_the_cpu_has_them(tmp_path, compiler):
    flags = _cpu_flags()
    want = 2 if "avx512f" in flags else 1 if "avx2" in flags else 0
    main = tmp_path / "main.c"
    main.write_text('#include <stdio.h>\nint up_vector_level(void);\n'
                    'int main(void) { printf("%d\\n", up_vector_level()); return 0; }\n')
    exe = tmp_path / "level"
    if compiler == "zig":
        pytest.importorskip("ziglang")
        cmd = [sys.executable, "-m", "ziglang", "cc", "-target", "x86_64-linux-gnu.2.17"]
    elif shutil.which("cc"):
        cmd = ["cc"]
    else:
        pytest.skip("needs the system compiler")
    for cap, level in (([], want), (["-DUP_MAX_LEVEL=1"], min(want, 1))):    # the width test's AVX2 build
        subprocess.run([*cmd, "-std=c99", "-O3", "-ffp-contract=off", *cap, f"-I{NATIVE / 'include'}", "-o",
                        str(exe), str(main), str(NATIVE / "linalg.c"), "-lm"], check=True, cwd=tmp_path)
        assert int(subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout) == level

def test_cosim_route_runs_the_native_pair_by_default(route_spread):
    from orchestrator.routes.cosim import run_cosim
    mono = run_monolithic(SCENE, MOTION, MODEL)
    native = run_cosim(SCENE, MOTION, MODEL)
    python = run_cosim(SCENE, MOTION, MODEL, kind="python")
    assert native.info["fmu_kind"] == "native" and python.info["fmu_kind"] == "python"
    assert native.max_uplift() > 1e-3
    assert_same_histories(native, mono)
    assert_within_spread(python, mono, route_spread)


def test_step_doubling_check_on_the_native_stepper_equals_the_python_one(monkeypatch):
    from orchestrator.run import proxy_springs, step_doubling
    model, springs = SCENE.model(), proxy_springs(SCENE, True)
    fast = step_doubling(SCENE, model, springs, MOTION)
    monkeypatch.setattr(native_stepper, "library", lambda folder=None: None)     # no compiler: simulate runs
    ref = step_doubling(SCENE, model, springs, MOTION)
    assert ref["max_uplift_m"] > 1e-3
    for key in ("max_uplift_m", "max_uplift_half_dt_m"):
        assert fast[key] == pytest.approx(ref[key], rel=1e-10, abs=0.0)
