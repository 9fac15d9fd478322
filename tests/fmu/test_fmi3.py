"""FMI 3.0 co-simulation FMUs of the native runtime (``export_scene(..., fmi_version=3)``,
``uplift export --fmi-version 3``): the same answers as the monolithic route and the FMI 2.0
FMUs, the interface vectors as arrays, binaries for four platforms, robust entry points.

Small scene (reactor stick on a 21-node raft over rock), a pulse along x, y and z at once that
lifts the raft by 52 mm and rocks it about both axes, a rational soil with a history force;
exported once for the module. Checked:

- fmpy's validator finds nothing in any of the three model descriptions; the interface
  vectors are arrays (<Dimension>: 3, or the structural parameter N), units as in FMI 2.0;
  sources/buildDescription.xml lists the C files (fmi3.c and the shared runtime);
- the binaries: x86_64-linux needs libc and libm only, x86_64-windows imports no Python DLL
  (the C runtime only), x86_64-darwin and aarch64-darwin are Mach-O dylibs for x86_64 and
  arm64 that load libSystem only;
- fmpy.simulate_fmu on coupled.fmu, the pair under the project's master (every schedule), a
  plain C host (tests/fmu/native/host3.c, no Python in the process) on the shipped binary and on
  one compiled from the FMU's sources: the monolithic route to 1e-8 (measured ~1e-12);
- hostile calls through host3 are refused with a status and a message, the host survives;
  a serialised state replays bit-identically;
- system.ssd connects the arrays, one connection per array, units and lengths equal at both
  ends; the cross-check folders in the fmus/3.0 layout pass fmpy's per-folder check and a
  replay of the soil's _in.csv through simulate_fmu reproduces its _ref.csv.
"""
import re
import shutil
import struct
import subprocess
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description

from helpers import assert_pair_rolls_back, pulse_motion, rel, rocks_about_both_axes, small_scene, soil_model
from helpers.c_host import compile_host, unpack_fmu
from fmus.native_build import PLATFORMS3, SOURCES3, fmi_headers
from fmus.schema import vector3
from orchestrator.export import export_scene
from orchestrator.master import FmuSlave, cosimulate
from orchestrator.routes.monolithic import run_monolithic

SCENE = small_scene()
MODEL = soil_model(SCENE)
MOTION = pulse_motion(T=1.0, y=0.5)          # x, y and z at once
DT = MOTION.dt
N = SCENE.mesh.xy.shape[0]
ROLES = ("structure", "soil", "coupled")
TOL = 1e-8


def max_rotation(res):
    return np.hypot(res.raft[:, 3], res.raft[:, 4]).max()


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """(FMI 3.0 Export, monolithic RouteResult)."""
    exp = export_scene(SCENE, tmp_path_factory.mktemp("fmi3"), MODEL, motion=MOTION, fmi_version=3)
    mono = run_monolithic(SCENE, MOTION, MODEL)
    assert mono.converged and mono.max_uplift() > 1e-2 and rocks_about_both_axes(mono)
    return exp, mono


