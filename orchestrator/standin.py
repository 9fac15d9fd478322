"""The time-frequency route's causal stand-in, marched by the native stepper.

The route (orchestrator/timefreq, ``march.defect_correction``) solves the whole-range contact
equation of the BEM table by marches, each solving a causal problem with the last residual
fed back as a source. Its default march steps the table's own kernel on the grid (~0.75 s
per sweep on the reactor, four sweeps). The stand-in: the table's fit constrained to the
route's continuation above the table (``soil_impedance.fit.continuation_fit``: the scene fit's
poles, D = A and E = B of the route's springs and dashpots, the residues refit; tested for
passivity), run by the recursive convolution inside the Newmark stepper of the native runtime
(fmus/native: ``up_sim_steps_src``, the source W added to each step's contact equations), at a
monolithic step's cost. The residual stays the table's, so the fixed point does: the stand-in
changes the sweeps, not the answer. On the trapezoidal grid the Newmark average-acceleration
stepper solves the same discrete equations as the route's march on a rational soil, so the
stand-in's linear rate is rho(S_x^-1 (S_table - S_x)) (< 0.46 at every frequency on the
reactor; benchmarks/timefreq.py --stand-in). The marches run in correction form (``SINGLE``:
each takes the last march's recorded soil history plus the history of the change from it in
single precision, soil.c's ``up_soil_corr_mode``): 0.40 -> 0.30 s CPU a march on the reactor, the
same sweeps and answer.

``stand_in_factory(table, fit_model, ...)`` returns what ``orchestrator.timefreq.solve(...,
stand_in=)`` takes: a callable prob -> (NativeStandIn or None, reason).
"""
from __future__ import annotations

import ctypes
import time
import weakref

import numpy as np

from fmus.native_build import NativeBuildError
from fmus.native_stepper import CHUNK, cache_folder, encode_run, library, library_note
from fmus.schema import row_slices, row_width
from orchestrator.timefreq.march import DIVERGED_M, MarchDiverged
from soil_impedance.convolution import RecursiveConvolutionSoil
from soil_impedance.fit.continuation import continuation_fit
from structure.newmark import NewmarkStepper

#: the stand-in's marches in correction form (``up_sim_correction``, soil.c): the history as the
#: last march's plus the change's in single precision; its rounding is relative to the change, and
#: the fixed point stays the residual's (on the reactor a march 0.42 -> 0.32 s CPU, the same
#: residuals to 4 digits, max uplift 9e-14 relative apart: docs/native.md)
SINGLE = True
#: the first march too (the change from rest: the whole history in single precision, ~1e-7 of it;
#: that error is the same in every later march's recorded history, a fixed offset the source W
#: absorbs, so the sweeps and the fixed point are unchanged: reactor residuals the same to 4
#: digits, max uplift 1.7e-13 relative apart); False: the first march in float64
SINGLE_FIRST = True


