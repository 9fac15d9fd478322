"""Linear frequency-domain route: full contact (no uplift), the soil's K(s) used directly.

The raft is bonded to the soil through the stepper's penalty springs (contact disabled:
P = P0 - kp d, the same linear model ``structure.simulate`` runs with ``enabled = False``), so
per frequency (S + kp) d = f (operator), solved by the Richardson iteration
d <- (f - S d) / kp (||S|| / kp ~ 1e-4 with the auto penalty: converges to round-off in a
few sweeps; a dense per-frequency solve is the fallback). The structure is condensed
exactly on the raft with all its fixed-base modes; the soil is the BEM table interpolated at
the FFT frequencies (spring-dashpot continuation above the table, see soil); FFTs through
pyfftw. Wrap-around: by default no exponential window (eta = 0) and the padding the physics
needs alone, max(1 s, ln(1/wrap_tol) tau_1) (grid): the window would amplify the acausal
part of a hysteretic table by up to 1/wrap_tol at the end of the record (on the reactor the
raft rotation drifted to 1.7e-5 rad, 11 % of its peak, in the last second). The bilinear grid
keeps the window (its s_d has a pole at z = -1, the Nyquist bin, on the unit circle).
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from structure.contact import ContactSettings
from structure.results import RouteResult

from orchestrator.timefreq.operator import WorkerPool
from orchestrator.timefreq.options import THREADS, GridOptions
from orchestrator.timefreq.problem import prepare, route_result


def solve_bonded(op, f_hat, kp, tol=1e-15, max_sweeps=60):
    """d (N, F) with (S + diag kp) d = f_hat (N, F). Returns (d, sweeps, method)."""
    kpc = kp[:, None]
    d = f_hat / kpc
    prev = np.inf
    for it in range(1, max_sweeps + 1):
        dn = (f_hat - op.apply_S(d)) / kpc
        ch = np.linalg.norm(dn - d) / max(np.linalg.norm(dn), 1e-300)
        d = dn
        if ch <= tol:
            return d, it, "richardson"
        if it > 3 and ch > 0.5 * prev:
            break
        prev = ch
    # fallback: dense solve per frequency
    N = kp.size
    idx = np.arange(N)
    out = np.empty_like(d)
    for c in range(0, f_hat.shape[1], 32):
        sl = slice(c, min(c + 32, f_hat.shape[1]))
        S = _S_chunk(op, idx, sl)
        S[:, idx, idx] += kp
        out[:, sl] = np.linalg.solve(S, f_hat[:, sl].T[:, :, None])[:, :, 0].T
    return out, it, "dense"


def _S_chunk(op, idx, sl):
    """S[idx, idx] (F_chunk, m, m) at the frequencies sl."""
    F = op.s.size
    full = op.S_sub(idx, idx) if F <= 64 else None
    if full is not None:
        return full[sl]
    sub = np.empty((sl.stop - sl.start, idx.size, idx.size), complex)
    for band in op.soil.bands:
        sel = (band.idx >= sl.start) & (band.idx < sl.stop)
        if sel.any():
            sub[band.idx[sel] - sl.start] = band.sub_ww(idx, idx, op.s[band.idx], sel)
    sub -= op.Vr[sl] @ (op.Zinv[sl] @ op.Vl[sl])
    return sub


def linear_fd(model, soil, ag, dt, *, contact=None, damping=None, output_nodes=None,
              grid: GridOptions | None = None, threads: int = THREADS, route: str = "linear") -> RouteResult:
    """Linear (bonded) frequency-domain response to ground acceleration ag (nt, 3) m/s^2 at
    step dt (s).

    soil : ImpedanceTable ("gap", 6+N), WinklerSoil, RationalModel or RecursiveConvolutionSoil
    contact : ContactSettings (its penalty; contact is disabled here); damping : structural
    damping (structure.damping_matrix); output_nodes : node names (None: every named node)
    grid : GridOptions (default GridOptions(); None fields: the continuous grid, the window on the bilinear grid only;
    see the module notes); threads : worker threads of the operator (WorkerPool)
    Returns a RouteResult (gap zero, contact_force P0 - kp d, may be negative = tension).
    """
    t0 = time.perf_counter()
    contact = replace(contact or ContactSettings(), enabled=False)
    with WorkerPool(threads) as pool:
        prob = prepare(model, soil, ag, dt, grid=(grid or GridOptions()).resolved(bilinear=False), contact=contact,
                       damping=damping, pool=pool)
        g = prob.grid
        f_hat = g.to_freq(prob.f)
        d_hat, sweeps, how = solve_bonded(prob.op, f_hat, prob.kp)
    d = g.to_time(d_hat)
    P = prob.P0[:, None] - prob.kp[:, None] * d
    return route_result(prob, route, d, P, np.zeros_like(d), output_nodes=output_nodes, started=t0,
                        info=dict(method="linear-fd", bonded_solver=how, sweeps=sweeps))
