"""Linear frequency-domain route vs the Newmark route (contact disabled, bonded raft)."""
import numpy as np

from structure import ContactSettings, simulate

from orchestrator.timefreq import GridOptions, linear_fd
from helpers import COARSE_RAFT, rel, smooth_pulse
from helpers import broadband as motion

MODEL, soil = COARSE_RAFT.model, COARSE_RAFT.soil

BONDED = ContactSettings(enabled=False)


def test_bilinear_map_equals_newmark_to_roundoff():
    ag = motion(0.5)
    td = simulate(MODEL, soil(), ag, 0.005, contact=BONDED)
    fd = linear_fd(MODEL, soil(), ag, 0.005, contact=BONDED,
                   grid=GridOptions(bilinear=True, wrap_tol=1e-10, pad_s=20.0))
    for name in td.acc:
        assert rel(fd.acc[name], td.acc[name]) < 1e-8, name
    assert rel(fd.raft[:, [0, 2, 4]], td.raft[:, [0, 2, 4]]) < 1e-8
    assert rel(fd.contact_force - fd.info["P0"], td.contact_force - td.info["P0"]) < 1e-8


def test_newmark_converges_to_fd_with_order_two():
    """K(w) = K + i w C: the FD route is the exact solution; Newmark's error falls as dt^2."""
    ref = linear_fd(MODEL, soil(), smooth_pulse(0.00125), 0.00125, contact=BONDED)
    errs = []
    dts = (0.01, 0.005, 0.0025)
    for dt in dts:
        td = simulate(MODEL, soil(), smooth_pulse(dt), dt, contact=BONDED)
        step = round(dt / 0.00125)
        errs.append(rel(td.acc["top_outer"][:, 0], ref.acc["top_outer"][::step, 0]))
    rate = np.polyfit(np.log(dts), np.log(errs), 1)[0]
    assert 1.8 < rate < 2.3, (errs, rate)
    assert errs[-1] < 0.01


def test_padding_independent_once_rule_met():
    """Pad = the rule (max(1 s, 3 tau_1)) vs 2.5x the rule, same eta: < 0.1 % everywhere for a
    smooth input; for a broadband input (content up to Nyquist) the structure's floors and the
    raft motion stay < 0.1 %, the raft node's absolute acceleration (the input's own
    near-Nyquist content passes straight through the stiff soil) moves by up to 0.5 % in the
    last samples: the sampled input's band-limited interpolation, not wrap-around."""
    for ag, floors_only in ((smooth_pulse(0.005), False), (motion(0.5), True)):
        a = linear_fd(MODEL, soil(), ag, 0.005, contact=BONDED)
        b = linear_fd(MODEL, soil(), ag, 0.005, contact=BONDED, grid=GridOptions(pad_s=2.5 * a.info["pad_rule_s"]))
        assert a.info["pad_s"] >= a.info["pad_rule_s"]
        assert b.info["nfft"] > a.info["nfft"] and b.info["eta"] == a.info["eta"]
        for name in a.acc:
            if floors_only and name == "raft":
                continue
            assert rel(a.acc[name], b.acc[name]) < 1e-3, name
        assert rel(a.raft[:, [0, 2, 4]], b.raft[:, [0, 2, 4]]) < 1e-3


def test_rational_soil_splits_time_step_error_from_fit_error():
    """The ladder's step (b) on a frequency-dependent passive rational soil: linear FD with the
    recursion's z-transform (bilinear grid) equals the bonded Newmark run to round-off, and
    linear FD with the model itself (continuous grid) differs from it by the time-step error
    only (O(dt^2): halving dt divides the peak raft rotation gap by ~4)."""
    from helpers import oscillator_model
    from soil_impedance.convolution import RecursiveConvolutionSoil

    w = soil()
    K = w.static_stiffness().toarray()
    C = w.instantaneous(0.005)[1].toarray()
    model = oscillator_model(K, C, terms=[(0.3, 0.02, 0.3 / (2 * np.pi * 6.0) ** 2, K)],
                             maxwell=[(0.2, 0.2 / (2 * np.pi * 15.0), K)])

    def peak_rotation(r):
        return np.hypot(r.raft[:, 3], r.raft[:, 4]).max()

    gaps = []
    for dt in (0.005, 0.0025):
        ag = smooth_pulse(dt)
        td = simulate(MODEL, RecursiveConvolutionSoil(model, dt), ag, dt, contact=BONDED)
        if dt == 0.005:
            bil = linear_fd(MODEL, RecursiveConvolutionSoil(model, dt), ag, dt, contact=BONDED,
                            grid=GridOptions(bilinear=True, wrap_tol=1e-10, pad_s=20.0))
            assert rel(bil.raft[:, [0, 2, 4]], td.raft[:, [0, 2, 4]]) < 1e-8
        fd = linear_fd(MODEL, model, ag, dt, contact=BONDED)
        gaps.append(abs(peak_rotation(fd) / peak_rotation(td) - 1))
    assert gaps[0] < 1e-4, gaps
    assert 3.0 < gaps[0] / gaps[1] < 5.0, gaps


def test_bonded_solve_by_groups_equals_a_dense_solve():
    """solve_bonded (a group of frequencies at a time, each group's soil matrices formed once:
    a table's band is never formed whole) against a dense solve of (S + diag kp) d = f per
    frequency: to 1e-12 for groups of 1, 5 and 32 frequencies, and the same bits on 1 and 2
    threads (the groups, not the threads, decide what is computed together). Its fallback
    (a dense solve per frequency, forced by allowing 2 sweeps) agrees to 1e-12 as well."""
    from orchestrator.timefreq import WorkerPool, prepare, solve_bonded
    from helpers import hysteretic_table

    with WorkerPool(2) as two, WorkerPool(1) as one:
        prob = prepare(MODEL, hysteretic_table(), motion(0.5), 0.005, contact=BONDED, pool=two,
                       grid=GridOptions().resolved(bilinear=False))
        op, kp = prob.op, prob.kp
        f_hat = prob.grid.to_freq(prob.f)
        out = {}
        for group in (1, 5, 32):
            out[group] = solve_bonded(op, f_hat, kp, group=group)
            op.pool = one
            assert np.array_equal(solve_bonded(op, f_hat, kp, group=group)[0], out[group][0])
            op.pool = two
        fallback = solve_bonded(op, f_hat, kp, max_sweeps=2)
        assert "K" not in op.soil.bands[0].__dict__            # formed a group at a time only
        allN = np.arange(kp.size)
        S = op.S_sub(allN, allN)
        S[:, allN, allN] += kp
        ref = np.linalg.solve(S, f_hat.T[:, :, None])[:, :, 0].T
    for group, (d, sweeps, how) in out.items():
        assert how == "richardson" and sweeps < 10 and rel(d, ref) < 1e-12, (group, how, sweeps)
    assert fallback[2] == "dense" and rel(fallback[0], ref) < 1e-12
