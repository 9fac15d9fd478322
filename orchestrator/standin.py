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

The stand-in keeps the fewest of the fit's poles whose constrained fit is passive and whose
linear rate, predicted per frequency for a design motion, meets ``RATE_BOUND`` and
``WORST_BOUND`` (``choose_poles``, ``Probe``: on the reactor 4 of 8 poles, 4 sweeps instead of 6);
all of them when none does (the fallback, said in the route's info). The choice is the scene's
(the table, the fit's poles, the structure and the step: no record), made once and cached
(``pole_choice``), and an ensemble's set-up makes it for every cell (``scene_stand_in``).

``stand_in_factory(table, fit_model, ...)`` returns what ``orchestrator.timefreq.solve(...,
stand_in=)`` takes: a callable prob -> (NativeStandIn or None, reason).
"""
from __future__ import annotations

import ctypes
import dataclasses
import time
import weakref
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lu_factor, lu_solve

from fmus.native_build import NativeBuildError
from fmus.native_stepper import CHUNK, cache_folder, encode_run, library, library_note
from fmus.schema import row_slices, row_width
from orchestrator.timefreq.flexible import structure_of
from orchestrator.timefreq.march import DIVERGED_M, MarchDiverged
from orchestrator.timefreq.operator import InterfaceOperator
from orchestrator.timefreq.setup_cache import entry_path, read_arrays, setup_key, write_arrays
from orchestrator.timefreq.soil import soil_bands
from soil_impedance.convolution import RecursiveConvolutionSoil, bilinear_coefficients
from soil_impedance.fit.continuation import ContinuationBasis, continuation_fit
from soil_impedance.vectfit import real_basis
from structure.newmark import NewmarkStepper
from uplift_common.code import code_digest

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
#: the marches lean (simulate.c's ``up_sim_lean``): the native run fills only the rows' raft and soil
#: parts a march reads, sums no works nor energies, and takes the soil force's K0C x of each committed
#: state from the Newton iteration's S0 x (one packed product less a step; the iterations' round-off
#: carried from step to step, not a change of the fixed point, which is the residual's)
LEAN = True


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
    history of the change from it in single precision; info["correction"] says when it was.
    lean : the run lean (``LEAN``, simulate.c's ``up_sim_lean``): the rows' raft and soil parts
    only, no works, K0C x from the Newton iteration."""

    def __init__(self, prob, model, lib, damping=None, single: bool = False, lean: bool = False):
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
        self.single, self.lean = bool(single), bool(lean)
        self.info = {}              # what the route's info records of this stand-in (its poles: stand_in_factory)

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
        self.lib.up_sim_lean(h, int(self.lean))
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


# ---- which of the fit's poles the stand-in keeps ------------------------------------------------
#: the bounds a subset of the fit's poles must meet to stand in (``choose_poles``): the predicted
#: rate per sweep of the error where a design motion puts it (``RATE_BOUND``) and the worst
#: predicted rate over the frequencies sampled (``WORST_BOUND``). On the reactor the subsets meeting
#: both took 4-5 sweeps, those above RATE_BOUND 6-9, those above WORST_BOUND (all 8 poles among
#: them: 0.37 above the table) 6 (docs/native.md, round five)
RATE_BOUND = 0.08
WORST_BOUND = 0.3
#: the probe's frequencies: N_FREQ discrete-time frequencies log-spaced from F_LOW_HZ to TOP x the
#: Nyquist frequency, at the window's rate ETA (1/s: z = e^((i w + ETA) dt)). A grid's own rate
#: falls as its record lengthens (ln(1 / wrap_tol) over the record and its padding: the reactor's
#: 10 s, 0.82 1/s; 30 s, 0.3); the probe takes one rate for every record, so that the choice is the
#: scene's (the reactor's poles the same at 0.3 and 0.82; at 0, the unit circle, others: docs/native.md)
N_FREQ = 24
F_LOW_HZ = 0.1
TOP = 0.98
ETA = 0.8
#: power steps per frequency; at most this many subsets' constrained fits tested for passivity, of
#: each size at most PER_LEVEL (the best predicted)
N_POWER = 6
MAX_TESTS = 6
PER_LEVEL = 2
#: the design motion's weight on each direction of ground acceleration (x, y, z): the horizontals
#: and the vertical at the synthetic motions' default ratio (orchestrator.motion.VERTICAL_RATIO),
#: every direction whatever the record shakes, so that one choice serves every motion of a scene
DIRECTION_WEIGHTS = (1.0, 1.0, 2.0 / 3.0)


def design_psd(freq_hz):
    """The design motion's power spectral density (per Hz, relative: the rates are scale-free) at
    ``freq_hz``: a smooth spectrum of a motion compatible with the RG 1.60 design spectrum of the
    synthetic motions (orchestrator.motion), f^0.2 below its 2.5 Hz peak, then f^-1.8 to 9 Hz,
    f^-3 to 16 Hz and f^-8 above: the fall above the spectrum's corner is what matters here (a flat
    spectrum weighs the fit's error above the table 10^3-10^4 times more than the synthetic records
    put there, and picked other poles: docs/native.md, round five)."""
    f = np.asarray(freq_hz, float)
    return np.select([f < 2.5, f < 9.0, f < 16.0],
                     [(f / 2.5) ** 0.2, (2.5 / f) ** 1.8, (2.5 / 9.0) ** 1.8 * (9.0 / f) ** 3],
                     (2.5 / 9.0) ** 1.8 * (9.0 / 16.0) ** 3 * (16.0 / f) ** 8)


@dataclass(frozen=True)
class PoleChoice:
    """``choose_poles``'s verdict. kept : the fit's pole units kept (indices of
    ``ContinuationBasis.units``: a real pole or a complex pair; the fit's poles from the fastest);
    units : their count in the fit; rate, worst : the kept subset's predicted rates (``Probe``);
    fallback : no subset met the bounds and was passive: all the poles (today's stand-in);
    evaluated, tested : subsets predicted, constrained fits tested for passivity; key : what it was
    chosen for (``choice_key``; "" when not keyed); fit : the kept subset's ContinuationFit when it
    is at hand (not compared, not cached; None: make or read it)."""
    kept: tuple
    units: int
    rate: float
    worst: float
    fallback: bool
    evaluated: int = 0
    tested: int = 0
    key: str = ""
    fit: object = field(default=None, compare=False, repr=False)

    def note(self) -> str:
        head = (f"all {self.units} poles (no subset of fewer met the bounds, rate <= {RATE_BOUND:g} and worst "
                f"<= {WORST_BOUND:g}, and was passive)" if self.fallback else
                f"{len(self.kept)} of {self.units} poles ({', '.join(map(str, self.kept))})")
        return f"{head}, predicted rate {self.rate:.2f} per sweep, worst {self.worst:.2f}"

    def info(self) -> dict:
        return dict(stand_in_poles=list(self.kept), stand_in_fallback=self.fallback,
                    stand_in_rate=self.rate, stand_in_worst=self.worst)


class ProbeGrid:
    """The probe's frequencies as the route's bands and operator read a grid (``soil_bands``,
    ``InterfaceOperator``): freq_hz (nf,) Hz, z = e^((i 2 pi f + eta) dt), s the trapezoidal s_d
    at z (1/s), warped_hz the real frequency each stands for (Grid.warped_hz)."""
    bilinear = True

    def __init__(self, dt: float, freq_hz, eta: float):
        self.dt = float(dt)
        self.freq_hz = np.asarray(freq_hz, float)
        self.z = np.exp((2j * np.pi * self.freq_hz + eta) * self.dt)
        self.s = 2.0 / self.dt * (self.z - 1.0) / (self.z + 1.0)
        self.warped_hz = np.tan(np.pi * self.freq_hz * self.dt) / (np.pi * self.dt)
        self.n_freq = self.freq_hz.size


def probe_grid(dt: float) -> ProbeGrid:
    """The probe's ``N_FREQ`` frequencies at the step ``dt`` (s) (module constants)."""
    return ProbeGrid(dt, np.geomspace(F_LOW_HZ, TOP * 0.5 / dt, N_FREQ), ETA)


def raft_trace(model, structure):
    """The raft coordinates' trace the route's operator uses: a rigid raft's Bq (N, 6), a plate's B."""
    return np.asarray(structure.trace if hasattr(structure, "trace") else model.raft.vertical_trace(), float)


class Probe:
    """The defect correction's linear rate on a stand-in, predicted on ``N_FREQ`` frequencies of the
    step ``dt`` (``probe_grid``): a function of the table, the structure and the step only (no
    record, no grid of one: the choice is the scene's). With the raft open, the source W's error
    after one sweep is T e, T = (S_x - S) S_x^-1 per frequency (S the table's interface stiffness,
    S_x the stand-in's, both condensed on the structure: a march solves S_x d = W - f, the residual
    adds S d - S_x d; docs/routes.md); the raft closed only shrinks it (S_x + K_c in place of S_x).
    ``predict(basis, kept)`` -> (rate, worst): rate, the error's decay per sweep where a design
    motion puts it, (|T^n f| / |f|)^(1/n) with |.|^2 summed over the frequencies (each sample's
    share of the band, ``design_psd``) and the three directions (``DIRECTION_WEIGHTS``), f the
    blocked force of a unit ground acceleration in each, n = N_POWER; worst, the largest rate of
    the last power step at one frequency, from those forces and from a fixed pseudo-random vector
    (an estimate of the spectral radius of T there: the rate of the error the contact's switching
    puts at any frequency).

    model : the structure model (rigid raft); table : the gap ImpedanceTable; structure : its
    condensation (``flexible.structure_of(model, damping)``: the route's; default the model's own
    damping, as a scene's run); grid : the frequencies (default ``probe_grid(dt)``; a ProbeGrid)."""

    def __init__(self, model, table, dt, structure=None, grid=None):
        self.grid = grid = grid if grid is not None else probe_grid(dt)
        f = grid.freq_hz
        mid = np.sqrt(f[1:] * f[:-1])
        edges = np.concatenate([[f[0] * f[0] / mid[0]], mid, [0.5 / grid.dt]])
        self.share = np.diff(edges)                   # Hz each sample stands for (log-spaced)
        st = structure if structure is not None else structure_of(model)
        self.op = op = InterfaceOperator(model, soil_bands(table, grid), grid, structure=st)
        allN = np.arange(op.N)
        self.S = op.S_sub(allN, allN)
        forces = op.Vr @ (op.Zinv @ op.b)             # (nf, N, 3): a unit ground acceleration's blocked force
        rng = np.random.default_rng(0)
        v = rng.standard_normal(forces.shape[:2]) + 1j * rng.standard_normal(forces.shape[:2])
        self.x0 = np.concatenate([forces, v[:, :, None]], axis=2)     # (nf, N, 4)
        self.weight = self.share[:, None] * design_psd(f)[:, None] * np.square(DIRECTION_WEIGHTS)[None, :]
        self.Aq = st.blocks(grid.s)[0]
        self._parts = None

    def stand_in(self, A, B, poles, residues):
        """S_x (nf, N, N) of the rational model (poles, residues, D = A, E = B) as the native
        stepper runs it (its recursion's z-transform at the probe's z), condensed as the table's."""
        op, grid = self.op, self.grid
        a, b = bilinear_coefficients(poles, grid.dt)
        g = b * (grid.z[:, None] + 1) / (grid.z[:, None] - a)
        K = A + grid.s[:, None, None] * B + np.einsum("fk,kij->fij", g, residues)
        Bq = op.Bq
        Vr = K[:, 6:, :6] + K[:, 6:, 6:] @ Bq
        Vl = K[:, :6, 6:] + Bq.T @ K[:, 6:, 6:]
        Z = self.Aq + K[:, :6, :6] + K[:, :6, 6:] @ Bq + Bq.T @ Vr
        return K[:, 6:, 6:] - Vr @ np.linalg.solve(Z, Vl)

    def _basis_parts(self, basis):
        """The condensation's parts of A, B and each column's coefficients of ``basis`` (all linear
        in them): the stand-in of a subset is a combination of these (``subset_stand_in``)."""
        if self._parts is not None and self._parts[0] is basis:
            return self._parts[1]
        n, Bq = basis.n, self.op.Bq
        C = basis.C.reshape(-1, n, n)
        M = np.concatenate([basis.A[None], basis.B[None], 0.5 * (C + np.swapaxes(C, 1, 2))])   # (m + 2, n, n)
        ww = np.ascontiguousarray(M[:, 6:, 6:]).reshape(M.shape[0], -1)
        wP = (M[:, 6:, :6] + M[:, 6:, 6:] @ Bq).reshape(M.shape[0], -1)
        Pw = (M[:, :6, 6:] + Bq.T @ M[:, 6:, 6:]).reshape(M.shape[0], -1)
        PP = (M[:, :6, :6] + M[:, :6, 6:] @ Bq + Bq.T @ M[:, 6:, :6] + Bq.T @ M[:, 6:, 6:] @ Bq).reshape(M.shape[0], -1)
        Phi = real_basis(self.grid.s, basis.poles, const=False, linear=False)
        parts = (ww, wP, Pw, PP, Phi)
        self._parts = (basis, parts)
        return parts

    def subset_stand_in(self, basis, kept):
        """``stand_in`` of the units ``kept`` of ``basis`` (``basis.residues(kept)``), from the
        parts of every column made once (``_basis_parts``: the residues are the projection's
        coefficients times a small matrix, and K is linear in them): per subset one product of
        (nf, m + 2) weights and no pass over the residues' n^2 entries per pole."""
        ww, wP, Pw, PP, Phi = self._basis_parts(basis)
        cols = basis.columns(kept)
        X = np.linalg.lstsq(basis.R[:, cols], np.eye(basis.R.shape[0]), rcond=None)[0]    # coefficients = X C
        s = self.grid.s
        w = np.concatenate([np.ones((s.size, 1)), s[:, None], Phi[:, cols] @ X], axis=1)   # (nf, m + 2)

        def combine(parts):
            return w.real @ parts + 1j * (w.imag @ parts)
        N = self.op.N
        Kww = combine(ww).reshape(-1, N, N)
        Vr = combine(wP).reshape(-1, N, 6)
        Vl = combine(Pw).reshape(-1, 6, N)
        Z = self.Aq + combine(PP).reshape(-1, 6, 6)
        return Kww - Vr @ np.linalg.solve(Z, Vl)

    def predict(self, basis, kept):
        """(rate, worst) of the stand-in on the units ``kept`` of ``basis`` (class notes)."""
        Sx = self.subset_stand_in(basis, kept)
        nf, ncol = self.x0.shape[0], self.x0.shape[2]
        e = np.empty((nf, N_POWER + 1, ncol))
        for i in range(nf):
            x = self.x0[i]
            e[i, 0] = np.linalg.norm(x, axis=0)
            lu = lu_factor(Sx[i], check_finite=False)
            dS = Sx[i] - self.S[i]
            for j in range(1, N_POWER + 1):
                x = dS @ lu_solve(lu, x, check_finite=False)
                e[i, j] = np.linalg.norm(x, axis=0)
        energy = np.sqrt(np.einsum("fd,fjd->j", self.weight, e[:, :, :3] ** 2))
        rate = float((energy[-1] / energy[0]) ** (1.0 / N_POWER))
        with np.errstate(invalid="ignore", divide="ignore"):
            step = e[:, -1] / e[:, -2]
        worst = float(np.nanmax(step)) if np.isfinite(step).any() else float("inf")
        return rate, worst


def choose_poles(probe, basis, table, *, cache_dir=None, key="") -> PoleChoice:
    """Which units of ``basis`` (the scene fit's poles) the stand-in keeps: the fewest whose
    constrained fit is passive and whose predicted rates (``probe``: a Probe) meet RATE_BOUND and
    WORST_BOUND; all of them (``fallback``) when no subset does. The search removes one unit (a
    real pole or a complex pair) at a time from all of them, each time the one whose removal leaves
    the lowest predicted rate among those meeting the bounds (ties: the lower units first), until
    no removal meets them; then the constrained fits (``continuation_fit``) are tested for
    passivity from the smallest subsets up, in each size the best predicted first, at most
    PER_LEVEL of a size and MAX_TESTS in all. Only the kept subset's fit is written to
    ``cache_dir`` (the one a later run reads; the rejected ones are not kept). A function of the
    table, the structure and the step only (no record, no timing): the same inputs give the same
    poles."""
    memo = {}

    def pred(kept):
        if kept not in memo:
            memo[kept] = probe.predict(basis, kept)
        return memo[kept]

    def meets(kept):
        rate, worst = pred(kept)
        return rate <= RATE_BOUND and worst <= WORST_BOUND
    everything = tuple(range(len(basis.units)))
    levels, current = [], everything
    while len(current) > 1:
        ok = sorted((pred(c)[0], c) for c in (tuple(u for u in current if u != r) for r in current) if meets(c))
        if not ok:
            break
        levels.append([c for _, c in ok])
        current = ok[0][1]
    tested = 0
    for level in reversed(levels):
        for kept in level[:PER_LEVEL]:
            if tested >= MAX_TESTS:
                break
            tested += 1
            fit = continuation_fit(table, basis.unit_poles(kept), cache_dir=cache_dir, keep="passive")
            if fit.passive:
                return PoleChoice(kept, len(everything), *pred(kept), False, len(memo), tested, key, fit)
    return PoleChoice(everything, len(everything), *pred(everything), True, len(memo), tested, key)


def choice_key(model, table, poles, dt, structure) -> str | None:
    """The key of ``pole_choice``'s entry: the table's data (setup_key), the poles, the probe's s
    (the step and the probe's constants), the structure's condensation there (its A_q and b
    blocks: the modes, the damping, the masses), the raft's trace, the rule's constants and code.
    No record and no grid: every motion of a scene at one step shares it."""
    grid = probe_grid(dt)
    Aq, b = structure.blocks(grid.s)
    return setup_key("poles", table, np.asarray(poles, complex), grid.s, Aq, b, raft_trace(model, structure),
                     (RATE_BOUND, WORST_BOUND, N_FREQ, F_LOW_HZ, TOP, ETA, N_POWER, MAX_TESTS, PER_LEVEL,
                      DIRECTION_WEIGHTS), code_digest("orchestrator.standin"))


def pole_choice(model, table, poles, dt, *, structure=None, cache_dir=None) -> PoleChoice:
    """``choose_poles`` for the structure ``model`` (its condensation ``structure``, default
    ``structure_of(model)``) on the gap table ``table`` with the scene fit's ``poles`` at the step
    ``dt`` (s), kept in ``cache_dir`` (``tf-poles-<key>.h5``, ``choice_key``: once per scene, for
    every record): a second call with the same inputs reads it (its ``fit`` None then: the kept
    subset's constrained fit is in the cache too). None cache_dir: chosen every time. A
    prediction that cannot be made (a singular system at a probe frequency) gives the fallback,
    not kept."""
    structure = structure if structure is not None else structure_of(model)
    key = choice_key(model, table, poles, dt, structure)
    path = entry_path(cache_dir, "poles", key)
    names = ("kept", "units", "rate", "worst", "fallback", "evaluated", "tested")
    hit = read_arrays(path, (), attrs=names)
    if hit is not None:
        a = hit[1]
        return PoleChoice(tuple(int(u) for u in np.atleast_1d(a["kept"])), int(a["units"]), float(a["rate"]),
                          float(a["worst"]), bool(a["fallback"]), int(a["evaluated"]), int(a["tested"]), key or "")
    basis = ContinuationBasis(table, poles)
    try:
        choice = choose_poles(Probe(model, table, dt, structure), basis, table, cache_dir=cache_dir, key=key or "")
    except np.linalg.LinAlgError:        # a singular condensation at a probe frequency: no prediction
        n = len(basis.units)
        return PoleChoice(tuple(range(n)), n, float("nan"), float("nan"), True, key=key or "")
    write_arrays(path, {}, attrs=dict(kept=np.array(choice.kept, np.int64), units=choice.units, rate=choice.rate,
                                      worst=choice.worst, fallback=choice.fallback, evaluated=choice.evaluated,
                                      tested=choice.tested))
    return choice


def scene_stand_in(model, table, fit_model, dt, *, structure=None, cache_dir=None) -> PoleChoice:
    """``pole_choice`` with the kept subset's constrained fit at hand (``fit``: made, or read from
    ``cache_dir``): what a run of the scene marches, whatever its record. An ensemble's set-up
    makes it once (``settle``); each cell takes it when its key is the cell's own."""
    choice = pole_choice(model, table, fit_model.poles, dt, structure=structure, cache_dir=cache_dir)
    if choice.fit is None:
        kept = fit_model.poles if choice.fallback else ContinuationBasis.kept_poles(fit_model.poles, choice.kept)
        choice = dataclasses.replace(choice, fit=continuation_fit(table, kept, cache_dir=cache_dir))
    return choice


def stand_in_factory(table, fit_model, *, cache_dir=None, damping=None, chosen=None):
    """callable(prob) -> (NativeStandIn or None, reason): the constrained fit of ``table`` on the
    poles of ``fit_model`` that ``pole_choice`` keeps for the structure and step of ``prob`` (all of
    them when no subset of fewer meets its bounds and is passive: the reason and the marcher's
    ``info`` say which), cached in ``cache_dir``, marched natively, or None and why not (the fit not
    passive, no native library here). ``chosen``: a ``scene_stand_in`` made already (an ensemble's,
    once: ``settle``), taken when its key is this problem's (else chosen here, as a single run)."""
    def make(prob):
        structure = prob.op.st
        if chosen is not None and chosen.fit is not None and chosen.key and \
                chosen.key == choice_key(prob.model, table, fit_model.poles, prob.grid.dt, structure):
            choice = chosen
        else:
            choice = scene_stand_in(prob.model, table, fit_model, prob.grid.dt, structure=structure,
                                    cache_dir=cache_dir)
        fit, poles = choice.fit, f"; {choice.note()}"
        if not fit.passive:
            return None, (f"the fit constrained to the route's continuation ({fit_model.order} poles) is not "
                          f"passive (margin {fit.margin:.2e}{poles})")
        lib = library(cache_folder(cache_dir))
        if lib is None:
            return None, library_note(cache_folder(cache_dir))
        marcher = NativeStandIn(prob, fit.model, lib, damping, single=SINGLE, lean=LEAN)
        marcher.info = choice.info()
        return marcher, (f"stand-in: the fit constrained to the route's continuation ({fit.model.order} of the fit's "
                         f"{fit_model.order} poles{poles}; {fit.max_rel_error:.1e} on the table), native march")
    return make
