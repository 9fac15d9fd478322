"""Rational fit of the reactor's gap impedance table ((6+241)², 101 frequencies to 25 Hz).

Prints error against model order (pole identification + residues of all entries), then the full
``fit_table`` (order selection + passivity check/enforcement) time, and writes soil_fit.png.
Last row (``linear_row``, alone with --linear): the scene's fit (fit_tol, as the monolithic route)
against the table on the rigid-raft impedance P^T K P over 2-8 Hz (the SSI band: rocking/sway mode
~3.75 Hz), and the bonded linear response's peak raft rotation split into fit error (linear FD
with the table vs with the fit sampled as a table) and time-step error (linear FD with the fitted
model vs bonded Newmark with its recursive convolution).
The order selection requires the rigid-raft Re and Im errors to meet fit_tol too (soil_impedance.fit,
"Order selection of a gap table"): on the (causal) reactor at fit_tol 0.01 that is 8 poles (rigid
rocking Im 0.26 % over 2-8 Hz, peak rotation fit error +0.006 %) instead of 4 (4.8 %, +0.50 %).
With --causal: the rigid-raft table causal vs hysteretic (sliding, vertical, rocking Re/Im at 0, 1,
4, 10 Hz), then the same last row for the reactor with ``[soil] damping_model = "causal"`` (the
scene's; constant Q with a 0.05 Hz cut-off, vs at 1 Hz: soil_impedance.profile) at fit_tol 0.04 (6
poles, rigid rocking Im 1.3 %, peak rotation −0.24 %, of which −0.18 % time step), the scene's 0.01
(8 poles, −0.18 %: the time step) and 0.002 (10 poles; its tail has a band of round-off depth,
margin ~ −1e-15, which the passivity test counts as no violation).
With --cases (``cases_rows``): one row per case of the fit's bounds (tol 0.01, default options):
the built-in scenes' gap tables (reactor: causal, 241 nodes, 101 frequencies; disk-halfspace:
elastic, 317 nodes, 51 frequencies) and a small raft (R = 10 m, 37 nodes, 21 frequencies to 25 Hz)
on a half-space vs 500 m/s undamped, hysteretic ξ = 3 % and causal ξ = 3 %; "re-check" is the
stepper's exact test of the returned model (``check_passive``, on the model's own scaling). Measured
on 2 cores (one BLAS thread), before -> after the enforcement with deficit cutting planes (one plane
per sample for the whole subspace below the margin, besides one per eigenvector), sparing the
rigid-raft impedance, with a grid pre-screen before each exact test (one run each, ±20 % noise):
    reactor          7-9 s both; 8 poles, rel error 9.1e-5, rigid 0.31 %, passive (the same model bit
                     for bit: passive as fitted, no enforcement iteration)
    disk-halfspace   208 s, 4 poles, rigid 7.7 %, tol missed (the 7-pole enforcement stalled, 5-10 s
                     per exact test) -> 12.3 s, 7 poles, 0.11 %, rigid 0.195 %, passive, tol met (one
                     enforcement iteration, then the exact test: 5 s of the 12)
    small undamped   2.3 s, 8 poles, 0.26 %, rigid 0.84 % -> 0.7 s, 8 poles, 0.26 %, rigid 0.21 %
    small hysteretic 13.7 s -> 8.3 s, the same model: 4 poles, 4.6 %, rigid 7.4 % (tol below the
                     hysteretic floor ≈ 3.3 %: flagged, with the message; 16, 8 and 14 poles not
                     passive within 20 iterations each)
    small causal     0.1 s both; 6 poles, 0.11 %, rigid 0.83 %, passive (the same model)
Run: OPENBLAS_NUM_THREADS=1 python benchmarks/soil_fit.py [cache_dir] [--linear] [--causal] [--cases]
"""
import sys
import time
from importlib import resources

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

import numpy as np

from orchestrator.impedance import scene_impedance
from orchestrator.scene import load_scene, scene_from_dict
from soil_impedance.fit import Problem, fit_order, fit_table
from soil_impedance.passivity import check_passive