# ---- what the FMUs are ----------------------------------------------------------------------
def test_model_descriptions_validate_and_declare_arrays(case):
    from fmpy.validation import validate_fmu
    exp, _ = case
    for role in ROLES:
        fmu = getattr(exp, role)
        assert validate_fmu(str(fmu)) == [], role
        md = read_model_description(str(fmu))
        assert md.fmiVersion == "3.0" and md.coSimulation is not None and md.modelExchange is None
        ex = md.defaultExperiment
        assert (float(ex.startTime), float(ex.stepSize), float(ex.stopTime)) == (0.0, DT, pytest.approx(exp.stop_time))
        var = {v.name: v for v in md.modelVariables}
        n_var = var["N"]
        assert (n_var.type, n_var.causality, n_var.variability, int(n_var.start)) == \
            ("UInt64", "structuralParameter", "fixed", N)
        dims = {name: [(d.start, d.valueReference) for d in v.dimensions] for name, v in var.items() if v.dimensions}
        vec = "x" if role == "soil" or role == "coupled" else "g"
        assert dims[f"{vec}_raft_u"] == [(3, None)] and dims[f"{vec}_raft_r"] == [(3, None)]
        assert [vr for _, vr in dims[f"{vec}_w"]] == [n_var.valueReference]
        assert (var[f"{vec}_raft_u"].unit, var[f"{vec}_raft_r"].unit, var[f"{vec}_w"].unit) == \
            (("m", "rad", "m") if vec == "x" else ("N", "N.m", "N"))
        if role != "soil":
            assert [dims[k] for k in ("P", "gap")] == [[(None, n_var.valueReference)]] * 2
            assert all(var[a].unit == "m/s2" and var[a].causality == "input" and not var[a].dimensions
                       for a in ("ag_x", "ag_y", "ag_z"))
            assert var["max_uplift"].unit == "m" and var["max_raft_rotation"].unit == "rad"
            assert var["internal_motion"].type == "Boolean" and var["internal_motion"].start == "true"
        with zipfile.ZipFile(fmu) as z:
            names = set(z.namelist())
            build = ET.fromstring(z.read("sources/buildDescription.xml"))
        listed = [f.get("name") for f in build.iter("SourceFile")]
        assert listed == list(SOURCES3) and {f"sources/{s}" for s in listed} <= names
        assert {f"binaries/{p}/{md.coSimulation.modelIdentifier}.{PLATFORMS3[p][1]}" for p in PLATFORMS3} <= names
        assert not any(n.endswith((".py", ".npz")) for n in names)
        cs = md.coSimulation
        assert not cs.canHandleVariableCommunicationStepSize and cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
        assert not cs.hasEventMode and not cs.canReturnEarlyAfterIntermediateUpdate


def macho(blob: bytes):
    """(cputype, [dylib names]) of a 64-bit Mach-O file."""
    magic, cputype, _, _, ncmds, _, _, _ = struct.unpack_from("<8I", blob)
    assert magic == 0xFEEDFACF
    dylibs, off = [], 32
    for _ in range(ncmds):
        cmd, size = struct.unpack_from("<2I", blob, off)
        if cmd == 0xC:                                     # LC_LOAD_DYLIB
            (name,) = struct.unpack_from("<I", blob, off + 8)
            dylibs.append(blob[off + name:off + size].split(b"\0")[0].decode())
        off += size
    return cputype, dylibs


def test_binaries_per_platform_need_no_python(case, tmp_path):
    exp, _ = case
    with zipfile.ZipFile(exp.coupled) as z:
        z.extractall(tmp_path)
    bins = tmp_path / "binaries"
    needed = subprocess.run(["readelf", "-d", str(bins / "x86_64-linux" / "UpliftCoupled.so")], check=True,
                            capture_output=True, text=True).stdout
    assert set(re.findall(r"Shared library: \[(.+?)\]", needed)) == {"libc.so.6", "libm.so.6"}
    imports = subprocess.run(["objdump", "-p", str(bins / "x86_64-windows" / "UpliftCoupled.dll")], check=True,
                             capture_output=True, text=True).stdout
    dlls = {d.lower() for d in re.findall(r"DLL Name: (\S+)", imports)}
    assert "kernel32.dll" in dlls and all(d == "kernel32.dll" or d.startswith("api-ms-win-crt-") for d in dlls)
    for platform, cpu in (("x86_64-darwin", 0x01000007), ("aarch64-darwin", 0x0100000C)):   # x86_64, arm64
        cputype, dylibs = macho((bins / platform / "UpliftCoupled.dylib").read_bytes())
        assert cputype == cpu and dylibs == ["/usr/lib/libSystem.B.dylib"], (platform, dylibs)


