"""The order search: fit one more pole pair at a time until tol is met, the error stalls or the
work bound (``OrderSearch``); then passivity enforcement of the candidate orders, bounded by
work (``enforce_candidates``), and the message when tol is missed (``miss_message``)."""
from __future__ import annotations

import numpy as np

from ..passivity import enforce_passivity
from ..rational import FitError, RationalModel
from .options import RIGID, FitOptions
from .rigid import rigid_correct, rigid_error, rigid_errors, rigid_protection
from .target import fit_order, rel_errors

_I6 = np.eye(len(RIGID))          # the projection of a rigid-raft (6-DOF) model on itself
#: orders of the streamed search's first batch (``OrderSearch.run``): the mat and the 600- and 1200-node fits met
#: the default tol at 6 to 8 poles; an order's E costs an eigendecomposition when it is indefinite (half of the
#: mat's search when all 15 orders were fitted at once), so the orders after these are fitted only when needed
FIRST_ORDERS = 4


def _round_up(x, digits=2) -> float:
    if x <= 0:
        return 0.0
    e = np.floor(np.log10(x)) - (digits - 1)
    return float(np.ceil(x / 10 ** e - 1e-9) * 10 ** e)


def _rank(criterion) -> float:
    """A criterion for comparison: NaN (a failed error measure) ranks last."""
    return criterion if np.isfinite(criterion) else np.inf


def candidates(errs, tol, floor):
    """(first, up, down) indices into the fitted orders (selection criterion ``errs``, by increasing
    order) for passivity enforcement.

    first: the smallest order meeting tol; if none does, the smallest order at the plateau (error
    within 5 % of the best, or within 1.2 × the hysteretic floor estimate). up: larger orders worth
    trying afterwards (meeting tol, resp. lowering the error: the record orders), by increasing order.
    down: smaller orders, fallback when enforcement fails or misses tol (fewer poles are easier): halving the
    number of pole pairs first (the enforcement budget max_enforce reaches far down), then the others by
    decreasing order."""
    errs = np.asarray(errs, float)
    best = errs.min()
    ok = np.nonzero(errs <= tol)[0]
    if ok.size:
        first = int(ok[0])
        up = [int(i) for i in ok[1:]]
    else:
        good = max(1.05 * best, 1.2 * floor)
        first = int(np.nonzero(errs <= good)[0][0])
        up, rec = [], errs[first]
        for i in range(first + 1, errs.size):
            if errs[i] < 0.97 * rec:
                up.append(i)
                rec = errs[i]
    halving = [first >> k for k in range(1, first.bit_length() + 1)]     # first/2, first/4, ..., 0
    down = list(dict.fromkeys(halving + list(range(first - 1, -1, -1))))
    return first, up, down


