"""Skipping what a run does not need, and saying so.

The linear pre-check (structure.ContactSettings.precheck): with the raft in full contact at rest
``simulate`` first runs the closed-contact (linear) recursion; without tension that is the
unilateral solution, because the penalty law is linear while the contact is closed. Checked
against the forced nonlinear path (Newton), which is an independent solver of the same
equations: the two agree to round-off amplified by the penalty's conditioning. With tension the
run falls back to the nonlinear stepper from t = 0 and gives exactly what the forced path gives.
The closed recursion itself is checked against ``NewmarkStepper.step()`` step by step (HHT too,
with a soil that has memory), energies included. Then the ``skipped`` lists of ``uplift run``:
present, in the JSON summary, and true (cache hits only when the cache was hit).
"""
import json

import numpy as np
import pytest

from helpers import changed, pulse_motion, rel, small_scene, soil_model, tower, winkler, write_scene

from soil_impedance.convolution import RecursiveConvolutionSoil
from structure import ContactSettings, NewmarkStepper, StructureError, contact_from_spec, simulate

SCENE = small_scene()                 # reactor stick on a 21-node raft over rock
MODEL = SCENE.model()
FORCED = ContactSettings(precheck=False)
TERMS = ("input", "kinetic", "strain", "damping", "soil", "contact", "contact_potential")


@pytest.mark.parametrize("soil_kind", ["winkler", "memory"])
def test_no_uplift_precheck_equals_forced_newton(soil_kind):
    m = pulse_motion(pga=2.0)                          # rocking, no uplift
    make = (lambda: winkler(SCENE)) if soil_kind == "winkler" else \
        (lambda: RecursiveConvolutionSoil(soil_model(SCENE), m.dt))
    pre = simulate(MODEL, make(), m.acc, m.dt, ContactSettings())
    new = simulate(MODEL, make(), m.acc, m.dt, FORCED)
    assert pre.notes.skipped == ("no tension in the linear pre-check: nonlinear contact iterations skipped",)
    assert pre.notes.precheck.startswith("no tension")
    assert new.notes.skipped == () and new.notes.precheck.startswith("off")
    assert pre.newton_iters.sum() == 0 and new.newton_iters[1:].min() >= 1
    assert pre.info["factorisations"] == 1
    # a real dynamic response, the contact closed throughout, the same histories
    assert np.abs(new.raft[:, 4]).max() > 1e-5 and new.max_uplift() == 0.0 == pre.max_uplift()
    dP = new.contact_force - new.info["P0"]
    assert np.abs(dP).max() > 1e-3 * new.info["P0"].min()
    assert rel(pre.raft, new.raft) <= 1e-10
    assert rel(pre.soil_w, new.soil_w) <= 1e-10
    assert rel(pre.contact_force - pre.info["P0"], dP) <= 1e-10
    for node in new.acc:
        assert rel(pre.acc[node], new.acc[node]) <= 1e-10
        assert rel(pre.disp[node], new.disp[node]) <= 1e-10
    for term in TERMS:
        assert np.abs(pre.energy[term] - new.energy[term]).max() <= 1e-10 * np.abs(new.energy["input"]).max()


def test_precheck_difference_is_penalty_round_off():
    """The closed solve and Newton differ by round-off amplified by the penalty's conditioning:
    the difference scales with the penalty (1e-13 at 100x the soil stiffness, 1e-12 at the
    default 1e4x, 1e-10 at 1e6x here), it is not a modelling difference."""
    m = pulse_motion(pga=2.0)
    kv = winkler(SCENE).kv
    diff = []
    for factor in (1e2, 1e6):
        pen = factor * kv
        pre = simulate(MODEL, winkler(SCENE), m.acc, m.dt, ContactSettings(penalty=pen))
        new = simulate(MODEL, winkler(SCENE), m.acc, m.dt, ContactSettings(penalty=pen, precheck=False))
        assert pre.newton_iters.sum() == 0
        diff.append(rel(pre.raft, new.raft))
    assert diff[0] <= 1e-12 and diff[1] > 10 * diff[0]


def test_uplift_falls_back_to_the_nonlinear_run_exactly():
    """A pulse that lifts the raft, on a soil with memory (recursive convolution): the pre-check
    stops at the first tension step, rolls the soil back and the result is bit for bit the
    forced nonlinear run; the tension step it reports is where the forced run first lifts."""
    model, m = soil_model(SCENE), pulse_motion(pga=8.0)
    pre = simulate(MODEL, RecursiveConvolutionSoil(model, m.dt), m.acc, m.dt, ContactSettings())
    new = simulate(MODEL, RecursiveConvolutionSoil(model, m.dt), m.acc, m.dt, FORCED)
    assert new.max_uplift() > 1e-2 and pre.notes.skipped == ()
    first = int(np.flatnonzero(new.gap.max(axis=1) > 0)[0])
    assert f"(step {first})" in pre.notes.precheck and "nonlinear run from t = 0" in pre.notes.precheck
    for name in ("raft", "gap", "contact_force", "soil_w", "newton_iters"):
        assert np.array_equal(getattr(pre, name), getattr(new, name)), name
    for term in TERMS:
        assert np.array_equal(pre.energy[term], new.energy[term]), term


