"""The native FMUs (C runtime, fmus/native): the variables of the Python FMUs, the answers of
the monolithic route and of the Python FMUs to round-off, no Python needed in the host.

Small scene (reactor stick on a 21-node raft over rock, a pulse along x, y and z at once
lifting the raft by 52 mm and rocking it about both axes, a rational soil with a history
force), exported once per module in both kinds. Checked:

- the model descriptions against the Python FMUs' (names, causalities, units, value
  references, start values) and fmpy's validator; SourceFiles and the sources in the FMU;
- the binaries of linux64 (dynamic section: libc and libm only), win64 (no Python DLL
  imported) and darwin64 (a Mach-O library), cross-compiled by zig;
- the pair under the project's master (Gauss-Seidel in either order, Jacobi), libcosim and
  fmpy's SSP runner, the coupled FMU under fmpy.simulate_fmu: the monolithic route to 1e-10;
  a native FMU beside a Python one (the Python structure FMU against the native monolithic
  route: two steppers) within the scene's round-off spread (tests/helpers/roundoff.py: the
  Python stepper's monolithic run under the motion scaled by 1 + k 1e-14; max(1e-10, 100 x the
  spread)), the soil alone on random inputs: the Python FMUs to 1e-10; the coupled FMU against
  the Python one within the spread (1e-9 on the outputs without one);
- step halving (Newton limited to 2 iterations): the coupled FMU against the in-process
  stepper, the pair against the in-process split coupling, to 1e-10; a step that cannot
  converge is refused with the stepper's message;
- a plain C program (tests/fmu/native/host.c: dlopen, no Python in the process) runs coupled.fmu
  (max uplift equal to monolithic to 1e-10, no allocation inside fmi2DoStep) and makes hostile
  calls (each refused with a status and a log message, the host survives), rolls back through
  a serialised state bit-identically; a damaged resource file is refused at instantiation.
"""
import dataclasses
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from helpers import assert_pair_rolls_back, pulse_motion, rel, rocks_about_both_axes, small_scene, soil_model
from helpers.c_host import compile_host, unpack_fmu
from helpers.roundoff import assert_within_spread, roundoff_spread
from fmus.schema import AG
from fmus.native_build import (PLATFORMS, SOURCES, build_native_fmus, decode_resources,
                               encode_resources, fmi_headers)
from orchestrator.export import export_scene, fmu_data
from orchestrator.master import FmuSlave, cosimulate
from orchestrator.routes.monolithic import run_monolithic

SCENE = small_scene()
MODEL = soil_model(SCENE)
MOTION = pulse_motion(T=1.0, y=0.5)          # x, y and z at once
DT = MOTION.dt
N = SCENE.mesh.xy.shape[0]
ROLES = ("structure", "soil", "coupled")


def max_rotation(res):
    return np.hypot(res.raft[:, 3], res.raft[:, 4]).max()


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """(native Export, python Export, monolithic RouteResult)."""
    tmp = tmp_path_factory.mktemp("native")
    nat = export_scene(SCENE, tmp / "native", MODEL, motion=MOTION, kind="native")
    py = export_scene(SCENE, tmp / "python", MODEL, motion=MOTION, kind="python")
    mono = run_monolithic(SCENE, MOTION, MODEL)
    assert mono.converged and mono.max_uplift() > 1e-2 and rocks_about_both_axes(mono)
    return nat, py, mono


@pytest.fixture(scope="module")
def spread():
    """The round-off spread of the scene: the monolithic route's Python stepper under MOTION
    scaled by 1 + k 1e-14 (the cheap path: in process, no FMU)."""
    return roundoff_spread(lambda ag: run_monolithic(SCENE, dataclasses.replace(MOTION, acc=ag), MODEL,
                                                     stepper="python"), MOTION.acc)