# ---- the answers -----------------------------------------------------------------------------
def test_fmpy_simulate_fmu_on_the_coupled_fmu(case):
    from fmpy import simulate_fmu
    exp, mono = case
    res = simulate_fmu(str(exp.coupled), output=["max_uplift", "max_raft_rotation", "x_raft_u", "x_raft_r", "gap"])
    assert res["time"][-1] == pytest.approx(exp.stop_time)
    assert rel(np.hstack([res["x_raft_u"], res["x_raft_r"]]), mono.raft) <= TOL
    assert rel(res["gap"], mono.gap) <= TOL
    assert res["max_uplift"][-1] == pytest.approx(mono.max_uplift(), rel=TOL)
    assert res["max_raft_rotation"][-1] == pytest.approx(max_rotation(mono), rel=TOL)


@pytest.mark.parametrize("schedule", ["gauss-seidel", "soil-first", "jacobi"])
def test_pair_under_the_master_equals_monolithic(case, schedule):
    exp, mono = case
    res = cosimulate(exp.structure, exp.soil, MOTION.acc, DT, schedule=schedule)
    assert res.converged and res.nt == mono.nt, res.message
    for key in ("raft", "gap", "contact_force", "soil_w"):
        assert rel(getattr(res, key), getattr(mono, key)) <= TOL, key
    for node in mono.acc:
        assert rel(res.acc[node], mono.acc[node]) <= TOL
    assert np.array_equal(res.newton_iters, mono.newton_iters)
    assert res.info["fmu_max_uplift"] == pytest.approx(mono.max_uplift(), rel=TOL)
    assert res.info["fmu_max_raft_rotation"] == pytest.approx(max_rotation(mono), rel=TOL)


def test_pair_rolls_back_through_serialised_states(case):
    exp, _ = case

    def step(s, g, k):
        s.set("g", "g_time", g.get("g", "g_time"))
        s.do_step((k - 1) * DT, DT)
        g.set("x", "xdot", "x_time", s.get("x", "xdot", "x_time"))
        g.do_step((k - 1) * DT, DT)
        return np.concatenate([s.get("x", "gap"), g.get("g")])

    with FmuSlave(exp.structure, "s") as s, FmuSlave(exp.soil, "g") as g:
        assert s.version == 3 and s.size("x") == 6 + N
        s.initialize()
        g.initialize()
        assert_pair_rolls_back(s, g, step)


# ---- a plain C host ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def host3(tmp_path_factory):
    """The plain C FMI 3.0 host, compiled by the system compiler."""
    return compile_host("host3.c", tmp_path_factory.mktemp("host3"))


def unpack(fmu, dest):
    return unpack_fmu(fmu, dest, "x86_64-linux")