def main(cache_dir=".cache"):
    t0 = time.perf_counter()
    table = scene_impedance(load_scene("reactor"), ("gap",), cache_dir=cache_dir)["gap"]
    print(f"table: {table!r} ({time.perf_counter() - t0:.1f} s)")
    prob = Problem(table, "relative", "auto")
    print(f"active DOFs {prob.idx.size}, independent entries {prob.X.shape[1]}, f_causal {prob.f_c} Hz, "
          f"compressed columns {prob.Y.shape[1]}")
    print(f"{'poles':>6} {'max rel err (f>=f_c)':>21} {'low-f err':>10} {'fit s':>7} {'passive':>8} "
          f"{'margin':>10} {'check s':>8}")
    rows = []
    for n_pairs in (1, 2, 4, 8, 12, 15):
        t1 = time.perf_counter()
        poles, C, err = fit_order(prob, n_pairs, 12)
        t_fit = time.perf_counter() - t1
        model = prob.model(poles, C, {"f_max_hz": float(table.frequencies_hz[-1])})
        t2 = time.perf_counter()
        rep = check_passive(model)                     # sweep method (pencil too large)
        t_chk = time.perf_counter() - t2
        res = np.linalg.norm(np.asarray(prob.X - (__import__("soil_impedance.vectfit", fromlist=["x"])
                                                 .real_basis(prob.s, poles) @ C)), axis=1)
        e = res / np.linalg.norm(prob.X, axis=1)
        low = e[~prob.band].max() if (~prob.band).any() else 0.0
        rows.append((poles.size, err, low, t_fit, rep.passive, rep.margin, t_chk))
        print(f"{poles.size:6d} {err:21.3e} {low:10.3e} {t_fit:7.2f} {rep.passive!s:>8} {rep.margin:10.2e} "
              f"{t_chk:8.2f}")
    # tol 0.01 is below the causality floor of this ξ = 3 % table (3–4 %, fit.py docstring): the fit
    # stops on the floor and returns the best passive model within its work bounds, with the reason
    t4 = time.perf_counter()
    low = fit_table(table, tol=0.01, enforce=True)
    r = low.report
    print(f"\nfit_table(tol=0.01): {time.perf_counter() - t4:.1f} s wall; {r.summary()}; tol reached {r.tol_reached}, "
          f"floor estimate {r.error_floor:.3g}")
    print(f"  order search: {r.stop_reason}; enforcement attempts (poles, passive, err, s) {r.enforcement_attempts}")
    print(f"  {r.message}")
    t3 = time.perf_counter()
    result = fit_table(table, tol=0.04, enforce=True)
    wall = time.perf_counter() - t3
    r = result.report
    print(f"\nfit_table(tol=0.04, enforce=True): {wall:.1f} s wall (target < 30 s); {r.summary()}")
    print(f"  order history {[tuple(round(x, 4) for x in h) for h in r.order_history]}")
    print(f"  before enforcement {r.max_rel_error_fit:.3e}, after {r.max_rel_error:.3e}, "
          f"unscaled {r.max_rel_error_unscaled:.3e}, low-frequency (f < {r.f_causal_hz} Hz) {r.low_freq_error:.3e}")
    print(f"  blocks {r.block_errors}")
    print(f"  passivity {r.passivity}")
    result.plot(table, "soil_fit.png")
    print("wrote soil_fit.png")


def reactor_scene(damping_model="hysteretic"):
    """The built-in reactor scene with ``[soil] damping_model`` set."""
    data = tomllib.loads((resources.files("orchestrator.scenes") / "reactor.toml").read_text())
    data["soil"]["damping_model"] = damping_model
    return scene_from_dict(data, name=f"reactor-{damping_model}")


def rigid_table(scene, cache_dir):
    """Frequencies and rigid-raft impedance P^T K_gap P (F, 6, 6) of a scene's gap table."""
    from soil_impedance.fit import rigid_projection
    table = scene_impedance(scene, ("gap",), cache_dir=cache_dir)["gap"]
    P = rigid_projection(table)
    return table.frequencies_hz, np.einsum("ia,fij,jb->fab", P, table.matrices, P)