#: the Python FMUs' runs, in a fresh interpreter: a Python structure or coupled FMU instantiated
#: after another Python FMU of the same export was freed fails to import its bundled modules
#: (pythonfmu bundles them under one namespace per export), so every Python FMU is opened first
PY_RUNS = """
import sys
import numpy as np
from orchestrator.master import FmuSlave, cosimulate
args = dict(a.split("=", 1) for a in sys.argv[1:])
z = np.load(args["input"])
acc, dt, drive, names = z["acc"], float(z["dt"]), z["drive"], list(z["names"])
S, G, C, G2 = (FmuSlave(args[k], k) for k in ("py_structure", "py_soil", "py_coupled", "py_soil"))
out = {}
for key, pair in (("py_structure", (S, FmuSlave(args["nat_soil"], "ns"))),
                  ("py_soil", (FmuSlave(args["nat_structure"], "nS"), G))):
    res = cosimulate(*pair, acc, dt, schedule="jacobi")
    out[key] = np.hstack([res.raft, res.gap, res.contact_force, res.soil_w])
C.initialize()
rows = [C.get(*names).copy()]
for k in range(1, acc.shape[0]):
    C.do_step((k - 1) * dt, dt)
    rows.append(C.get(*names).copy())
out["py_coupled"] = np.array(rows)
G2.initialize()
soil = []
for k, u in enumerate(drive):
    G2.set("x", "xdot", "x_time", u)
    G2.do_step(k * dt, dt)
    soil.append(G2.get("g", "f", "dissipated_energy").copy())
out["soil"] = np.array(soil)
np.savez(args["output"], **out)
"""
COUPLED_OUT = ["max_uplift", "max_raft_rotation", "x", "xdot", "gap", "P", "energy.soil", "energy.kinetic"]


def soil_drive(n, steps=12):
    """Random interface states x, xdot with the stamp x_time = t of each step from t."""
    rng = np.random.default_rng(0)
    return np.array([np.concatenate([rng.normal(size=n) * 1e-3, rng.normal(size=n) * 1e-2, [k * DT]])
                     for k in range(steps)])


@pytest.fixture(scope="module")
def python_runs(case, tmp_path_factory):
    """What the Python FMUs give: the pair with one Python FMU, the coupled FMU, the soil on
    soil_drive(); run once, in a subprocess (see PY_RUNS)."""
    nat, py, _ = case
    tmp = tmp_path_factory.mktemp("pyruns")
    np.savez(tmp / "in.npz", acc=MOTION.acc, dt=DT, drive=soil_drive(MODEL.n), names=np.array(COUPLED_OUT))
    args = [f"input={tmp / 'in.npz'}", f"output={tmp / 'out.npz'}", f"py_structure={py.structure}",
            f"py_soil={py.soil}", f"py_coupled={py.coupled}", f"nat_soil={nat.soil}", f"nat_structure={nat.structure}"]
    proc = subprocess.run([sys.executable, "-c", PY_RUNS, *args], capture_output=True, text=True, timeout=600,
                          cwd=str(Path(__file__).parent))
    assert proc.returncode == 0, proc.stderr[-3000:]
    with np.load(tmp / "out.npz") as z:
        return {k: z[k] for k in z.files}


@pytest.fixture(scope="module")
def host(tmp_path_factory):
    """The plain C host, compiled by the system compiler."""
    return compile_host("host.c", tmp_path_factory.mktemp("host"))


def unpack(fmu, dest):
    return unpack_fmu(fmu, dest, "linux64")


# ---- what the FMUs are ----------------------------------------------------------------------
def test_variables_are_those_of_the_python_fmus(case):
    from fmpy.validation import validate_fmu
    nat, py, _ = case
    for role in ROLES:
        a, b = (read_model_description(str(getattr(e, role))) for e in (nat, py))
        row = lambda v: (v.name, v.valueReference, v.type, v.causality, v.variability, v.initial, v.unit,
                         v.start, v.description)
        assert [row(v) for v in a.modelVariables] == [row(v) for v in b.modelVariables]
        assert (a.modelName, a.defaultExperiment.stopTime, a.defaultExperiment.stepSize) == \
               (b.modelName, b.defaultExperiment.stopTime, b.defaultExperiment.stepSize)
        assert not a.coSimulation.needsExecutionTool and a.coSimulation.canGetAndSetFMUstate
        assert validate_fmu(str(getattr(nat, role))) == []
        with zipfile.ZipFile(getattr(nat, role)) as z:
            names = set(z.namelist())
        listed = a.buildConfigurations[0].sourceFileSets[0].sourceFiles
        assert {f"sources/{s}" for s in listed} == {f"sources/{s}" for s in SOURCES} <= names
        assert {f"binaries/{p}/{a.coSimulation.modelIdentifier}.{PLATFORMS[p][1]}" for p in PLATFORMS} <= names
        assert not any(n.endswith((".py", ".npz")) for n in names)           # no Python in the FMU
        assert not any(n.endswith("host.c") for n in names)                 # the test host is not shipped


