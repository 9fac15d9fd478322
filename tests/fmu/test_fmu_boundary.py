"""The FMI boundary of both kinds, from fmpy's low-level interface, each case in a fresh
process (a crash would be seen as the child's death):

- fmi2DoStep with an infinite, NaN or negative step, or one past the stop time given to
  fmi2SetupExperiment: not OK, logged, and the instance goes on (the next right step is OK);
  a communication step of more than MAX_STEPS_PER_CALL steps is refused before any work;
- the last step of a host that accumulates its time by repeated addition: after N steps the
  host asks for a sliver of 3e-14 s; it returns OK with the outputs unchanged, and the run
  goes on;
- serialised FMU states: 200 single-byte flips spread over the buffer are all refused (the
  native kind at fmi2DeSerializeFMUstate with fmi2Error; the Python kind, whose deserialiser
  pythonfmu calls without the instance, when the state is set), 200 refusals in a row in one
  process, the host alive; the unmodified buffer is accepted and gives the same next step
  bit for bit.
"""
import json
import subprocess
import sys
import textwrap

import pytest

from helpers import EXPORT_MOTION
from helpers.fmu_host import OPEN_FMU2

DT = EXPORT_MOTION.dt
OK = 0

HOST = textwrap.dedent("""
    import ctypes, json, math, sys
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, defaultCallbacks
    path, case, dt = sys.argv[1], sys.argv[2], float(sys.argv[3])
    LOGGING = case != "quiet"
""") + OPEN_FMU2 + textwrap.dedent("""
    stop = 40 * dt
    if case == "long":
        dll.fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0)            # no stop time
    else:
        dll.fmi2SetupExperiment(c, 0, 0.0, 0.0, 1, ctypes.c_double(stop))
    dll.fmi2EnterInitializationMode(c)
    dll.fmi2ExitInitializationMode(c)
    stamped = md.modelName == "UpliftSoil"
    outs = [v for v in vr if v.startswith(("g[", "x[", "max_uplift", "energy."))]
    out_vr = (ctypes.c_uint * len(outs))(*[vr[v] for v in outs])
    def outputs():
        values = (ctypes.c_double * len(outs))()
        dll.fmi2GetReal(c, out_vr, len(outs), values)
        return list(values)
    def step(t, h):
        if stamped:
            dll.fmi2SetReal(c, (ctypes.c_uint * 1)(vr["x_time"]), 1, (ctypes.c_double * 1)(t))
        return dll.fmi2DoStep(c, ctypes.c_double(t), ctypes.c_double(h), 1)
    out = {}
    t = 0.0
    for k in range(10):                                   # time accumulated by repeated addition
        assert step(t, dt) == 0, log
        t += dt
    if case == "steps":
        for name, h in (("inf", math.inf), ("nan", math.nan), ("negative", -dt), ("past-stop", 40 * dt)):
            out[name] = step(t, h)
            out[name + "-after"] = step(t, dt)             # the instance goes on
            t += dt
        before = outputs()
        out["sliver"] = step(t, 3e-14)
        out["sliver-unchanged"] = outputs() == before
        t += 3e-14
        statuses = []
        while t < stop - 0.5 * dt:                         # on to the stop time
            statuses.append(step(t, dt))
            t += dt
        out["rest"] = max(statuses)
        out["end"] = t
        out["final-sliver"] = step(t, 2.9e-14)             # the host's last sliver at the stop time
    elif case == "machine":
        out["setup"] = dll.fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0)
        out["enter"] = dll.fmi2EnterInitializationMode(c)
        out["exit"] = dll.fmi2ExitInitializationMode(c)
        out["step"] = step(t, dt)
    elif case == "quiet":
        out["refused"] = step(t, math.inf)
    elif case == "long":
        import time
        start = time.perf_counter()
        out["huge"] = step(t, 1e6)
        out["huge-seconds"] = time.perf_counter() - start
        out["huge-after"] = step(t, dt)
    elif case == "states":
        state = ctypes.c_void_p()
        size = ctypes.c_size_t()
        dll.fmi2GetFMUstate(c, ctypes.byref(state))
        dll.fmi2SerializedFMUstateSize(c, state, ctypes.byref(size))
        good = (ctypes.c_char * size.value)()
        out["serialize"] = dll.fmi2SerializeFMUstate(c, state, good, size)
        out["size"] = size.value
        assert step(t, dt) == 0
        first = outputs()
        accepted, positions = 0, sorted({(i * size.value) // 200 for i in range(200)})
        for pos in positions:
            bad = (ctypes.c_char * size.value).from_buffer_copy(good)
            bad[pos] = bytes([bad[pos][0] ^ 0x5A])
            s = ctypes.c_void_p()
            status = dll.fmi2DeSerializeFMUstate(c, bad, size, ctypes.byref(s))
            if status == 0:
                status = dll.fmi2SetFMUstate(c, s)
                dll.fmi2FreeFMUstate(c, ctypes.byref(s))
            accepted += status == 0
        out["flips"], out["flips-accepted"] = len(positions), accepted
        s = ctypes.c_void_p()
        out["good"] = dll.fmi2DeSerializeFMUstate(c, good, size, ctypes.byref(s)) | dll.fmi2SetFMUstate(c, s)
        out["replay"] = step(t, dt)
        out["replay-equal"] = outputs() == first
    out["log"] = chr(10).join(log)
    print(json.dumps(out))
    sys.stdout.flush()
    import os; os._exit(0)
""")