def compare_tables(cache_dir=".cache", freqs=(0.0, 1.0, 4.0, 10.0)):
    """Rigid-raft impedances of the reactor, causal vs hysteretic damping, at a few frequencies."""
    f, Kh = rigid_table(reactor_scene("hysteretic"), cache_dir)
    _, Kc = rigid_table(reactor_scene("causal"), cache_dir)
    print("\nreactor rigid-raft impedance, causal vs hysteretic table (Re in N/m or N m/rad, "
          "Im/Re, causal/hysteretic - 1 in %)")
    print(f"{'dof':12s} {'f Hz':>5} {'Re hyst':>11} {'Re causal':>11} {'dRe %':>7} {'Im/Re hyst':>11} "
          f"{'Im/Re causal':>12} {'dIm %':>7}")
    for i, lab in ((0, "ux sliding"), (2, "uz vertical"), (4, "ry rocking")):
        for fk in freqs:
            k = int(np.argmin(np.abs(f - fk)))
            h, c = Kh[k, i, i], Kc[k, i, i]
            dim = f"{100 * (c.imag / h.imag - 1):+7.2f}" if h.imag != 0 else f"{'-':>7}"
            print(f"{lab:12s} {f[k]:5.2f} {h.real:11.4e} {c.real:11.4e} {100 * (c.real / h.real - 1):+7.2f} "
                  f"{h.imag / h.real:11.4f} {c.imag / c.real:12.4f} {dim}")


def linear_row(cache_dir=".cache", scene=None, fit_tol=None):
    """Rigid-raft impedance errors over 2-8 Hz and the linear FD vs bonded TD peak raft rotation
    (scene: default the reactor; fit_tol: default the scene's)."""
    from dataclasses import replace

    from orchestrator.motion import make_motion
    from orchestrator.routes.linear import run_linear
    from orchestrator.timefreq import linear_fd
    from soil_impedance.convolution import RecursiveConvolutionSoil
    from soil_impedance.fit import rigid_projection
    from soil_impedance.table import ImpedanceTable
    from structure import simulate

    scene = load_scene("reactor") if scene is None else scene
    table = scene_impedance(scene, ("gap",), cache_dir=cache_dir)["gap"]
    fit_tol = scene.analysis.fit_tol if fit_tol is None else fit_tol
    model, motion = scene.model(), make_motion(scene.motion, 0.005)
    contact = scene.contact
    nodes = scene.output.nodes
    t0 = time.perf_counter()
    fit = fit_table(table, tol=fit_tol, cache_dir=cache_dir)
    t_fit = time.perf_counter() - t0
    rm, f = fit.model, table.frequencies_hz
    P = rigid_projection(table)
    band = (f >= 2.0) & (f <= 8.0)
    Kt = np.einsum("ia,fij,jb->fab", P, table.matrices[band], P)
    Km = np.einsum("ia,fij,jb->fab", P, rm(2j * np.pi * f[band]), P)
    rep = fit.report
    print(f"\n{scene.name}, fit_tol {fit_tol}: {rm.order} poles, max rel error "
          f"{rep.max_rel_error:.4f}, passive {rep.passive}, fit {t_fit:.1f} s "
          f"({'cache' if rep.cached else 'computed'}; {rep.wall_s:.1f} s), "
          f"f_causal {rep.f_causal_hz:g} Hz, low-frequency error {rep.low_freq_error:.4f}")
    print(f"order search (poles, max rel error[, rigid-raft Re/Im error]): "
          f"{[tuple(round(x, 4) for x in h) for h in rep.order_history]}; tol reached {rep.tol_reached}")
    print("rigid-raft impedance, fit vs table, max over f >= f_causal (report.rigid_errors, Re/Im %): "
          + ", ".join(f"{d} {100 * e['re']:.2f}/{100 * e['im']:.2f}" for d, e in rep.rigid_errors.items()))
    print("rigid-raft impedance P^T K P, fit vs table, max over 2-8 Hz (%):")
    for i, lab in ((0, "ux sliding"), (2, "uz vertical"), (4, "ry rocking")):
        t, m = Kt[:, i, i], Km[:, i, i]
        print(f"  {lab:12s} Re {100 * np.abs(m.real / t.real - 1).max():5.2f}  Im {100 * np.abs(m.imag / t.imag - 1).max():5.2f}"
              f"  |dK|/|K| {100 * np.abs(m / t - 1).max():5.2f}")

    def peak(r):
        return float(np.hypot(r.raft[:, 3], r.raft[:, 4]).max())

    fit_as_table = ImpedanceTable(f, rm(2j * np.pi * f), table.dofs, dict(table.provenance, fitted=True))
    t1 = time.perf_counter()
    runs = {"linear FD, table": run_linear(motion, model, table, contact=contact, output_nodes=nodes),
            "linear FD, fit as table": run_linear(motion, model, fit_as_table, contact=contact, output_nodes=nodes),
            "linear FD, fitted model": linear_fd(model, rm, motion.acc, motion.dt, contact=contact,
                                                 output_nodes=nodes)}
    bonded = replace(contact, enabled=False)
    runs["bonded TD (Newmark)"] = simulate(model, RecursiveConvolutionSoil(rm, motion.dt), motion.acc,
                                           motion.dt, contact=bonded, output_nodes=nodes)
    ref = peak(runs["linear FD, table"])
    print(f"peak raft rotation, bonded, {motion.acc.shape[0] * motion.dt:g} s at dt {motion.dt:g} s "
          f"({time.perf_counter() - t1:.1f} s):")
    for k, r in runs.items():
        print(f"  {k:26s} {peak(r):.5e} rad  {100 * (peak(r) / ref - 1):+.3f} % vs the table")
    print(f"  fit error (fit as table vs table) {100 * (peak(runs['linear FD, fit as table']) / ref - 1):+.3f} %, "
          f"time step (Newmark vs fitted model) "
          f"{100 * (peak(runs['bonded TD (Newmark)']) / peak(runs['linear FD, fitted model']) - 1):+.3f} %")