def test_binaries_need_no_python(case, tmp_path):
    nat = case[0]
    with zipfile.ZipFile(nat.coupled) as z:
        z.extractall(tmp_path)
    bins = tmp_path / "binaries"
    needed = subprocess.run(["readelf", "-d", str(bins / "linux64" / "UpliftCoupled.so")], check=True,
                            capture_output=True, text=True).stdout
    assert set(re.findall(r"Shared library: \[(.+?)\]", needed)) == {"libc.so.6", "libm.so.6"}
    imports = subprocess.run(["objdump", "-p", str(bins / "win64" / "UpliftCoupled.dll")], check=True,
                             capture_output=True, text=True).stdout
    dlls = {d.lower() for d in re.findall(r"DLL Name: (\S+)", imports)}
    assert "kernel32.dll" in dlls and not any("python" in d for d in dlls)
    assert all(d == "kernel32.dll" or d.startswith("api-ms-win-crt-") for d in dlls)   # the C runtime only
    assert (bins / "darwin64" / "UpliftCoupled.dylib").read_bytes()[:4] == bytes.fromhex("cffaedfe")  # Mach-O 64


def test_resource_format_round_trip():
    records = {"guid": "g-1", "dt": 0.005, "a": np.arange(6.0).reshape(2, 3), "i": np.array([3, -1], np.int64)}
    back = decode_resources(encode_resources(records))
    assert back["guid"] == "g-1" and back["dt"] == 0.005 and back["i"].tolist() == [3, -1]
    assert np.array_equal(back["a"], records["a"])
    with pytest.raises(ValueError, match="longer than 32"):
        encode_resources({"x" * 33: 1.0})


def _encode_reference(records: dict) -> bytes:
    """The resource file written field by field (fmus/native/README.md's layout: a 32-byte header
    of magic, version, count, size, CRC-32 of the body; per record its padded name, kind, rank,
    four dimensions, byte count, data padded to 8 bytes), each array copied to its record type
    first: what ``encode_resources`` must give byte for byte."""
    import struct
    import zlib

    from fmus.native_build import KINDS, MAGIC, VERSION
    body = b""
    for name, value in records.items():
        if isinstance(value, str):
            kind, dims, data = KINDS["text"], (len(value.encode()),), value.encode()
        else:
            a = np.asarray(value)
            a = np.array(a, "<i8" if a.dtype.kind in "iub" else "<f8", order="C")
            kind, dims, data = KINDS["i8" if a.dtype.kind == "i" else "f8"], a.shape, a.tobytes()
        body += (name.encode().ljust(32, b"\0") + struct.pack("<II", kind, len(dims))
                 + struct.pack("<4Q", *(tuple(dims) + (0,) * (4 - len(dims)))) + struct.pack("<Q", len(data))
                 + data + b"\0" * (-len(data) % 8))
    return MAGIC + struct.pack("<IIQII", VERSION, len(records), 32 + len(body), zlib.crc32(body), 0) + body


def test_resource_records_are_encoded_byte_for_byte_without_copies_changing_them():
    """``encode_resources`` (one copy of each array, the CRC taken part by part) gives the bytes of
    the field-by-field layout for every kind of value: scalars, 0-d, empty, strided, big-endian,
    float32, int32 and bool arrays, text; a soil's pair records (the float view of its complex
    residues) are ``np.stack([re, im], -1)`` of them."""
    from fmus.native_build import _interleaved, soil_records
    rng = np.random.default_rng(3)
    records = {"dt": 0.005, "n": 3.0, "text": "h\u00e9llo", "empty_text": "", "a": rng.standard_normal((3, 4)),
               "i": np.arange(5), "b": np.array([True, False]), "big": rng.standard_normal((2, 3, 4, 2)).astype(">f8"),
               "f32": np.arange(3, dtype=np.float32), "strided": rng.standard_normal((6, 6))[::2, 1::2],
               "empty": np.zeros((0, 3)), "i32": np.arange(4, dtype=np.int32).reshape(2, 2), "scalar": np.float64(2.5),
               "zero_d": np.array(3)}
    assert encode_resources(records) == _encode_reference(records)
    z = rng.standard_normal((3, 5, 5)) + 1j * rng.standard_normal((3, 5, 5))
    for w in (z, z[:, ::2], z.astype(np.complex64)):
        assert np.array_equal(_interleaved(w), np.stack([w.real, w.imag], -1))
    from helpers.passive_models import random_passive_model
    soil = random_passive_model(5, 3, 2)
    rec = soil_records(soil, DT)
    assert encode_resources(rec) == _encode_reference(rec)
    pr, Rr, pc, Rc = soil.pole_split
    assert np.array_equal(rec["residues_pair"], np.stack([Rc.real, Rc.imag], -1).reshape(-1, soil.n, soil.n, 2))


