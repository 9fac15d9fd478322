"""The guard of the python FMUs (fmus/pyguard.py, fmus/pyguard_c/guard.c): every misuse that
crashed pythonfmu's library or was silently accepted is refused with fmi2Error (fmi2Instantiate:
NULL) and a logged reason, and the next legal call works; legal calls give what pythonfmu gives.

All cases run in one child process (a crash would be its death by a signal), through ctypes on
the FMU's shipped binary (no fmpy wrapper in between: the raw pointers a host may pass), on the
session's python export (``exported``) and one state of the native soil FMU (``exported_native``).
The child frees everything and exits normally, so a crash at teardown is seen too.
"""
import json
import re
import shutil
import subprocess
import sys
import textwrap
import zipfile

import pytest

from helpers import EXPORT_MOTION

DT = EXPORT_MOTION.dt
OK, ERROR = 0, 3
STEPS = 12

HOST = textwrap.dedent(r"""
    import ctypes, json, sys
    from ctypes import POINTER, byref, c_char_p, c_double, c_int, c_size_t, c_uint, c_void_p
    from fmpy import extract, read_model_description
    coupled_path, soil_path, native_path, dt, steps = sys.argv[1:6]
    dt, steps = float(dt), int(steps)
    LOGGER = ctypes.CFUNCTYPE(None, c_void_p, c_char_p, c_int, c_char_p, c_char_p)

    class Callbacks(ctypes.Structure):
        _fields_ = [("logger", LOGGER), ("allocateMemory", c_void_p), ("freeMemory", c_void_p),
                    ("stepFinished", c_void_p), ("componentEnvironment", c_void_p)]

    log = []
    logger = LOGGER(lambda env, name, status, category, message: log.append(message.decode("utf-8", "replace")))
    CALLBACKS = Callbacks(logger)
    SIGNATURES = {
        "fmi2Instantiate": (c_void_p, [c_char_p, c_int, c_char_p, c_char_p, POINTER(Callbacks), c_int, c_int]),
        "fmi2FreeInstance": (None, [c_void_p]),
        "fmi2SetDebugLogging": (c_int, [c_void_p, c_int, c_size_t, c_void_p]),
        "fmi2SetupExperiment": (c_int, [c_void_p, c_int, c_double, c_double, c_int, c_double]),
        "fmi2EnterInitializationMode": (c_int, [c_void_p]), "fmi2ExitInitializationMode": (c_int, [c_void_p]),
        "fmi2Terminate": (c_int, [c_void_p]), "fmi2Reset": (c_int, [c_void_p]),
        "fmi2DoStep": (c_int, [c_void_p, c_double, c_double, c_int]),
        "fmi2GetRealStatus": (c_int, [c_void_p, c_int, c_void_p]),
        "fmi2GetDirectionalDerivative": (c_int, [c_void_p] + [c_void_p, c_size_t] * 2 + [c_void_p, c_void_p]),
        "fmi2GetFMUstate": (c_int, [c_void_p, c_void_p]), "fmi2SetFMUstate": (c_int, [c_void_p, c_void_p]),
        "fmi2FreeFMUstate": (c_int, [c_void_p, c_void_p]),
        "fmi2SerializedFMUstateSize": (c_int, [c_void_p, c_void_p, c_void_p]),
        "fmi2SerializeFMUstate": (c_int, [c_void_p, c_void_p, c_void_p, c_size_t]),
        "fmi2DeSerializeFMUstate": (c_int, [c_void_p, c_void_p, c_size_t, c_void_p])}
    for name in ("Real", "Integer", "Boolean", "String"):
        SIGNATURES[f"fmi2Get{name}"] = SIGNATURES[f"fmi2Set{name}"] = (c_int, [c_void_p, c_void_p, c_size_t, c_void_p])

    class Fmu:
        def __init__(self, path, library=None):
            self.md = read_model_description(path)
            self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
            self.folder = str(extract(path))
            self.uri = f"file://{self.folder}/resources"
            library = library or self.md.coSimulation.modelIdentifier + ".so"
            self.lib = ctypes.CDLL(f"{self.folder}/binaries/linux64/{library}")
            for name, (restype, argtypes) in SIGNATURES.items():
                f = getattr(self.lib, name)
                f.restype, f.argtypes = restype, argtypes

        def __getattr__(self, name):
            return getattr(self.lib, "fmi2" + name)

        def new(self, guid=True, uri=True, kind=1, name=b"host", callbacks=CALLBACKS):
            # an instance (None: refused); guid, uri True: the FMU's own
            guid = self.md.guid.encode() if guid is True else guid
            uri = self.uri.encode() if uri is True else uri
            return self.Instantiate(name, kind, guid, uri, byref(callbacks), 0, 0)

        def start(self, c):
            return self.SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0) | self.EnterInitializationMode(c) \
                | self.ExitInitializationMode(c)

    def refs(*vrs):
        return (c_uint * len(vrs))(*vrs)

    def reals(n, value=0.0):
        return (c_double * n)(*[value] * n)

    out = {}

    def case(name, status):
        out[name] = [None if status is None else int(status), chr(10).join(log[mark[0]:])]
        mark[0] = len(log)

    mark = [0]
    fmu, soil, native = Fmu(coupled_path), Fmu(soil_path), Fmu(native_path)
    vr = fmu.vr
    outs = refs(*[vr[n] for n in vr if n.startswith(("x[", "max_uplift", "energy."))])
    one_out, motion = refs(vr["x[2]"]), refs(vr["internal_motion"])

    def outputs(c, f=fmu):
        values = reals(len(outs))
        assert f.GetReal(c, outs, len(outs), values) == 0
        return list(values)

    def run(c, k0=0, f=fmu):
        for k in range(k0, k0 + steps):
            assert f.DoStep(c, k * dt, dt, 1) == 0, log[-3:]
        return outputs(c, f)

    # ---- fmi2Instantiate: refused with NULL, the reason logged ---------------------------------
    folder = fmu.folder.encode()
    for name, kwargs in (("wrong-guid", dict(guid=b"{not-this-one}")), ("null-guid", dict(guid=None)),
                         ("missing-folder", dict(uri=fmu.uri.encode() + b"/nowhere")),
                         ("not-a-uri", dict(uri=b"http://example.com/resources")),
                         ("relative-path", dict(uri=b"nowhere/resources")), ("null-location", dict(uri=None)),
                         ("bad-escape", dict(uri=b"file://" + folder + b"/resources%zz")),
                         ("model-exchange", dict(kind=0)), ("empty-name", dict(name=b"")),
                         ("other-fmus-resources", dict(uri=soil.uri.encode()))):
        case(name, int(fmu.new(**kwargs) is None))
    quiet = fmu.new(callbacks=Callbacks())                           # no logger: still guarded
    case("no-logger", fmu.DoStep(quiet, 0.0, dt, 1))
    fmu.FreeInstance(quiet)
    bare = fmu.Instantiate(b"host", 1, fmu.md.guid.encode(), fmu.uri.encode(), None, 0, 0)   # no callbacks
    case("null-callbacks", int(bare is not None) | fmu.start(bare) << 1 | fmu.DoStep(bare, 0.0, dt, 1) << 3)
    fmu.FreeInstance(bare)
    alt = fmu.new(uri=b"file:" + folder + b"/resources")             # the other file URI form, decoded
    case("file-colon-uri", int(alt is not None))
    fmu.FreeInstance(alt)

    # ---- NULL and foreign instances, calls out of their state, value references --------------
    c, ref = fmu.new(), fmu.new()
    junk = ctypes.create_string_buffer(256)                          # readable, but no instance
    v = reals(1)
    case("null-instance-step", fmu.DoStep(None, 0.0, dt, 1))
    case("null-instance-get", fmu.GetReal(None, one_out, 1, v))
    case("foreign-instance-step", fmu.DoStep(junk, 0.0, dt, 1))
    case("null-instance-state", fmu.GetFMUstate(None, byref(c_void_p())))
    fmu.FreeInstance(None)
    case("before-init", fmu.DoStep(c, 0.0, dt, 1))
    case("exit-before-enter", fmu.ExitInitializationMode(c))
    case("null-refs", fmu.GetReal(c, None, 1, v))
    case("null-values", fmu.GetReal(c, one_out, 1, None))
    case("null-set-values", fmu.SetReal(c, refs(vr["ag_x"]), 1, None))
    case("bad-vr", fmu.GetReal(c, refs(10 ** 6), 1, v))
    case("no-integers", fmu.GetInteger(c, refs(0), 1, (c_int * 1)()))
    case("set-output", fmu.SetReal(c, one_out, 1, reals(1, 1.0)))
    case("set-parameter-before-init", fmu.SetBoolean(c, motion, 1, (c_int * 1)(1)))
    case("init", fmu.start(c))
    case("setup-after-init", fmu.SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0))
    case("set-parameter-after-init", fmu.SetBoolean(c, motion, 1, (c_int * 1)(0)))
    flag = (c_int * 1)()
    fmu.GetBoolean(c, motion, 1, flag)
    out["parameter-kept"] = flag[0]
    before = reals(1)
    fmu.GetReal(c, one_out, 1, before)
    case("set-output-after-init", fmu.SetReal(c, one_out, 1, reals(1, 123.0)))
    after = reals(1)
    fmu.GetReal(c, one_out, 1, after)
    out["output-kept"] = after[0] == before[0]
    case("set-input-after-init", fmu.SetReal(c, refs(vr["ag_x"]), 1, reals(1, 0.0)))
    case("status-null", fmu.GetRealStatus(c, 2, None))
    case("logging-null-categories", fmu.SetDebugLogging(c, 1, 2, None))
    case("logging-on", fmu.SetDebugLogging(c, 1, 0, None))
    case("directional-derivative", fmu.GetDirectionalDerivative(c, None, 0, None, 0, None, None))
    # the refused calls changed nothing: the same steps as an instance that was never misused
    fmu.start(ref)
    clean = run(ref)
    out["moved"] = max(abs(x) for x in clean) > 0                   # the comparisons below mean something
    out["misused-equals-clean"] = run(c) == clean
    raw = Fmu(coupled_path, "pythonfmu-export.so")                  # pythonfmu's library, unguarded
    rc = raw.new()
    raw.start(rc)
    out["guarded-equals-pythonfmu"] = run(rc, f=raw) == clean
    raw.FreeInstance(rc)

    # ---- FMU states --------------------------------------------------------------------------
    s, other, nat = c_void_p(), c_void_p(), c_void_p()
    case("get-state-null", fmu.GetFMUstate(c, None))
    case("get-state", fmu.GetFMUstate(c, byref(s)))
    fmu.GetFMUstate(ref, byref(other))
    nc = native.new()
    native.start(nc)
    native.GetFMUstate(nc, byref(nat))
    nsize = c_size_t()
    native.SerializedFMUstateSize(nc, nat, byref(nsize))
    nbytes = ctypes.create_string_buffer(nsize.value)
    native.SerializeFMUstate(nc, nat, nbytes, nsize)
    sc = soil.new()
    soil.start(sc)
    ss, ssize = c_void_p(), c_size_t()
    soil.GetFMUstate(sc, byref(ss))
    soil.SerializedFMUstateSize(sc, ss, byref(ssize))
    sbytes = ctypes.create_string_buffer(ssize.value)
    soil.SerializeFMUstate(sc, ss, sbytes, ssize)
    case("set-null-state", fmu.SetFMUstate(c, None))
    case("set-unmapped-state", fmu.SetFMUstate(c, 0x10))             # never dereferenced
    case("set-junk-state", fmu.SetFMUstate(c, junk))
    case("set-other-instances-state", fmu.SetFMUstate(c, other))
    case("set-native-state", fmu.SetFMUstate(c, nat))
    case("free-unmapped-state", fmu.FreeFMUstate(c, byref(c_void_p(0x10))))
    case("free-null-pointer", fmu.FreeFMUstate(c, None))
    size = c_size_t()
    case("size-null", fmu.SerializedFMUstateSize(c, s, None))
    case("size-of-native-state", fmu.SerializedFMUstateSize(c, nat, byref(size)))
    fmu.SerializedFMUstateSize(c, s, byref(size))
    good = ctypes.create_string_buffer(size.value)
    case("serialize-short-buffer", fmu.SerializeFMUstate(c, s, good, size.value - 1))
    case("serialize-null-buffer", fmu.SerializeFMUstate(c, s, None, size.value))
    case("serialize", fmu.SerializeFMUstate(c, s, good, size.value))
    s2 = c_void_p()
    case("deserialize-null-bytes", fmu.DeSerializeFMUstate(c, None, size.value, byref(s2)))
    damaged = ctypes.create_string_buffer(good.raw, size.value)
    damaged[size.value // 2] = bytes([damaged.raw[size.value // 2] ^ 1])
    case("deserialize-damaged", fmu.DeSerializeFMUstate(c, damaged, size.value, byref(s2)))
    case("deserialize-native-bytes", fmu.DeSerializeFMUstate(c, nbytes, nsize.value, byref(s2)))
    # a well-formed state of another python FMU: the guard forwards it, the FMU refuses it by name
    case("deserialize-soil-bytes", fmu.DeSerializeFMUstate(c, sbytes, ssize.value, byref(s2)))
    case("set-soil-state", fmu.SetFMUstate(c, s2))
    case("free-soil-state", fmu.FreeFMUstate(c, byref(s2)))
    # the legal round trip still works, bit for bit
    first = run(c, steps)
    s3 = c_void_p()
    case("deserialize", fmu.DeSerializeFMUstate(c, good, size.value, byref(s3)) | fmu.SetFMUstate(c, s3))
    out["replay-equal"] = run(c, steps) == first
    held = s.value
    case("get-state-again", fmu.GetFMUstate(c, byref(s)))            # the same wrapper, overwritten
    out["state-reused"] = s.value == held
    case("free-states", fmu.FreeFMUstate(c, byref(s)) | fmu.FreeFMUstate(c, byref(s3)))
    out["freed-to-null"] = s.value is None and s3.value is None
    case("free-freed", fmu.SetFMUstate(c, held))

    # ---- after terminate, reset --------------------------------------------------------------
    case("terminate", fmu.Terminate(c))
    case("set-input-after-terminate", fmu.SetReal(c, refs(vr["ag_x"]), 1, reals(1)))
    case("step-after-terminate", fmu.DoStep(c, 2 * steps * dt, dt, 1))
    case("reset", fmu.Reset(c) | fmu.start(c) | fmu.DoStep(c, 0.0, dt, 1))
    # pythonfmu adds the resources folder to sys.path at every instantiation: one entry stays
    out["path-entries"] = sys.path.count(fmu.folder + "/resources")
    for f, inst, state in ((fmu, ref, other), (native, nc, nat), (soil, sc, ss), (fmu, c, None)):
        if state is not None:
            f.FreeFMUstate(inst, byref(state))
        f.FreeInstance(inst)
    print(json.dumps(out))
""")

