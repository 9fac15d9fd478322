"""Newmark stepper: order of accuracy, energy balance, external soil, rollback, HHT."""
import numpy as np

from helpers import FINE_RAFT, stepper_pulse as pulse
from structure import ContactSettings, NewmarkStepper, simulate
from structure.broadband import broadband_accelerogram

MODEL, soil = FINE_RAFT.model, FINE_RAFT.soil


def test_second_order_in_dt_linear():
    off = ContactSettings(enabled=False)
    ref_dt = 0.0003125
    ref = simulate(MODEL, soil(), pulse(ref_dt), ref_dt, contact=off)
    dts = np.array([0.005, 0.0025, 0.00125])
    errs = []
    for dt in dts:
        r = simulate(MODEL, soil(), pulse(dt), dt, contact=off)
        stride = int(round(dt / ref_dt))
        u = r.disp["top_outer"][:, 0]
        uref = ref.disp["top_outer"][::stride, 0][: u.size]
        errs.append(np.abs(u - uref).max() / np.abs(uref).max())
    rate = np.polyfit(np.log(dts), np.log(errs), 1)[0]
    assert 1.85 < rate < 2.15, (rate, errs)


def test_energy_balance_linear():
    ag = np.zeros((801, 3))
    ag[:, 0] = broadband_accelerogram(4.0, 0.005, 2.5, seed=3)
    r = simulate(MODEL, soil(), ag, 0.005, contact=ContactSettings(enabled=False))
    assert r.energy_balance_error() < 1e-6
    assert r.energy["damping"][-1] > 0 and r.energy["soil"][-1] > 0


def test_energy_with_contact_switching():
    ag = np.zeros((1201, 3))
    ag[:, 0] = broadband_accelerogram(6.0, 0.005, 0.5 * 9.81, seed=1)
    r = simulate(MODEL, soil(), ag, 0.005)
    assert r.max_uplift() > 1e-3                        # the raft did lift
    assert r.energy_balance_error() < 1e-6                            # discrete balance, contact work included
    # contact switching must not create energy: the physical penalty potential may not
    # exceed the work the contact forces absorbed by more than a tiny fraction of the input
    created = (r.energy["contact_potential"] - r.energy["contact"]).max()
    assert created < 1e-4 * r.energy["input"].max(), created / r.energy["input"].max()


def test_external_soil_and_rollback_match_monolithic():
    dt = 0.005
    ag = np.zeros((300, 3))
    ag[:, 0] = broadband_accelerogram(1.495, dt, 0.6 * 9.81, seed=5)
    s_int, s_ext = soil(), soil()
    a = NewmarkStepper(MODEL, s_int, dt, ag0=ag[0])
    b = NewmarkStepper(MODEL, s_ext, dt, ag0=ag[0], external_soil=True)
    for k in range(1, ag.shape[0]):
        a.set_ground_acceleration(ag[k])
        a.step()
        b.set_ground_acceleration(ag[k])
        b.set_soil_history(s_ext.history())
        if k == 200:                                    # rollback: redo a step from a saved state
            saved = b.get_state()
            b.step()
            first = b.u.copy()
            b.set_state(saved)
            b.set_ground_acceleration(ag[k])
        b.step()
        if k == 200:
            assert np.array_equal(first, b.u)
    assert np.array_equal(a.u, b.u)


def test_hht_damps_high_frequencies_and_agrees_at_low():
    dt = 0.005
    ag = pulse(dt, 3.0)
    off = ContactSettings(enabled=False)
    r0 = simulate(MODEL, soil(False), ag, dt, contact=off, damping=0.0)
    r1 = simulate(MODEL, soil(False), ag, dt, contact=off, damping=0.0, alpha=-0.1)
    # no physical damping: average acceleration conserves energy after the pulse, HHT dissipates
    e0 = sum(r0.energy[k] for k in ("kinetic", "strain", "soil", "contact"))
    e1 = sum(r1.energy[k] for k in ("kinetic", "strain", "soil", "contact"))
    assert abs(e0[-1] - r0.energy["input"][-1]) / e0[-1] < 1e-8
    assert e1[-1] < r1.energy["input"][-1]
    u0, u1 = r0.raft[:, 4], r1.raft[:, 4]
    assert np.abs(u0 - u1).max() < 0.05 * np.abs(u0).max()


def test_hht_with_contact_close_to_average_acceleration():
    dt = 0.005
    ag = np.zeros((1201, 3))
    ag[:, 0] = broadband_accelerogram(6.0, dt, 0.5 * 9.81, seed=1)
    r0 = simulate(MODEL, soil(), ag, dt)
    r1 = simulate(MODEL, soil(), ag, dt, alpha=-0.05)
    assert r1.converged and r1.newton_iters.max() <= 10
    assert abs(r1.max_uplift() - r0.max_uplift()) < 0.02 * r0.max_uplift()
    e = r1.energy
    residual = e["input"][-1] - sum(e[k][-1] for k in ("kinetic", "strain", "damping", "soil", "contact"))
    assert 0 <= residual < 0.01 * e["input"][-1]        # HHT only removes energy