def test_other_soil_factories_are_refused():
    data = dataclasses.replace(fmu_data(SCENE, MODEL, DT), soil_factory="helpers.soil_double:TrapezoidRationalSoil")
    with pytest.raises(ValueError, match="kind = 'python'"):
        build_native_fmus(data, "unused")
    with pytest.raises(ValueError, match="kind = 'fortran'"):
        export_scene(SCENE, "unused", MODEL, kind="fortran")


# ---- the answers -----------------------------------------------------------------------------
def assert_equal_runs(res, ref, tol=1e-10):
    assert res.converged and res.nt == ref.nt
    for key in ("raft", "gap", "contact_force", "soil_w"):
        assert rel(getattr(res, key), getattr(ref, key)) <= tol, key
    for node in ref.acc:
        assert rel(res.acc[node], ref.acc[node]) <= tol
    for term in ("input", "kinetic", "soil", "contact"):
        assert rel(res.energy[term], ref.energy[term]) <= tol, term


@pytest.mark.parametrize("schedule", ["gauss-seidel", "soil-first", "jacobi"])
def test_native_pair_equals_monolithic_under_every_schedule(case, schedule):
    nat, _, mono = case
    res = cosimulate(nat.structure, nat.soil, MOTION.acc, DT, schedule=schedule)
    assert_equal_runs(res, mono)
    assert np.array_equal(res.newton_iters, mono.newton_iters)
    assert res.info["fmu_max_uplift"] == pytest.approx(mono.max_uplift(), rel=1e-10)
    assert res.info["fmu_max_raft_rotation"] == pytest.approx(max_rotation(mono), rel=1e-10)


@pytest.mark.parametrize("python_fmu", ["py_structure", "py_soil"])
def test_native_beside_a_python_fmu(case, python_runs, python_fmu, spread):
    """py_structure: the Python stepper against the native one (the monolithic route), within
    the round-off spread; py_soil: the native stepper on both sides, the Python soil: the same."""
    mono = case[2]
    got = python_runs[python_fmu]
    names = ("raft", "gap", "contact_force", "soil_w")
    assert got.shape == (mono.nt, 6 + 3 * N)
    parts = dict(zip(names, np.split(got, [6, 6 + N, 6 + 2 * N], axis=1)))
    assert_within_spread(parts, {k: getattr(mono, k) for k in names}, spread)


def test_native_soil_equals_python_soil_on_random_inputs(case, python_runs):
    nat = case[0]
    got = []
    with FmuSlave(nat.soil, "native") as a:
        a.initialize()
        for k, u in enumerate(soil_drive(MODEL.n)):
            a.set("x", "xdot", "x_time", u)
            a.do_step(k * DT, DT)
            got.append(a.get("g", "f", "dissipated_energy").copy())
    ref = python_runs["soil"]
    assert np.abs(ref[1:, :MODEL.n]).max(axis=1).min() > 0             # the history force is there
    for a, b in zip(got[1:], ref[1:]):
        assert rel(a, b) <= 1e-10


def test_native_soil_outputs_computed_when_read(case):
    """The native soil FMU computes f and dissipated_energy only when they are read (D0 x then; the
    work of D0 x telescopes to x . D0 x / 2). Read after 30 steps of g alone, then again after a
    state saved while they were not computed is restored: equal, bit for bit, to an instance that
    read them every step (the same state), and to the soil object stepped in process (the
    recursive convolution: its force and its work summed step by step) to 1e-10, as the Python FMU."""
    from soil_impedance.convolution import RecursiveConvolutionSoil
    nat = case[0]
    drive = soil_drive(MODEL.n, steps=41)
    soil = RecursiveConvolutionSoil(MODEL, DT)
    soil.instantaneous(DT)
    ref = []
    for k, u in enumerate(drive):
        if k:                                        # at t = 0 the soil is at rest: nothing committed
            soil.commit(u[:MODEL.n], u[MODEL.n:2 * MODEL.n])
        ref.append(np.concatenate([soil.total_force(), [soil.dissipated_energy()]]))
    with FmuSlave(nat.soil, "every") as a, FmuSlave(nat.soil, "late") as b:
        a.initialize()
        b.initialize()
        every, late = [], {}
        for k, u in enumerate(drive):
            for fmu in (a, b):
                fmu.set("x", "xdot", "x_time", u)
                fmu.do_step(k * DT, DT)
            every.append(a.get("f", "dissipated_energy").copy())
            b.get("g", "g_time")                     # what the master reads: not the outputs
            if k == 30:
                late[k] = b.get("f", "dissipated_energy").copy()
            if k == 33:
                saved = b.get_state()                # outputs not computed at this state
        late[40] = b.get("f", "dissipated_energy").copy()
        b.set_state(saved)
        late[33] = b.get("f", "dissipated_energy").copy()
        b.fmu.freeFMUState(saved)
    assert abs(ref[-1][-1]) > 0 and np.abs(ref[-1][:-1]).max() > 0
    for k, got in late.items():
        assert np.array_equal(got, every[k])
    for k in range(len(drive)):
        assert rel(every[k][:-1], ref[k][:-1]) <= 1e-10
        assert abs(every[k][-1] - ref[k][-1]) <= 1e-10 * abs(ref[-1][-1])