def small_raft_table(damping, damping_model, cache_dir=".cache"):
    """Gap table and node coordinates of a rigid raft R = 10 m (37 nodes) on a half-space
    vs = 500 m/s, ν = 1/3, 21 frequencies over 0..25 Hz."""
    from soil_impedance import Material, SoilProfile, circle_mesh, impedance_sweep
    prof = SoilProfile((), Material(vs=500.0, rho=2000.0, nu=1 / 3, damping=damping, damping_model=damping_model))
    mesh = circle_mesh(10, 2.8)
    return impedance_sweep(prof, mesh, np.linspace(0, 25, 21), outputs=("gap",), cache_dir=cache_dir)["gap"], mesh.xy


def cases_rows(cache_dir=".cache", tol=0.01):
    """Wall time, order, errors and passivity of fit_table (default options) per case."""
    import warnings

    from soil_impedance.rational import FitError
    cases = {"reactor": None, "disk-halfspace": None, "small undamped": (0.0, "hysteretic"),
             "small hysteretic": (0.03, "hysteretic"), "small causal": (0.03, "causal")}
    print(f"\n{'case':18s} {'n':>4} {'F':>4} {'wall s':>7} {'poles':>5} {'rel err':>9} {'rigid':>9} {'passive':>7} "
          f"{'re-check':>8} {'tol met':>7}  stop; enforced (poles, passive, iterations)")
    for name, soil in cases.items():
        if soil is None:
            scene = load_scene(name)
            table, xy = scene_impedance(scene, ("gap",), cache_dir=cache_dir)["gap"], scene.mesh.xy
        else:
            table, xy = small_raft_table(*soil, cache_dir=cache_dir)
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                fit = fit_table(table, tol=tol, node_xy=xy)
            r = fit.report
        except FitError as exc:
            print(f"{name:18s} {table.n_dof:4d} {table.frequencies_hz.size:4d} {time.perf_counter() - t0:7.1f} "
                  f"FitError: {str(exc)[:120]}")
            continue
        wall = time.perf_counter() - t0
        rig = max((max(e["re"], e["im"]) for e in r.rigid_errors.values()), default=0.0)
        again = check_passive(fit.model).passive          # the stepper's re-check, on the model's own scaling
        print(f"{name:18s} {table.n_dof:4d} {table.frequencies_hz.size:4d} {wall:7.1f} "
              f"{r.order:5d} {r.max_rel_error:9.2e} {rig:9.2e} {r.passive!s:>7} {again!s:>8} {r.tol_reached!s:>7}  "
              f"{r.stop_reason}; {[(a[0], a[1], a[3]) for a in r.enforcement_attempts]}")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    if "--cases" in sys.argv:
        cases_rows(*args)
        sys.exit()
    if "--linear" not in sys.argv and "--causal" not in sys.argv:
        main(*args)
    if "--causal" not in sys.argv or "--linear" in sys.argv:
        linear_row(*args)
    if "--causal" in sys.argv:
        compare_tables(*args)
        causal = reactor_scene("causal")
        for tol in (0.04, None, 0.002):
            linear_row(*args, scene=causal, fit_tol=tol)