#: fmi2Status of each case (0 OK, 3 fmi2Error); instantiations: 1 = refused (NULL)
EXPECTED = {
    "wrong-guid": (1, "GUID {not-this-one} does not match"), "null-guid": (1, "GUID (null) does not match"),
    "missing-folder": (1, "uplift_guard.txt cannot be opened"), "not-a-uri": (1, "is not a file URI"),
    "relative-path": (1, "cannot be opened"), "null-location": (1, "fmuResourceLocation (null)"),
    "bad-escape": (1, "is not a file URI"), "model-exchange": (1, "co-simulation only"),
    "empty-name": (1, "instanceName is empty"), "other-fmus-resources": (1, "belongs to another FMU"),
    "no-logger": (ERROR, ""), "null-callbacks": (1, ""), "file-colon-uri": (1, ""),
    "null-instance-step": (ERROR, ""), "null-instance-get": (ERROR, ""), "foreign-instance-step": (ERROR, ""),
    "null-instance-state": (ERROR, ""),
    "before-init": (ERROR, "fmi2DoStep before initialisation"),
    "exit-before-enter": (ERROR, "fmi2ExitInitializationMode is not allowed before fmi2EnterInitializationMode"),
    "null-refs": (ERROR, "NULL value reference or value array"), "null-values": (ERROR, "NULL value reference"),
    "null-set-values": (ERROR, "NULL value reference"), "bad-vr": (ERROR, "value references 1000000"),
    "no-integers": (ERROR, "this FMU has no Integer variables"), "set-output": (ERROR, "is an output"),
    "set-parameter-before-init": (OK, ""), "init": (OK, ""),
    "setup-after-init": (ERROR, "fmi2SetupExperiment is not allowed after initialisation"),
    "set-parameter-after-init": (ERROR, "is a fixed parameter: set it before fmi2ExitInitializationMode"),
    "set-output-after-init": (ERROR, "is an output"), "set-input-after-init": (OK, ""),
    "status-null": (ERROR, "value pointer is NULL"),
    "logging-null-categories": (ERROR, "categories is NULL"), "logging-on": (OK, ""), "directional-derivative": (ERROR, "not provided by this FMU"),
    "get-state-null": (ERROR, "FMUstate pointer is NULL"), "get-state": (OK, ""),
    "set-null-state": (ERROR, "not an FMU state of this FMU"), "set-unmapped-state": (ERROR, "not an FMU state"),
    "set-junk-state": (ERROR, "not an FMU state"), "set-other-instances-state": (ERROR, "not an FMU state"),
    "set-native-state": (ERROR, "not an FMU state"), "free-unmapped-state": (ERROR, "not an FMU state"),
    "free-null-pointer": (ERROR, "FMUstate pointer is NULL"), "size-null": (ERROR, "size pointer is NULL"),
    "size-of-native-state": (ERROR, "not an FMU state"), "serialize-short-buffer": (ERROR, "this state needs"),
    "serialize-null-buffer": (ERROR, "this state needs"), "serialize": (OK, ""),
    "deserialize-null-bytes": (ERROR, "the byte array is NULL"),
    "deserialize-damaged": (ERROR, "checksum mismatch"), "deserialize-native-bytes": (ERROR, "not an uplift FMU state"),
    "deserialize-soil-bytes": (OK, ""), "set-soil-state": (4, "a state of another FMU"), "free-soil-state": (OK, ""),
    "deserialize": (OK, ""), "get-state-again": (OK, ""), "free-states": (OK, ""), "free-freed": (ERROR, "not an FMU state"),
    "terminate": (OK, ""), "set-input-after-terminate": (ERROR, "no variable can be set after fmi2Terminate"),
    "step-after-terminate": (ERROR, "fmi2DoStep after fmi2Terminate"), "reset": (OK, ""),
}