@pytest.mark.parametrize("n_pairs, n_real", [(0, 3), (2, 1)])
def test_native_soil_history_with_and_without_pole_pairs(tmp_path, n_pairs, n_real):
    """The native soil FMU's two ways to its histories (soil.c, up_soil_step): with real poles only
    (packed blocks) the history of its next commit and the g it publishes come from the same block
    products (no product with Gx); with pole pairs, g_{k+2} + Gx x_{k+1}. Both against the soil
    object stepped in process (commit, then fmus.coupling.history_ahead; its force and work), on
    random inputs, to 1e-10: g, f and dissipated_energy at every step."""
    from fmus.coupling import history_ahead
    from fmus.native_stepper import cache_folder, fmu_binaries
    from helpers import random_passive_model
    from soil_impedance.cache import default_cache_dir
    from soil_impedance.convolution import RecursiveConvolutionSoil
    model = random_passive_model(6 + N, n_pairs=n_pairs, n_real=n_real, seed=3)
    assert model.pole_split[2].size == n_pairs and model.pole_split[0].size == n_real
    bins = fmu_binaries(cache_folder(default_cache_dir()))
    path = build_native_fmus(fmu_data(SCENE, model, DT), tmp_path, platforms=tuple(bins), binaries=bins)["soil"]
    drive = soil_drive(model.n, steps=30)
    soil = RecursiveConvolutionSoil(model, DT)
    soil.instantaneous(DT)
    with FmuSlave(path, "soil") as fmu:
        fmu.initialize()
        for k, u in enumerate(drive):
            fmu.set("x", "xdot", "x_time", u)
            fmu.do_step(k * DT, DT)
            if k:                                    # at t = 0 the soil is at rest: nothing committed
                soil.commit(u[:model.n], u[model.n:2 * model.n])
            got = fmu.get("g", "f", "dissipated_energy")
            g = history_ahead(soil)
            assert rel(got[:model.n], g) <= 1e-10
            assert rel(got[model.n:2 * model.n], soil.total_force()) <= 1e-10
            assert abs(got[-1] - soil.dissipated_energy()) <= 1e-10 * max(abs(soil.dissipated_energy()), 1e-30)
        assert np.abs(g).max() > 0 and abs(soil.dissipated_energy()) > 0


#: the histories whose spread holds each output of COUPLED_OUT (x = [raft q, soil w])
SPREAD_OF = {"x": ("raft", "soil_w"), "gap": ("gap",), "P": ("contact_force",), "energy.soil": ("energy.soil",),
             "energy.kinetic": ("energy.kinetic",)}


def test_coupled_fmu_equals_monolithic_and_the_python_fmu(case, python_runs, spread):
    nat, _, mono = case
    rows = []
    with FmuSlave(nat.coupled, "coupled") as c:
        c.initialize()
        rows.append(c.get(*COUPLED_OUT).copy())
        for k in range(1, mono.nt):
            c.do_step((k - 1) * DT, DT)
            rows.append(c.get(*COUPLED_OUT).copy())
        sizes = [len(c.vrs(name)) for name in COUPLED_OUT]
    got, ref = np.array(rows), python_runs["py_coupled"]
    assert got.shape == ref.shape
    for name, cols in zip(COUPLED_OUT, np.split(np.arange(got.shape[1]), np.cumsum(sizes)[:-1])):
        tol = max(spread.tol(k) for k in SPREAD_OF[name]) if name in SPREAD_OF else 1e-9   # (xdot: 1.0e-10)
        assert rel(got[:, cols], ref[:, cols]) <= tol, name
    assert rel(got[:, 2:8], mono.raft) <= 1e-10
    assert got[-1, 0] == pytest.approx(mono.max_uplift(), rel=1e-10)
    assert got[-1, 1] == pytest.approx(max_rotation(mono), rel=1e-10)


