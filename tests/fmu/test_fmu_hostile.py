"""Hostile calls on the exported FMUs: each returns a failed status with a log message and the
host survives; a refused step leaves the instance usable. Each case runs in a subprocess so
that a crash would be seen (exit by a signal) instead of killing the test run.

What pythonfmu (the Python FMU wrapper) lets a Python FMU say: OK, fmi2Discard (``do_step``
returns False) or fmi2Fatal (any exception, its message in the log). A step that cannot be
right is fmi2Fatal, so that hosts stop on it (fmpy's simulate_fmu ends a run silently on
fmi2Discard); the instance is left as it was and still answers if the host calls again (the
standard allows no further call after fmi2Fatal, but a host that does must not crash). What the
guard in front of pythonfmu refuses itself (a call out of its state, an unknown value reference:
fmus/pyguard.py, tests/fmu/test_python_fmu_guard.py) is fmi2Error.
"""

import pytest

from helpers.fmu_host import ERROR, FATAL, OK, run_host


@pytest.mark.parametrize("case, message", [
    ("nan", "inputs must be finite"),
    ("negative-time", "steps must follow one another"),
    ("skipped-time", "steps must follow one another"),
    ("after-terminate", "after fmi2Terminate"),
    ("before-init", "before initialisation"),
    ("bad-stamp", "stamped x_time"),
])
def test_refused_step_is_reported_and_the_instance_survives(exported, case, message):
    out = run_host(exported.soil, case)
    assert out["status"] in (ERROR, FATAL) and message in out["log"]
    if "after" in out:
        assert out["after"] == OK


def test_unknown_value_reference_is_not_ok(exported):
    out = run_host(exported.soil, "bad-vr")
    assert out["status"] in (ERROR, FATAL) and "value references 1000000" in out["log"]
    assert out["after"] == OK and out["step"] == OK


def test_initialisation_without_scipy_fails_loudly(exported):
    out = run_host(exported.structure, "no-scipy")
    assert out["status"] in (ERROR, FATAL)
    assert "initialisation failed" in out["log"] and "pip install -r" in out["log"]
    # the traceback whole (the guard passes pythonfmu's long messages on uncut), and the
    # exception's own report names the cause too (not pythonfmu's "unknown error")
    assert "Traceback" in out["log"] and "import scipy" in out["log"] and "unknown error" not in out["log"]
    assert "RuntimeError(\"initialisation failed" in out["log"]


def test_host_modules_of_the_same_name_do_not_shadow_the_fmu(exported):
    for fmu in (exported.structure, exported.soil, exported.coupled):
        out = run_host(fmu, "shadowed")
        assert out["status"] == OK, out["log"]