def test_static_gap_skips_the_precheck():
    """A raft that is not in full contact at rest: the closed problem is not the unilateral one."""
    m = pulse_motion(pga=0.5)
    soil = winkler(SCENE)
    static = NewmarkStepper(MODEL, soil, m.dt).static
    P0 = static.P0.copy()
    P0[0] = 0.0
    lifted = type(static)(static.u, P0, np.where(np.arange(P0.size) == 0, 1e-6, static.d0), static.settlement,
                          static.iterations)
    r = simulate(MODEL, soil, m.acc, m.dt, ContactSettings(), static=lifted)
    assert r.notes.precheck.startswith("not run: 1 interface nodes are not in contact")
    assert r.newton_iters[1:].min() >= 1 and r.notes.skipped == ()


@pytest.mark.parametrize("soil_kind, alpha", [("winkler", 0.0), ("winkler", -0.1), ("memory", 0.0),
                                              ("memory", -0.05)])
def test_closed_run_is_the_stepper(soil_kind, alpha):
    """Bonded raft: simulate's closed recursion (one factorisation, outputs and energies over
    the whole history at the end) against NewmarkStepper.step() one step at a time."""
    m = pulse_motion(pga=8.0)
    make = (lambda: winkler(SCENE)) if soil_kind == "winkler" else \
        (lambda: RecursiveConvolutionSoil(soil_model(SCENE), m.dt))
    bonded = ContactSettings(enabled=False)
    res = simulate(MODEL, make(), m.acc, m.dt, bonded, alpha=alpha)
    assert res.notes.skipped == ("contact disabled: one linear solve per step, no Newton",)
    st = NewmarkStepper(MODEL, make(), m.dt, bonded, alpha=alpha, ag0=m.acc[0])
    ni = st.ni
    raft, P, top = [st.x[:6].copy()], [st.P.copy()], [st.a[MODEL.dofs(MODEL.node_by_name("top_outer").id)[:3]] + st.ag]
    energy = [st.energies()]
    for k in range(1, m.acc.shape[0]):
        st.set_ground_acceleration(m.acc[k])
        st.step()
        raft.append(st.u[ni:ni + 6].copy())
        P.append(st.P.copy())
        top.append(st.a[MODEL.dofs(MODEL.node_by_name("top_outer").id)[:3]] + st.ag)
        energy.append(st.energies())
    assert rel(res.raft, np.array(raft)) <= 1e-12
    assert rel(res.contact_force - st.P0, np.array(P) - st.P0) <= 1e-10
    assert rel(res.acc["top_outer"], np.array(top)) <= 1e-12
    scale = max(abs(e["input"]) for e in energy)
    for term in TERMS:
        assert np.abs(res.energy[term] - [e[term] for e in energy]).max() <= 1e-10 * scale, term


def test_precheck_scene_key():
    assert contact_from_spec({"precheck": False}).precheck is False
    assert contact_from_spec({}).precheck is True
    with pytest.raises(StructureError, match=r"contact.precheck = 'no' must be true or false"):
        contact_from_spec({"precheck": "no"})
    with pytest.raises(StructureError, match="allowed: auto_factor, enabled, penalty, precheck"):
        contact_from_spec({"pre_check": False})


BEM_SCENE = tower(soil={"winkler": None}, foundation={"element_size": 5.0},
                  impedance={"frequencies_hz": [0.0, 5.0, 10.0]}, output=None,
                  motion={"pga_g": 0.02, "duration_s": 1.0}, analysis={"routes": ["winkler", "linear"]})


def test_skipped_in_run_summary_and_true(tmp_path, capsys, monkeypatch):
    """uplift run --json: a first run computes the BEM sweep (a homogeneous half-space: K(0) from
    the closed-form static kernels), the second reads it from the cache and says so; the
    winkler route at 0.02 g on the Python stepper (the native one, without a compiler here, has
    no pre-check) skips its Newton iterations unless the scene forces them."""
    from fmus import native_stepper
    from fmus.native_build import NativeBuildError
    from orchestrator.cli import main

    def no_compiler(folder):
        raise NativeBuildError("no C compiler")

    monkeypatch.setattr(native_stepper, "_build", no_compiler)
    monkeypatch.setenv("UPLIFT_CACHE", str(tmp_path / "cache"))
    scene = tmp_path / "tiny.toml"
    write_scene(scene, BEM_SCENE)

    def run():
        assert main(["run", str(scene), "-o", str(tmp_path / "r.h5"), "--json"]) == 0
        return json.loads(capsys.readouterr().out)["routes"]

    first, second = run(), run()
    homog = "homogeneous half-space: K(0) from the closed-form static kernels (no wavenumber integral at 0 Hz)"
    assert homog in first["winkler"]["skipped"] and homog in first["linear"]["skipped"]
    for summ in first.values():
        assert "impedance sweep read from cache" not in summ["skipped"]
    for summ in second.values():
        assert "impedance sweep read from cache" in summ["skipped"] and homog not in summ["skipped"]
    assert "rigid raft: soil interface reduced from 3N = 12 to 6 + N = 10 DOFs" in second["linear"]["skipped"]
    assert "no tension in the linear pre-check: nonlinear contact iterations skipped" in second["winkler"]["skipped"]
    assert second["winkler"]["precheck"].startswith("no tension")
    assert second["winkler"]["max_uplift_m"] == 0.0
    from orchestrator.results_file import read_results
    assert list(read_results(tmp_path / "r.h5")["winkler"].notes.skipped) == second["winkler"]["skipped"]

    write_scene(scene, changed(BEM_SCENE, contact={"enabled": None, "precheck": False}))
    forced = run()["winkler"]
    assert forced["precheck"].startswith("off") and forced["skipped"] == ["impedance sweep read from cache"]
    assert forced["max_raft_rotation_rad"] == pytest.approx(second["winkler"]["max_raft_rotation_rad"], rel=1e-9)