def test_coupled_fmu_driven_through_its_three_motion_inputs(case):
    """internal_motion = false: ag_x, ag_y, ag_z carry a_g(t + dt) of each component; the same
    answer as the bundled motion, the monolithic route's."""
    nat, _, mono = case
    with FmuSlave(nat.coupled, "coupled", parameters={"internal_motion": False}) as c:
        c.set(*AG, MOTION.acc[0])
        c.initialize()
        raft = [c.get("x")[:6].copy()]
        for k in range(1, mono.nt):
            c.set(*AG, MOTION.acc[k])
            c.do_step((k - 1) * DT, DT)
            raft.append(c.get("x")[:6].copy())
    assert rel(raft, mono.raft) <= 1e-10


def test_fmpy_simulate_fmu_on_the_coupled_fmu(case):
    from fmpy import simulate_fmu
    nat, _, mono = case
    res = simulate_fmu(str(nat.coupled), output=["max_uplift"] + [f"x[{i}]" for i in range(6)])
    assert rel(np.column_stack([res[f"x[{i}]"] for i in range(6)]), mono.raft) <= 1e-10
    assert res["max_uplift"][-1] == pytest.approx(mono.max_uplift(), rel=1e-10)


def test_coupled_fmu_takes_a_multiple_of_its_step_the_pair_does_not(case):
    """fmpy.simulate_fmu doubles its communication step past 1000 steps: the coupled FMU steps its
    own dt inside, with the same answer; the pair, coupled every dt, refuses (as the Python FMUs)."""
    from fmpy import simulate_fmu
    nat, _, mono = case
    res = simulate_fmu(str(nat.coupled), output=["max_uplift"], output_interval=4 * DT)
    assert res["time"][-1] == pytest.approx(nat.stop_time)
    assert res["max_uplift"][-1] == pytest.approx(mono.max_uplift(), rel=1e-10)
    with pytest.raises(Exception, match="fmi2DoStep failed with status 3"):
        simulate_fmu(str(nat.structure), output=["max_uplift"], output_interval=2 * DT)


def test_libcosim_and_the_ssp_runner(case):
    pytest.importorskip("libcosimpy", reason="libcosimpy is not installed (the 'test' extra)")
    from fmpy.ssp.simulation import simulate_ssp
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    nat, _, mono = case
    log_output_level(CosimLogLevel.WARNING)
    ex = CosimExecution.from_ssp_file(str(nat.ssd))
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    si = ex.slave_index_from_instance_name("structure")
    refs = {v.name.decode(): v.reference for v in ex.slave_variables(si)}
    vr = [refs[f"x[{i}]"] for i in range(6)] + [refs["max_uplift"]]
    out = []
    for _ in range(mono.nt - 1):
        assert ex.step(1)
        out.append(obs.last_real_values(si, vr))
    out = np.array(out)
    assert rel(out[:, :6], mono.raft[1:]) <= 1e-10
    assert out[-1, -1] == pytest.approx(mono.max_uplift(), rel=1e-10)
    res = simulate_ssp(str(nat.ssp), stop_time=nat.stop_time, step_size=nat.dt)
    assert res["structure.max_uplift"][-1] == pytest.approx(mono.max_uplift(), rel=1e-10)


def _gs_step(s, g, k):
    s.set("g", "g_time", g.get("g", "g_time"))
    s.do_step((k - 1) * DT, DT)                                      # the bundled motion
    g.set("x", "xdot", "x_time", s.get("x", "xdot", "x_time"))
    g.do_step((k - 1) * DT, DT)
    return np.concatenate([s.get("x", "xdot", "P", "gap", "energy.soil"), g.get("g", "f", "dissipated_energy")])


def test_pair_rolls_back_through_serialised_states(case):
    nat = case[0]
    with FmuSlave(nat.structure, "s") as s, FmuSlave(nat.soil, "g") as g:
        s.initialize()
        g.initialize()
        assert_pair_rolls_back(s, g, _gs_step)


# ---- step halving ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def halving(tmp_path_factory):
    """Native FMUs whose Newton stops after 2 iterations (the step is halved where the active
    set changes twice), the linux64 binary only."""
    data = fmu_data(SCENE, MODEL, DT, MOTION)
    out = {}
    for max_iter in (1, 2):
        out[max_iter] = build_native_fmus(data, tmp_path_factory.mktemp(f"halving{max_iter}"), coupled=True,
                                          platforms=("linux64",), newton={"max_iter": max_iter})
    return data, out