@pytest.mark.parametrize("binary", ["shipped", "from sources"])
def test_plain_c_host_runs_the_coupled_fmu(case, host3, tmp_path, binary):
    exp, mono = case
    folder, lib, token, vr = unpack(exp.coupled, tmp_path)
    if binary == "from sources":                   # what a tool does with sources/buildDescription.xml
        lib = tmp_path / "rebuilt.so"
        build = ET.parse(folder / "sources" / "buildDescription.xml").getroot()
        files = [str(folder / "sources" / f.get("name")) for f in build.iter("SourceFile")]
        subprocess.run([shutil.which("cc") or "gcc", "-std=c99", "-O2", "-shared", "-fPIC", f"-I{fmi_headers()}",
                        *files, "-o", str(lib), "-lm"], check=True)
    out = subprocess.run([str(host3), "run", str(folder), str(lib), token, repr(DT), str(mono.nt - 1),
                          str(vr["max_uplift"]), str(vr["max_raft_rotation"])], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    values = dict(line.split() for line in out.stdout.splitlines() if line[:1].isdigit())
    assert float(values[str(vr["max_uplift"])]) == pytest.approx(mono.max_uplift(), rel=TOL)
    assert float(values[str(vr["max_raft_rotation"])]) == pytest.approx(max_rotation(mono), rel=TOL)
    assert "allocations in doStep 0" in out.stdout and "python symbols 0" in out.stdout


#: fmi3Status of each hostile call (0 OK, 3 fmi3Error: refused, the instance as it was), or 1/0
#: for a yes/no case (an instantiation that returned an instance, a replay that differs)
EXPECTED = {"wrong-token": 0, "wrong-folder": 0, "event-mode": 0, "model-exchange": 0, "null-token": 0,
            "null-instance-step": 3, "null-instance-get": 3, "before-init": 3, "bad-vr": 3, "null-values": 3,
            "short-array": 3, "get-array": 0, "set-output": 3, "get-N": 0, "set-N": 3, "configuration-mode": 3,
            "init": 0, "event-mode-call": 3, "set-parameter-after-init": 3, "nan": 3, "nan-after": 0,
            "skipped-time": 3, "negative-time": 3, "nan-time": 3, "wrong-step": 3, "stamp": 3, "stamp-after": 0,
            "get-state": 0, "serialize": 0, "deserialize": 0, "replay-differs": 0, "deserialize-damaged": 3,
            "deserialize-short": 3, "set-null-state": 3, "free-states": 0, "terminate": 0, "after-terminate": 3,
            "reset": 0, "survived": 1}
MESSAGES = ("does not match the resources", "cannot be opened", "no event mode", "co-simulation only",
            "before initialisation \\(call fmi3ExitInitializationMode first\\)", "value reference 1000000",
            "nValues = ", "is an output", "fixed by the export", "fixed parameter", "input ag_y = nan|inputs must be "
            "finite", "steps must follow one another", "per communication step", "after fmi3Terminate",
            "not a serialised state of this FMU", "not an FMU state of this FMU")


@pytest.mark.parametrize("role, vr_in, vr_out", [("soil", "x_time", "g_raft_u"), ("structure", "g_time", "x_raft_u"),
                                                 ("coupled", "ag_y", "x_raft_u")])
def test_hostile_calls_are_refused_and_the_host_survives(case, host3, tmp_path, role, vr_in, vr_out):
    folder, lib, token, vr = unpack(getattr(case[0], role), tmp_path)
    stamped = role != "coupled"
    out = subprocess.run([str(host3), "hostile", str(folder), str(lib), token, repr(DT), str(vr[vr_in]),
                          str(vr[vr_out]), "3", str(vr["N"]), str(vr.get("internal_motion", -1)), str(int(stamped))],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    got = dict(line.rsplit(" ", 1) for line in out.stdout.splitlines()
               if not line.startswith(("log:", "N = ")))
    expected = {k: v for k, v in EXPECTED.items() if (stamped or not k.startswith("stamp"))
                and (role != "soil" or k != "set-parameter-after-init")}
    assert {k: int(v) for k, v in got.items()} == expected
    assert f"N = {N}" in out.stdout
    for message in MESSAGES if role != "soil" else [m for m in MESSAGES if m != "fixed parameter"]:
        assert re.search(message, out.stdout), message
    if stamped:
        assert f"is stamped {vr_in}" in out.stdout


# ---- the SSP system and the cross-check folders --------------------------------------------------
def test_ssd_connects_the_arrays(case, tmp_path):
    exp, _ = case
    ns = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription"}
    with zipfile.ZipFile(exp.ssp) as z:
        z.extractall(tmp_path)
    for ssd, folder in ((exp.ssd, exp.ssd.parent), (tmp_path / "SystemStructure.ssd", tmp_path)):
        root = ET.parse(ssd).getroot()
        sources = {c.get("name"): folder / c.get("source") for c in root.iterfind(".//ssd:Component", ns)}
        md = {comp: read_model_description(str(src)) for comp, src in sources.items()}
        assert all(m.fmiVersion == "3.0" for m in md.values())
        slaves_len = {}
        for comp, m in md.items():
            by_vr = {v.valueReference: v for v in m.modelVariables}
            slaves_len[comp] = {v.name: (v.unit, v.causality, [int(d.start or by_vr[d.valueReference].start)
                                                               for d in v.dimensions]) for v in m.modelVariables}
        conns = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
                 for c in root.iterfind(".//ssd:Connection", ns)]
        assert len(conns) == 3 * 3 + 2                  # x, xdot, g in three arrays each; x_time, g_time
        for a, va, b, vb in conns:
            (ua, ca, da), (ub, cb, db) = slaves_len[a][va], slaves_len[b][vb]
            assert va == vb and (ca, cb) == ("output", "input") and ua == ub and da == db, (va, da, db)
        assert {va for _, va, _, _ in conns if slaves_len["structure"].get(va, (0, 0, []))[2] == [N]} == \
            {"x_w", "xdot_w", "g_w"}


def test_cross_check_folders_in_the_fmi3_layout(case, tmp_path):
    """The folders pass fmpy's per-folder check; coupled_in.csv (scalar inputs) replayed by
    fmpy.simulate_fmu, and soil_in.csv (arrays, which fmpy's input reader does not take)
    replayed row by row, reproduce their _ref.csv."""
    from fmpy import simulate_fmu
    from fmpy.util import read_csv, read_ref_opt_file
    from orchestrator.crosscheck import write_cross_check
    exp, _ = case
    xc = write_cross_check(exp, tmp_path / "xc", "small")
    assert xc.problems == ()
    for model, folder in xc.models.items():
        assert folder.parts[-7:-3] == ("fmus", "3.0", "cs", "x86_64-linux"), model
    folder = xc.models["coupled"]
    opt = read_ref_opt_file(str(folder / "coupled_ref.opt"))
    ref = read_csv(str(folder / "coupled_ref.csv"))
    res = simulate_fmu(str(folder / "coupled.fmu"), stop_time=opt["StopTime"], output_interval=opt["StepSize"],
                       input=read_csv(str(folder / "coupled_in.csv")), output=list(ref.dtype.names[1:]))
    for name in ref.dtype.names[1:]:
        assert rel(res[name][:len(ref)], ref[name]) <= TOL, name
    folder = xc.models["soil"]
    ref, inp = (read_csv(str(folder / f"soil_{k}.csv")) for k in ("ref", "in"))
    assert ref.dtype["g_raft_u"].shape == (3,) and inp.dtype["x_w"].shape == (N,)
    names = list(inp.dtype.names[1:])
    vectors = list(dict.fromkeys(vector3(n) for n in names))          # x_raft_u, x_raft_r, x_w: x ...
    rows = []
    with FmuSlave(folder / "soil.fmu", "soil") as g:
        g.initialize()
        for k in range(len(inp) - 1):
            g.set(*vectors, np.concatenate([np.atleast_1d(inp[n][k]) for n in names]))
            g.do_step(k * DT, DT)
            rows.append(g.get("g").copy())
    g_ref = np.hstack([ref["g_raft_u"], ref["g_raft_r"]])[1:]
    assert np.abs(g_ref).max() > 0 and rel(np.array(rows)[:, :6], g_ref) <= TOL


def test_cli_export_fmi_version_3(tmp_path, monkeypatch, capsys):
    """``uplift export --fmi-version 3`` writes FMI 3.0 FMUs and cross-check folders under
    fmus/3.0; FMI 3.0 with --kind python is refused before any computation (exit 2)."""
    from orchestrator.cli import main
    from orchestrator.crosscheck import model_folder
    from helpers import export_tower, write_scene
    monkeypatch.setenv("UPLIFT_CACHE", str(tmp_path / "cache"))
    scene = tmp_path / "toy.toml"
    write_scene(scene, export_tower())
    out, xdir = tmp_path / "fmus", tmp_path / "xc"
    assert main(["export", str(scene), "-o", str(out), "--fmi-version", "3", "--cross-check", str(xdir)]) == 0
    err = capsys.readouterr().err
    assert "WARNING" not in err
    for model in ROLES:
        assert read_model_description(str(out / f"{model}.fmu")).fmiVersion == "3.0"
        assert (model_folder(xdir, model, 3) / f"{model}_ref.csv").is_file()
    assert main(["export", str(scene), "-o", str(tmp_path / "py"), "--fmi-version", "3", "--kind", "python"]) == 2
    assert "--fmi-version 3" in capsys.readouterr().err and not (tmp_path / "py").exists()
