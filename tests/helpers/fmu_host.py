"""A Python host of an exported FMU in a subprocess (fmpy's raw FMI 2.0 calls): the hostile
calls of tests/fmus, each run apart so that a crash is seen as the host dying, not the tests.
``run_host(fmu, case)`` returns the host's JSON report (status of the call, the FMU's log, the
status of a call after it)."""
import json
import subprocess
import sys
import textwrap

from .cases import EXPORT_MOTION

DT = EXPORT_MOTION.dt

#: the part of a host script that opens the FMU (the script has set ``path`` and ``LOGGING`` and
#: imported fmpy's extract, read_model_description, FMU2Slave, fmi2CallbackFunctions,
#: fmi2CallbackLoggerTYPE and defaultCallbacks): ``md``, ``vr`` {name: value reference}, the
#: FMU's messages collected in ``log``, the instance ``f`` (library ``dll``, component ``c``)
OPEN_FMU2 = textwrap.dedent("""
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    log = []
    def logger(env, inst, status, cat, msg):
        log.append(msg.decode("utf-8", "replace"))
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory, cb.freeMemory = defaultCallbacks.allocateMemory, defaultCallbacks.freeMemory
    f = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="x")
    f.instantiate(callbacks=cb, loggingOn=LOGGING)
    dll, c = f.dll, f.component
""")

HOST = textwrap.dedent("""
    import json, math, sys
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, defaultCallbacks
    path, case, dt = sys.argv[1], sys.argv[2], float(sys.argv[3])
    if case == "no-scipy":
        sys.modules["scipy"] = None                       # a host Python without scipy
    if case == "shadowed":                                # a host with modules of the same names
        import types
        for name in ("structure", "fmus", "soil_impedance"):
            sys.modules[name] = types.ModuleType(name)
    LOGGING = True
""") + OPEN_FMU2 + textwrap.dedent("""
    import ctypes
    def set_real(name, value):
        return dll.fmi2SetReal(c, (ctypes.c_uint * 1)(vr[name]), 1, (ctypes.c_double * 1)(value))
    def step(t):
        return dll.fmi2DoStep(c, t, dt, 1)
    out = {}
    if case == "before-init":
        out["status"] = step(0.0)
    elif case == "no-scipy":
        dll.fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0)
        dll.fmi2EnterInitializationMode(c)
        out["status"] = dll.fmi2ExitInitializationMode(c)
    else:
        f.setupExperiment(startTime=0.0)
        f.enterInitializationMode()
        f.exitInitializationMode()
        if case == "nan":
            set_real("x[0]", math.nan)
            out["status"] = step(0.0)
            set_real("x[0]", 0.0)
            out["after"] = step(0.0)                     # usable again
        elif case == "negative-time":
            out["status"] = step(-dt)
            out["after"] = step(0.0)
        elif case == "skipped-time":
            out["status"] = step(5 * dt)
            out["after"] = step(0.0)
        elif case == "after-terminate":
            f.terminate()
            out["status"] = step(0.0)
        elif case == "bad-stamp":
            set_real("x_time", 7 * dt)
            out["status"] = step(0.0)
            set_real("x_time", 0.0)
            out["after"] = step(0.0)
        elif case == "shadowed":
            out["status"] = step(0.0)
        elif case == "bad-vr":
            value = (ctypes.c_double * 1)()
            out["status"] = dll.fmi2GetReal(c, (ctypes.c_uint * 1)(10 ** 6), 1, value)
            out["after"] = dll.fmi2GetReal(c, (ctypes.c_uint * 1)(0), 1, value)
            out["step"] = step(0.0)
            f.terminate()
            f.freeInstance()                             # then a garbage collection: no crash
            import gc
            gc.collect()
    out["log"] = chr(10).join(log)
    print(json.dumps(out))
    sys.stdout.flush()
    import os; os._exit(0)          # after fmi2Fatal the standard allows no further call (not even free)
""")

OK, ERROR, FATAL = 0, 3, 4


def run_host(fmu, case):
    proc = subprocess.run([sys.executable, "-c", HOST, str(fmu), case, repr(DT)], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, f"host died ({proc.returncode}): {proc.stderr[-2000:]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])