class NativeStandIn:
    """A marcher of ``defect_correction``: the contact problem ``prob``'s structure, static state
    and penalty on the rational soil ``model`` (passive), stepped by the native runtime with a
    source. ``march(lam, W, deadline)`` -> (d (N, nt) m the dynamic relative displacement, info).

    One native run serves every march: opened by the first, rewound to rest by the next
    (``up_sim_rewind``: the stepper's systems, Newton bases and capacitance matrices kept, whose
    numbers depend on the step size and the active set only, so a march is the same bits as on a
    new run; on the reactor the records' parse and the bases cost ~25 ms of a march's ~0.4 s CPU),
    closed with the marcher (``close``, or when it is collected).

    single : the marches in correction form (``SINGLE``, ``SINGLE_FIRST``; simulate.c's
    ``up_sim_correction``): each march's soil history is the last whole march's (recorded) plus the
    history of the change from it in single precision; info["correction"] says when it was."""

    def __init__(self, prob, model, lib, damping=None, single: bool = False):
        dt = prob.grid.dt
        st = NewmarkStepper(prob.model, RecursiveConvolutionSoil(model, dt, checked=True), dt,
                            contact=prob.contact, damping=damping, static=prob.static)
        st.kp = np.array(prob.kp, float)           # the table's penalty (the stand-in's K(0) differs)
        self.blob = encode_run(st, [])
        self.lib, self.N, self.Bq3, self.dt = lib, st.N, np.array(st.Bq3), dt
        self.ag = np.ascontiguousarray(prob.ag, float)
        self.at = row_slices(st.N, 0)
        self.width = row_width(st.N, 0)
        self.n_factor = self.n_factor_total = 0
        self._handle, self._close, self._rows = None, None, None
        self.single = bool(single)

    def _run(self, ag0):
        """The native run at rest under ag0 (3): opened on the first call, rewound after."""
        if self._handle is not None:
            self.lib.up_sim_rewind(self._handle, ag0.ctypes.data)
            return self._handle
        err = ctypes.create_string_buffer(1024)
        h = self.lib.up_sim_open(self.blob, len(self.blob), ag0.ctypes.data, err)
        if not h:
            raise NativeBuildError(f"the native stepper refused the stand-in: {err.value.decode(errors='replace')}")
        self._handle, self._close = h, weakref.finalize(self, self.lib.up_sim_close, h)
        return h

    def close(self):
        """Free the native run (the next march opens a new one)."""
        if self._close is not None:
            self._close()
        self._handle, self._close = None, None

    def march(self, lam, source, deadline=None):
        """One march: the stand-in's contact equations under lam x the motion with the source
        ``source`` (N, nt) N added, P - P0 + W the dynamic interface force. The run starts at
        rest one step before the first sample (the grid's causal histories are zero before it):
        sample n of the march is the native run's sample n + 1, so that sample 0 is a step with
        its own contact equations and source, as in the grid's march (a run whose sample 0 is
        the state at rest cannot follow a source there: the residual stalled at 9e-5 on the small
        reactor at 0.9 g). Returns (d (N, nt), info: newton, factors, steps, wall_s, correction (the
        change from the last march), single (the history in single precision: that, or the change
        from rest), halved (steps halved)); steps < nt
        when ``deadline`` (perf_counter) passed between two chunks."""
        t0 = time.perf_counter()
        lib, N = self.lib, self.N
        nt = self.ag.shape[0] + 1
        ag = np.zeros((nt, 3))
        ag[1:] = lam * self.ag
        src = np.zeros((nt, N))
        src[1:] = np.asarray(source, float).T
        if self._rows is None or self._rows.shape[0] != nt:     # the rows' buffer of every march
            self._rows = np.empty((nt, self.width))
        rows = self._rows
        iters = np.empty(nt, np.int64)
        stats = np.zeros(3, np.int64)
        err = ctypes.create_string_buffer(1024)
        h = self._run(ag[0])
        mode, last = 0, False
        if self.single:     # 2: the change from the last whole march; without one (-1), the change from
            mode = lib.up_sim_correction(h, nt, 2)          # rest (3, set as 2) or a float64 march (1)
            last = mode == 2
            if not last:
                mode = max(0, lib.up_sim_correction(h, nt, 3 if SINGLE_FIRST else 1))
        else:
            lib.up_sim_correction(h, nt, 0)
        k, factors0 = 0, self.n_factor_total
        while k < nt:
            k1 = min(k + CHUNK, nt)
            rc = lib.up_sim_steps_src(h, ag.ctypes.data, src.ctypes.data, k, k1, rows[k:].ctypes.data,
                                      iters[k:].ctypes.data, stats.ctypes.data, err)
            if rc != 0:                          # a step's Newton failed: this stand-in cannot go on
                raise MarchDiverged((int(stats[0]) - 1) * self.dt, N)
            k = k1
            if deadline is not None and time.perf_counter() > deadline and k < nt:
                break
        q, w = rows[1:k, self.at["raft"]], rows[1:k, self.at["soil_w"]]
        d = np.zeros((N, nt - 1))
        d[:, :k - 1] = (q[:, 2:5] @ self.Bq3.T - w).T
        if k > 1 and not np.abs(d[:, k - 2]).max() < DIVERGED_M:
            raise MarchDiverged((k - 2) * self.dt, N)
        self.n_factor_total = int(stats[1])            # the run's, since it was opened
        self.n_factor = self.n_factor_total - factors0
        return d, dict(newton=int(iters[:k].sum()), factors=self.n_factor, steps=int(k - 1),
                       wall_s=time.perf_counter() - t0, correction=last, single=mode == 2,
                       halved=int(stats[2]))


def constrained_fit(table, fit_model, *, cache_dir=None):
    """The stand-in's fit: ``table`` constrained to the route's continuation on ``fit_model``'s
    poles (``continuation_fit``, cached in ``cache_dir``)."""
    return continuation_fit(table, fit_model.poles, cache_dir=cache_dir)


def stand_in_factory(table, fit_model, *, cache_dir=None, damping=None, constrained=None):
    """callable(prob) -> (NativeStandIn or None, reason): the constrained fit of ``table`` on
    ``fit_model``'s poles (``constrained`` when made already, else ``constrained_fit``, cached in
    ``cache_dir``), marched natively, or None and why not (the fit not passive, no native library
    here)."""
    def make(prob):
        fit = constrained if constrained is not None else constrained_fit(table, fit_model, cache_dir=cache_dir)
        if not fit.passive:
            return None, (f"the fit constrained to the route's continuation ({fit_model.order} poles) is not "
                          f"passive (margin {fit.margin:.2e})")
        lib = library(cache_folder(cache_dir))
        if lib is None:
            return None, library_note(cache_folder(cache_dir))
        return NativeStandIn(prob, fit.model, lib, damping, single=SINGLE), (f"stand-in: the fit constrained to the route's continuation ({fit_model.order} poles, "
                         f"{fit.max_rel_error:.1e} on the table), native march")
    return make