def _contact(data, max_iter):
    from structure.spec import contact_from_spec
    return dataclasses.replace(contact_from_spec(data.contact), max_iter=max_iter, precheck=False)


def test_step_halving_coupled_equals_the_stepper(halving):
    from fmpy import simulate_fmu
    from fmus.resources import soil_from_model
    from structure import simulate
    data, fmus = halving
    ref = simulate(SCENE.model(), soil_from_model(MODEL, DT), MOTION.acc, DT, contact=_contact(data, 2),
                   damping=data.damping, output_nodes=data.output_nodes)
    assert ref.info["subdivided_steps"] > 0
    res = simulate_fmu(str(fmus[2]["coupled"]), output=[f"x[{i}]" for i in range(6)] + ["max_uplift"])
    assert rel(np.column_stack([res[f"x[{i}]"] for i in range(6)]), ref.raft) <= 1e-10
    assert res["max_uplift"][-1] == pytest.approx(ref.max_uplift(), rel=1e-10)


def test_step_halving_pair_equals_the_split_in_process(halving):
    from fmus.coupling import history_ahead, history_gains
    from fmus.resources import soil_from_model
    from structure import NewmarkStepper
    data, fmus = halving
    soil = soil_from_model(MODEL, DT)                                # the soil FMU's
    Gx, Gv = history_gains(soil, DT)
    st = NewmarkStepper(SCENE.model(), soil_from_model(MODEL, DT), DT, contact=_contact(data, 2),
                        damping=data.damping, external_soil=True, ag0=MOTION.acc[0])    # its own: dt / 2 inside
    raft, g, prev, halved = [st.x[:6].copy()], np.zeros(st.nb), None, 0
    for k in range(1, MOTION.acc.shape[0]):                         # Gauss-Seidel, as the master runs it
        st.set_ground_acceleration(MOTION.acc[k])
        st.set_soil_history(g + Gx @ st.x + Gv @ st.xdot)
        st.step()
        halved += st.last_substeps > 1
        raft.append(st.x[:6].copy())
        if prev is not None:
            soil.commit(*prev)
        prev = st.x.copy(), st.xdot.copy()
        g = history_ahead(soil)
    assert halved > 0
    res = cosimulate(fmus[2]["structure"], fmus[2]["soil"], MOTION.acc, DT)
    assert res.converged and rel(res.raft, np.array(raft)) <= 1e-10


def test_a_step_that_cannot_converge_is_refused_with_the_steppers_message(halving):
    from fmus.resources import soil_from_model
    from orchestrator.master import CosimError
    from structure import ConvergenceError, simulate
    data, fmus = halving
    with pytest.raises(ConvergenceError) as err:
        simulate(SCENE.model(), soil_from_model(MODEL, DT), MOTION.acc, DT, contact=_contact(data, 1),
                 damping=data.damping)
    def serialized(c):
        state = c.get_state()
        data = c.serialize(state)
        c.fmu.freeFMUstate(state)
        return data

    with FmuSlave(fmus[1]["coupled"], "coupled") as c:
        c.initialize()
        k = 1
        with pytest.raises(CosimError) as refused:
            for k in range(1, MOTION.acc.shape[0]):
                before = serialized(c)
                c.do_step((k - 1) * DT, DT)
        assert k == err.value.result.nt and str(err.value) in str(refused.value)     # the same step, message
        assert rel(c.get("x")[:6], err.value.result.raft[-1]) <= 1e-10                 # the instance as it was,
        assert serialized(c) == before                                                 # bit for bit