@pytest.mark.slow             # about 5 s: one child loading three FMUs
def test_every_misuse_is_refused_with_a_reason_and_the_next_call_works(exported, exported_native):
    proc = subprocess.run([sys.executable, "-c", HOST, str(exported.coupled), str(exported.soil),
                           str(exported_native.soil), repr(DT), str(STEPS)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"host died ({proc.returncode}): {proc.stderr[-3000:]}"
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    got = {name: out[name][0] for name in EXPECTED}
    assert got == {name: status for name, (status, _) in EXPECTED.items()}
    for name, (_, message) in EXPECTED.items():
        assert message in out[name][1], (name, out[name][1])
    for name, (status, _) in EXPECTED.items():                  # every refusal says why (a logger exists)
        if status in (1, ERROR) and not name.startswith(("null-instance", "foreign-instance", "no-logger",
                                                          "null-callbacks", "file-colon")):
            assert out[name][1].strip(), name
        assert "unknown error" not in out[name][1], name
    assert out["parameter-kept"] == 1 and out["output-kept"]
    assert out["moved"] and out["misused-equals-clean"] and out["guarded-equals-pythonfmu"] and out["replay-equal"]
    assert out["state-reused"] and out["freed-to-null"]
    assert out["path-entries"] == 1


def test_the_fmu_ships_the_guard_in_front_of_pythonfmu(exported, tmp_path):
    """binaries/<platform>/<id>.<ext> is the guard (the FMI 2.0 entry points, no Python symbol),
    pythonfmu's library beside it, and the variable table matches the model description."""
    from fmpy import read_model_description
    from fmus.pyguard import CAUSALITIES, TABLE_FILE, guard_table
    md = read_model_description(str(exported.structure))
    ident = md.coSimulation.modelIdentifier
    with zipfile.ZipFile(exported.structure) as z:
        table = z.read(f"resources/{TABLE_FILE}").decode()
        assert table == guard_table(z.read("modelDescription.xml"))
        guard, inner = (z.read(f"binaries/linux64/{n}") for n in (f"{ident}.so", "pythonfmu-export.so"))
        windows = {n: z.read(f"binaries/win64/{n}") for n in (f"{ident}.dll", "pythonfmu-export.dll")}
    assert b"fmi2DoStep" in guard and b"Py_Initialize" not in guard and b"PyGILState_Ensure" in inner
    if shutil.which("objdump"):           # the Windows guard: pythonfmu's entry points, the C runtime only
        dumps = {}
        for name, blob in windows.items():
            path = tmp_path / name
            path.write_bytes(blob)
            dumps[name] = subprocess.run(["objdump", "-p", str(path)], check=True, capture_output=True,
                                         text=True).stdout
        entries = {n: set(re.findall(r"\]\s+(fmi2\w+)", d)) for n, d in dumps.items()}
        assert len(entries[f"{ident}.dll"]) > 30 and entries[f"{ident}.dll"] == entries["pythonfmu-export.dll"]
        dlls = {d.lower() for d in re.findall(r"DLL Name: (\S+)", dumps[f"{ident}.dll"])}
        assert all(d == "kernel32.dll" or d.startswith("api-ms-win-crt-") for d in dlls), dlls
    lines = table.splitlines()
    assert lines[1] == f"guid {md.guid}"
    rows = {int(line.split()[1]): line.split() for line in lines[3:]}
    assert len(rows) == len(md.modelVariables)
    for v in md.modelVariables:
        assert CAUSALITIES[int(rows[v.valueReference][2])] == v.causality, v.name


@pytest.mark.parametrize("text, codes", [
    ('<ScalarVariable name="p" valueReference="4" causality="parameter" variability="fixed"><Boolean start="true"/>'
     '</ScalarVariable>', "Boolean 4 0 1 0"),
    ('<ScalarVariable name="u" valueReference="0" causality="input"><Real start="0"/></ScalarVariable>',
     "Real 0 2 4 0"),
    ('<ScalarVariable name="y" valueReference="1" causality="output"><Real/></ScalarVariable>', "Real 1 3 4 2"),
    ('<ScalarVariable name="k" valueReference="2" causality="parameter" variability="tunable" initial="approx">'
     '<Integer start="1"/></ScalarVariable>', "Integer 2 0 2 1"),
])
def test_the_variable_table_follows_the_fmi_defaults(text, codes):
    """causality local and variability continuous (Real) / discrete (others) when absent; initial
    exact for parameters and inputs, calculated for outputs (FMI 2.0, section 2.2.7)."""
    from fmus.pyguard import guard_table
    md = f'<fmiModelDescription guid="{{g}}"><ModelVariables>{text}</ModelVariables></fmiModelDescription>'
    lines = guard_table(md.encode()).splitlines()
    assert lines[:2] == ["uplift-pyguard 1", "guid {g}"] and lines[3] == codes