def max_pairs(options: FitOptions, n_freq: int) -> int:
    """Pole pairs the order search may try: max_order/2, and at most (F − 2)/2 for F table
    frequencies, so that each entry's least squares keeps at least twice as many real equations
    (2F) as unknowns (m poles + D + E): with fewer the fit interpolates the table, with spurious
    resonances between its frequencies that passivity enforcement cannot remove (small raft,
    21 frequencies, 3 % hysteretic soil: 30 poles met 0.8 % where the causal floor is 3.3 %, and
    no enforcement converged)."""
    return max(1, min(options.max_order, n_freq - 2) // 2)


class OrderSearch:
    """The fitted orders of one fit, by increasing order (one more pole pair each), and their
    selection criterion before enforcement: the band error, and for gap tables with the rigid-raft
    correction max(band error, rigid-raft Re/Im error).

    Memory: an order's coefficients are (m + 2) n² doubles (1.6 GB for 30 poles at 2506 DOFs), so
    only those of the order with the best criterion so far are kept (``fits[i][1]``, None for the
    others); the others keep their poles and errors, and their coefficients are fitted again when
    the enforcement asks for them (``coefficients``: the same deterministic least squares on the
    same poles, hence the same arrays bit for bit). At most two orders' coefficients are alive at
    once: the kept one and the order being fitted (or refitted)."""

    #: ``run`` fits a streamed problem's orders at once (``StreamedProblem.search_orders``); False: order by order
    batched = True

    def __init__(self, prob, options: FitOptions, P, prov, progress):
        self.prob, self.options, self.P, self.prov = prob, options, P, prov
        self.max_pairs = max_pairs(options, prob.f.size)
        self.protect = None if P is None else rigid_protection(prob, P)
        self.fits = []            # (poles, C or None (not kept), max_rel_error, criterion)
        self.history = []         # report.order_history
        self.refits = 0           # coefficients fitted again on demand (``coefficients``)
        self.progress = progress
        self.batch = None         # the orders' (poles, error, rigid-raft model) of a streamed problem (``run``)

    def coefficients(self, i) -> np.ndarray:
        """The coefficients of fitted order i: the kept ones, or fitted again from its poles."""
        poles, C = self.fits[i][:2]
        if C is None:
            self.refits += 1
            C = self.prob.coefficients(poles)
        return C

    def held(self) -> int:
        """How many orders' coefficients the search holds (at most 1 between two calls)."""
        return sum(fit[1] is not None for fit in self.fits)

    def build(self, i, corrected=True, C=None) -> RationalModel:
        """The model of fitted order i (rigid-corrected unless ``corrected`` is False); ``C`` its
        coefficients when the caller has them (else ``coefficients(i)``)."""
        poles = self.fits[i][0]
        model = self.prob.model(poles, self.coefficients(i) if C is None else C, self.prov)
        if self.P is None or not corrected:
            return model
        if getattr(self.prob, "streamed", False):         # Pᵀ target P taken in the problem's first pass
            return rigid_correct(model, None, self.prob.f, self.P, f_c=self.prob.f_c, Kt=self.prob.rigid_target)
        return rigid_correct(model, self.prob.unscaled_target, self.prob.f, self.P, f_c=self.prob.f_c)

    def rigid_error(self, model) -> float:
        if self.P is None:
            return 0.0
        if getattr(self.prob, "streamed", False):
            return rigid_error(rigid_errors(model, None, self.prob.f, self.P, self.prob.band,
                                            Kt=self.prob.rigid_raw[self.prob.band]))
        return rigid_error(rigid_errors(model, self.prob.table.matrices, self.prob.f, self.P, self.prob.band))

    def criterion(self, model) -> float:
        """The selection criterion of a model (e.g. after enforcement)."""
        if getattr(self.prob, "streamed", False):
            band_error = float(np.max(self.prob.response_errors(model)[self.prob.band]))
            return max(band_error, self.rigid_error(model))
        band_error = float(np.max(rel_errors(self.prob.scaled_response(model), self.prob.Ks)[self.prob.band]))
        return max(band_error, self.rigid_error(model))

    def fit_next(self) -> float:
        """Fit the next order; its criterion (before enforcement). Its coefficients are kept when
        its criterion is the best so far (strictly lower: the first of equals), and those of the
        order kept before are dropped. With ``batch`` (``run`` on a streamed problem) the order is
        taken from it: its criterion without its coefficients, which are fitted when asked for."""
        if self.batch is not None:
            return self._take_batched()
        poles, C, err = fit_order(self.prob, len(self.fits) + 1, self.options.n_iter)
        kept = [i for i, fit in enumerate(self.fits) if fit[1] is not None]
        self.fits.append((poles, C, err, err))
        if self.P is None:
            self.history.append((int(poles.size), err))
        else:
            rig = self.rigid_error(self.build(len(self.fits) - 1, C=C))
            self.fits[-1] = (poles, C, err, max(err, rig))
            self.history.append((int(poles.size), err, rig))
        if not kept or _rank(self.fits[-1][3]) < _rank(self.fits[kept[0]][3]):
            for i in kept:
                self.fits[i] = (self.fits[i][0], None) + self.fits[i][2:]
        else:
            self.fits[-1] = (poles, None) + self.fits[-1][2:]
        del C
        if self.progress is not None:
            self.progress(len(self.fits), self.max_pairs, "order search")
        return self.fits[-1][3]

    def _take_batched(self) -> float:
        if len(self.fits) == len(self.batch):           # the next orders: the first few, then all the others
            last = self.max_pairs if self.batch else min(FIRST_ORDERS, self.max_pairs)
            self.batch += self.prob.search_orders(last, self.options.n_iter, self.prov, first=len(self.batch) + 1)
        poles, err, rigid = self.batch[len(self.fits)]
        crit = err
        if self.P is None:
            self.history.append((int(poles.size), err))
        else:
            corrected = rigid_correct(rigid, None, self.prob.f, _I6, f_c=self.prob.f_c, Kt=self.prob.rigid_target)
            rig = rigid_error(rigid_errors(corrected, None, self.prob.f, _I6, self.prob.band,
                                           Kt=self.prob.rigid_raw[self.prob.band]))
            crit = max(err, rig)
            self.history.append((int(poles.size), err, rig))
        self.fits.append((poles, None, err, crit))
        if self.progress is not None:
            self.progress(len(self.fits), self.max_pairs, "order search")
        return crit

    def run(self) -> str:
        """Fit orders until tol is met, the criterion stalls (``patience``) or max_pairs; the reason.

        A streamed problem (the table on disk) fits its orders in two batches, the first
        ``FIRST_ORDERS`` orders and, if the search goes on, all the others up to max_pairs, each batch
        in one or two passes over the table (``StreamedProblem.search_orders``: errors and rigid-raft
        criteria up to round-off those of the order-by-order fit, no coefficients held); the search
        takes them in order with the same rules, and the enforcement fits the coefficients of the
        orders it tries (``coefficients``). The "entry" weighting fits order by order."""
        tol, patience = self.options.tol, self.options.patience
        if self.batched and getattr(self.prob, "streamed", False) and self.prob.weighting != "entry" and not self.fits:
            self.batch = []
        while len(self.fits) < self.max_pairs:
            if self.fit_next() <= tol:
                return "tol reached"
            errs = [fit[3] for fit in self.fits]
            if patience and len(errs) > patience and min(errs[-patience:]) > 0.8 * min(errs[:-patience]):
                return f"error stalled at {min(errs):.3g} over the last {patience} orders"
        return "max_order"

    def further(self):
        """Orders above the last one fitted that meet tol, fitted on demand (enforcement may push the
        criterion above tol: on gap tables, the rigid-raft Im K at low frequency)."""
        while len(self.fits) < self.max_pairs:
            if self.fit_next() <= self.options.tol:
                yield len(self.fits) - 1


def enforce_candidates(search: OrderSearch, stop: str, floor: float, progress):
    """Passivity enforcement of the candidate orders (``candidates``), bounded by work: at most
    1 + max_enforce orders, each with at most enforce_iter iterations per variant (the rigid-corrected
    model, then the plain fit). Returns (best, attempts, failures, notes) with best = (criterion,
    model, PassivityReport, max_rel_error before enforcement) or None when no order was made passive."""
    opt, prob = search.options, search.prob
    first, up, down = candidates([fit[3] for fit in search.fits], opt.tol, floor)
    if stop == "tol reached":
        up = search.further()
    attempts, failures, notes = [], [], []
    budget = [1 + opt.max_enforce]

    def attempt(i):
        budget[0] -= 1
        poles, err_fit = search.fits[i][0], search.fits[i][2]
        stage = f"passivity {poles.size} poles"
        C = search.coefficients(i)             # once for both variants (fitted again if not kept)
        for corrected in ((True, False) if search.P is not None else (False,)):
            what = "rigid-corrected " if corrected else ""
            tick = None if progress is None else (lambda done, total, s=stage + (" (plain fit)" if not corrected and
                                                  search.P is not None else ""): progress(done, total, s))
            try:
                model, rep, it = enforce_passivity(search.build(i, corrected, C), prob.f, prob.w_rel, margin=opt.margin,
                                                   method=opt.passivity_method, max_iter=opt.enforce_iter,
                                                   progress=tick, protect=search.protect)
                break
            except FitError as exc:
                failures.append(f"{poles.size} poles {what}: {exc}")
                attempts.append((int(poles.size), False, float("nan"), exc.iterations))
        else:
            return None
        e = search.criterion(model)
        attempts.append((int(poles.size), True, e, int(it)))
        return (e, model, rep, err_fit)

    best = attempt(first)
    at_floor = best is not None and floor > 0 and opt.tol < floor and best[0] <= 1.2 * floor
    if at_floor and up:
        notes.append("at the hysteretic floor: larger orders not tried")
    if best is not None and best[0] > opt.tol and not at_floor:
        for i in up:                       # more poles: lower error or tol met, while the budget allows
            if budget[0] <= 0:
                notes.append(f"at most {opt.max_enforce} further orders are tried (max_enforce)")
                break
            got = attempt(i)
            if got is None:
                notes.append(f"passivity enforcement failed at {search.fits[i][0].size} poles")
                break
            if got[0] < best[0]:
                best = got
            if best[0] <= opt.tol:
                break
    if best is None or (best[0] > opt.tol and not at_floor):
        for i in down:                     # fewer poles: easier to make passive, and may need a smaller change
            if best is not None and search.fits[i][3] >= best[0]:
                continue                       # already worse before enforcement
            if budget[0] <= 0:
                notes.append(f"at most {1 + opt.max_enforce} orders are enforced (max_enforce)")
                break
            got = attempt(i)
            if got is not None and (best is None or got[0] < best[0]):
                best = got
            if best is not None and best[0] <= opt.tol:
                break
    return best, attempts, failures, notes


def miss_message(search: OrderSearch, best, stop, notes, floor) -> str:
    """Why tol was missed and which tol is reachable ("" when reached)."""
    err, model, prep = best[:3]
    tol = search.options.tol
    if err <= tol:
        return ""
    what = "max rel error" if search.P is None else "max(rel error, rigid-raft Re/Im error)"
    parts = [f"tol {tol:g} not reached: returning the best {'passive ' if prep.passive else ''}model found, "
             f"{model.order} poles, {what} {err:.3g} (order search: {stop}"
             + (f"; {'; '.join(notes)}" if notes else "") + ")."]
    if floor > 0:
        parts.append(f"The table has hysteretic damping (loss factor 2ξ ≈ {floor / 0.55:.2g}), which no causal "
                     f"model follows (Kramers–Kronig): the band error has a floor ≈ ξ ≈ {floor:.2g} "
                     "(docs/formulation.md, Causality).")
    parts.append(f"Raise tol to ~{_round_up(1.05 * err):g}.")
    return " ".join(parts)
