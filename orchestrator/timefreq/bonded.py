"""Linear frequency-domain route: full contact (no uplift), the soil's K(s) used directly.

The raft is bonded to the soil through the stepper's penalty springs (contact disabled:
P = P0 - kp d, the same linear model ``structure.simulate`` runs with ``enabled = False``), so
per frequency (S + kp) d = f (operator), solved by the Richardson iteration
d <- (f - S d) / kp (||S|| / kp ~ 1e-4 with the auto penalty: converges to round-off in a
few sweeps; a dense per-frequency solve is the fallback), a group of frequencies at a time:
a table's band is formed for one group, used for its sweeps and dropped (the whole band is
never held: 260 MB of fresh memory on the reactor). The structure is condensed
exactly on the raft with all its fixed-base modes; the soil is the BEM table interpolated at
the FFT frequencies (spring-dashpot continuation above the table, see soil); FFTs through
pyfftw. Wrap-around (a rigid raft): by default no exponential window (eta = 0) and the padding the physics
needs alone, max(1 s, ln(1/wrap_tol) tau_1) (grid): the window would amplify the acausal
part of a hysteretic table by up to 1/wrap_tol at the end of the record (on the reactor the
raft rotation drifted to 1.7e-5 rad, 11 % of its peak, in the last second). The bilinear grid
keeps the window (its s_d has a pole at z = -1, the Nyquist bin, on the unit circle), and so
does a plate raft (orchestrator/timefreq/flexible.py: its bending modes on the soil are lightly
damped and ring past the sticks' padding).
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from structure.contact import ContactSettings
from structure.results import RouteResult

from orchestrator.timefreq.operator import WorkerPool
from orchestrator.timefreq.solver_options import THREADS, GridOptions
from orchestrator.timefreq.flexible import is_plate
from orchestrator.timefreq.problem import prepare, route_result


#: frequencies per group of the bonded solve (a table's band formed a group at a time: a
#: group of 32 reactor matrices is 31 MB; fewer make the table's product slower)
GROUP = 32
#: frequencies per dense solve of the fallback (an (m, N, N) system each)
DENSE_CHUNK = 32


def solve_bonded(op, f_hat, kp, tol=1e-15, max_sweeps=60, group=GROUP):
    """d (N, F) with (S + diag kp) d = f_hat (N, F). Returns (d, sweeps, method).

    A group of frequencies at a time (op.pieces: a table's band is never formed whole), each
    by the Richardson iteration d <- (f - S d) / kp to a relative change <= tol, or, when it
    stalls, by a dense solve per frequency. The groups are fixed (not the threads'), each
    frequency's answer depends on its group alone. sweeps: the most any group took; method:
    "richardson", "dense" or "richardson, dense in k of G groups"."""
    ft = np.ascontiguousarray(f_hat.T)[:, :, None]                      # (F, N, 1)
    d = np.empty_like(ft)
    kpc = kp[:, None]
    groups = op.groups(group)
    parts = min(op.pool.threads, len(groups))
    shares = [groups[k::parts] for k in range(parts)]                 # dealt round-robin
    stats = []

    def solve(share):
        for i, apply, matrix in op.pieces(share):
            d[i], it, dense = _solve_piece(apply, matrix, ft[i], kpc, tol, max_sweeps)
            stats.append((it, dense))
    op.pool.run([lambda share=share: solve(share) for share in shares])
    sweeps = max(it for it, _ in stats)
    k = sum(dense for _, dense in stats)
    how = "richardson" if k == 0 else "dense" if k == len(stats) else \
        f"richardson, dense in {k} of {len(stats)} groups"
    return d[:, :, 0].T, sweeps, how


def _solve_piece(apply, matrix, f, kpc, tol, max_sweeps):
    """(d (m, N, 1), sweeps, dense?) on one group's frequencies, f (m, N, 1)."""
    d = f / kpc
    prev = np.inf
    for it in range(1, max_sweeps + 1):
        dn = (f - apply(d)) / kpc
        ch = np.linalg.norm(dn - d) / max(np.linalg.norm(dn), 1e-300)
        d = dn
        if ch <= tol:
            return d, it, False
        if it > 3 and ch > 0.5 * prev:
            break
        prev = ch
    out = np.empty_like(d)                               # the fallback: dense, per frequency
    idx = np.arange(kpc.size)
    for c in range(0, f.shape[0], DENSE_CHUNK):
        j = slice(c, min(c + DENSE_CHUNK, f.shape[0]))
        S = matrix(j)
        S[:, idx, idx] += kpc[:, 0]
        out[j] = np.linalg.solve(S, f[j])
    return out, it, True


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
        # a plate: the window by default (its bending modes on the soil ring long: without it the
        # padding left the 49-node test plate's peak rotation 17 % off bonded Newmark, with it +0.03 %)
        window = True if is_plate(model) else None
        prob = prepare(model, soil, ag, dt, grid=(grid or GridOptions()).resolved(bilinear=False, window=window),
                       contact=contact,
                       damping=damping, pool=pool)
        g = prob.grid
        f_hat = g.to_freq(prob.f)
        d_hat, sweeps, how = solve_bonded(prob.op, f_hat, prob.kp)
    d = g.to_time(d_hat)
    P = prob.P0[:, None] - prob.kp[:, None] * d
    return route_result(prob, route, d, P, np.zeros_like(d), output_nodes=output_nodes, started=t0,
                        info=dict(method="linear-fd", bonded_solver=how, sweeps=sweeps))