def run(fmu, case):
    proc = subprocess.run([sys.executable, "-c", HOST, str(fmu), case, repr(DT)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, f"host died ({proc.returncode}): {proc.stderr[-3000:]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(params=["python", "native"])
def fmus(request, exported, exported_native):
    return {"python": exported, "native": exported_native}[request.param]


@pytest.mark.parametrize("role", ["coupled", "soil"])
def test_impossible_steps_refused_and_the_last_sliver_taken(fmus, role):
    out = run(getattr(fmus, role), "steps")
    for name, message in (("inf", "finite and positive"), ("nan", "finite and positive"),
                          ("negative", "finite and positive"), ("past-stop", "past the stop time")):
        assert out[name] != OK and out[name + "-after"] == OK, name
        assert message in out["log"], name
    assert out["sliver"] == OK and out["sliver-unchanged"]
    assert out["rest"] == OK and out["end"] == pytest.approx(40 * DT, abs=1e-12)
    assert out["final-sliver"] == OK


def test_a_step_too_long_is_refused_up_front(fmus):
    out = run(fmus.coupled, "long")
    assert out["huge"] != OK and "more than 100000 steps" in out["log"] and out["huge-seconds"] < 5
    assert out["huge-after"] == OK


def test_calls_out_of_their_state_are_refused_by_the_guard(fmus):
    """The allowed-state masks (the native runtime's; the python kind's guard, fmus/pyguard.py,
    has the same): set-up and initialisation calls after initialisation are refused, naming the
    state; the instance goes on stepping."""
    out = run(fmus.soil, "machine")
    assert out["setup"] != OK and out["enter"] != OK and out["exit"] != OK and out["step"] == OK
    for fn in ("fmi2SetupExperiment", "fmi2EnterInitializationMode", "fmi2ExitInitializationMode"):
        assert f"{fn} is not allowed after initialisation" in out["log"], fn


def test_the_logging_flag_is_honoured(exported_native):
    """Events (instantiation, steps) are logged when logging is on; errors always."""
    loud, quiet = (run(exported_native.coupled, case) for case in ("long", "quiet"))
    assert "step(s) of dt" in loud["log"] and "instantiated from" in loud["log"]
    assert quiet["refused"] != OK and "finite and positive" in quiet["log"] and "step(s) of dt" not in quiet["log"]


@pytest.mark.parametrize("role", ["coupled", "soil"])
def test_damaged_serialised_states_are_refused(fmus, role):
    out = run(getattr(fmus, role), "states")
    assert out["serialize"] == OK and out["flips"] == 200 and out["flips-accepted"] == 0
    assert "checksum mismatch" in out["log"] or "not an uplift FMU state" in out["log"]
    assert out["good"] == OK and out["replay"] == OK and out["replay-equal"]