# ---- a plain C host ----------------------------------------------------------------------------
@pytest.mark.parametrize("binary", ["shipped", "from sources"])
def test_plain_c_host_runs_the_coupled_fmu(case, host, tmp_path, binary):
    """The shipped linux64 binary, and one a tool compiles from the FMU's sources/ alone."""
    nat, _, mono = case
    folder, lib, guid, vr = unpack(nat.coupled, tmp_path)
    if binary == "from sources":
        lib = tmp_path / "rebuilt.so"
        listed = read_model_description(str(nat.coupled)).buildConfigurations[0].sourceFileSets[0].sourceFiles
        subprocess.run([shutil.which("cc") or "gcc", "-std=c99", "-O2", "-shared", "-fPIC", f"-I{fmi_headers()}",
                        *[str(folder / "sources" / s) for s in listed], "-o", str(lib), "-lm"], check=True)
    out = subprocess.run([str(host), "run", str(folder), str(lib), guid, repr(DT), str(mono.nt - 1),
                          str(vr["max_uplift"]), str(vr["max_raft_rotation"])], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    values = dict(line.split() for line in out.stdout.splitlines() if line[:1].isdigit())
    assert float(values[str(vr["max_uplift"])]) == pytest.approx(mono.max_uplift(), rel=1e-10)
    assert float(values[str(vr["max_raft_rotation"])]) == pytest.approx(max_rotation(mono), rel=1e-10)
    assert "allocations in doStep 0" in out.stdout and "python symbols 0" in out.stdout
    ldd = subprocess.run(["readelf", "-d", str(host)], capture_output=True, text=True).stdout
    assert "python" not in ldd.lower()


#: fmi2Status of each hostile call (0 OK, 3 fmi2Error: refused, the instance as it was), or 1/0
#: for a yes/no case (an instantiation that returned an instance, a replay that differs)
EXPECTED = {"wrong-guid": 0, "wrong-folder": 0, "model-exchange": 0, "null-guid": 0, "null-instance-step": 3,
            "null-instance-get": 3, "before-init": 3, "bad-vr": 3, "null-values": 3, "set-output": 3, "init": 0,
            "set-parameter-after-init": 3, "nan": 3, "nan-after": 0, "skipped-time": 3, "negative-time": 3,
            "nan-time": 3, "wrong-step": 3, "stamp": 3, "stamp-after": 0, "get-state": 0, "serialize": 0,
            "deserialize": 0, "replay-differs": 0, "deserialize-damaged": 3, "deserialize-short": 3,
            "set-null-state": 3, "free-states": 0, "terminate": 0, "after-terminate": 3, "reset": 0, "survived": 1}
MESSAGES = ("GUID", "cannot be opened", "co-simulation only", "before initialisation", "value references 1000000",
            "is an output", "fixed parameter", "inputs must be finite", "steps must follow one another",
            "per communication step", "after fmi2Terminate", "not a serialised state of this FMU",
            "not an FMU state of this FMU")


@pytest.mark.parametrize("role, vr_in, vr_out", [("soil", "x_time", "g[0]"), ("structure", "g_time", "x[2]"),
                                                 ("coupled", "ag_y", "x[2]")])
def test_hostile_calls_are_refused_and_the_host_survives(case, host, tmp_path, role, vr_in, vr_out):
    folder, lib, guid, vr = unpack(getattr(case[0], role), tmp_path)
    stamped = role != "coupled"
    out = subprocess.run([str(host), "hostile", str(folder), str(lib), guid, repr(DT), str(vr[vr_in]),
                          str(vr[vr_out]), str(vr.get("internal_motion", -1)), str(int(stamped))],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    got = dict(line.rsplit(" ", 1) for line in out.stdout.splitlines() if not line.startswith("log:"))
    expected = {k: v for k, v in EXPECTED.items() if (stamped or not k.startswith("stamp"))
                and (role != "soil" or k != "set-parameter-after-init")}
    assert {k: int(v) for k, v in got.items()} == expected
    for message in MESSAGES if role != "soil" else [m for m in MESSAGES if m != "fixed parameter"]:
        assert re.search(message, out.stdout), message
    if stamped:
        assert f"is stamped {vr_in}" in out.stdout


def test_a_damaged_resource_file_is_refused(case, host, tmp_path):
    folder, lib, guid, vr = unpack(case[0].soil, tmp_path)
    path = folder / "resources" / "uplift.bin"
    blob = bytearray(path.read_bytes())
    blob[len(blob) // 2] ^= 0xFF
    path.write_bytes(bytes(blob))
    out = subprocess.run([str(host), "run", str(folder), str(lib), guid, repr(DT), "1"], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 4 and "damaged (checksum)" in out.stdout


@pytest.mark.parametrize("case_name, message", [
    ("nan", "inputs must be finite"), ("negative-time", "steps must follow one another"),
    ("skipped-time", "steps must follow one another"), ("after-terminate", "after fmi2Terminate"),
    ("before-init", "before initialisation"), ("bad-stamp", "stamped x_time"),
    ("bad-vr", "value references 1000000")])
def test_the_python_fmus_hostile_cases(case, case_name, message):
    """The hostile-call host of helpers.fmu_host (fmpy, in a subprocess) on the native soil FMU."""
    from helpers.fmu_host import ERROR, OK, run_host
    out = run_host(case[0].soil, case_name)
    assert out["status"] == ERROR and message in out["log"]
    if "after" in out:
        assert out["after"] == OK
