"""The fit of a table: ``fit_table`` (with the cache) and ``fit`` (the pipeline: target, order
search, rigid-raft correction, passivity, report)."""
from __future__ import annotations

import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..blocked import BlockedTable
from ..passivity import PassivityReport, check_passive, with_verified_passivity
from ..rational import FitError
from .io import read_fit, save_fit
from .options import RIGID, FitOptions, code_version
from .result import FitReport, FitResult
from .rigid import rigid_errors, rigid_projection
from .streamed import StreamedProblem
from .search import OrderSearch, candidates, enforce_candidates, miss_message
from .target import Problem, dof_blocks, hysteretic_floor, rel_errors


def fit_table(table, tol=None, *, cache_dir=None, node_xy=None, progress=None, options: FitOptions | None = None,
              **kwargs) -> FitResult:
    """Passive common-pole rational model of ``table`` (docs/formulation.md, "Rational soil model").

    table : ImpedanceTable
    tol (default 0.01), node_xy and the keyword options : ``FitOptions`` (max_order, weighting, enforce, f_causal_hz,
        n_iter, margin, passivity_method, patience, max_enforce, enforce_iter, rigid_correction), or
        ``options`` given whole (then tol, node_xy and kwargs must not be)
    cache_dir : directory for fitted models, keyed by ``FitOptions.cache_key`` (table hash, options,
        node_xy, code digest); entries are written atomically with a content checksum, a damaged
        one is recomputed with a ``soil_impedance.cache.CacheWarning``
    progress : optional callable(done: int, total: int, label: str), called after each fitted
        order (label "order search", total = the pole pairs it may try) and after each passivity
        test of an enforcement iteration (label "passivity <m> poles", or "... (plain fit)" when
        the rigid-corrected model failed; total = enforce_iter + 1; it stops early when passive)

    Order search and enforcement: the orders are fitted cheaply (compressed columns) until tol is
    met (the criterion: max_rel_error, and for gap tables rigid_error too), the criterion stalls
    (``patience``) or max_order; then passivity is enforced on the smallest order meeting tol; if
    enforcement pushed the criterion above tol, the next orders meeting it are fitted and enforced.
    If no order meets tol the smallest order at the error plateau is enforced first, then (unless tol
    is below the hysteretic floor estimate and that model is already within 1.2 × the floor) larger
    orders that lower the error are tried (the best passive one is kept; stop at the first failure);
    if none could be made passive, or (away from the hysteretic floor) none meets tol after its
    enforcement, smaller orders are tried too (those whose fit is not already worse than the best
    enforced model), the best passive one kept (the soft-soil stress case's 8-pole fit came out
    passive but 185 % off, its 6-pole one 28 %). At most 1 + max_enforce orders are
    enforced in all, each with at most enforce_iter iterations: the work is bounded, and the result
    depends on the inputs only (no wall-clock budget). Never an exception for a missed tol: the
    report's ``tol_reached`` is False and ``message`` says why (e.g. the hysteretic error floor
    ``error_floor``) and what tol is reachable; a RuntimeWarning carries the same message.
    FitError only if no order can be made passive within the bounds (nothing is cached then).
    """
    if options is None:
        options = FitOptions.make(node_xy, **({} if tol is None else {"tol": tol}), **kwargs)
    elif kwargs or node_xy is not None or tol is not None:
        raise FitError("fit_table: give either options=FitOptions(...) or tol/node_xy/keyword options, not both")
    if cache_dir is not None:
        hit = cached_fit(table.hash, options, cache_dir)
        if hit is not None:
            return hit
    result = fit(table, options, progress)
    if cache_dir is not None:                # a cache that cannot be written only warns
        from ..cache import write_entry
        write_entry(_cache_path(table.hash, options, cache_dir), lambda p: save_fit(result, p))
    return result


def cached_fit(table_hash: str, options: FitOptions, cache_dir) -> FitResult | None:
    """The fit ``fit_table`` cached in ``cache_dir`` for the table of hash ``table_hash`` (its
    inputs, ``ImpedanceTable.hash``; ``sweep.table_key`` gives it without the table) and
    ``options``, verified on read; None when there is none (a damaged entry is moved aside
    with a CacheWarning, ``cache.read_entry``). The entry is read once, as its checksum reads
    it, and the model's digest is the one stored with it (``rational.read_model``)."""
    from ..cache import read_entry
    path = _cache_path(table_hash, options, cache_dir)
    return read_entry(path, lambda h, data: read_fit(h, path, data, trust_digest=True), keep=True)


def _cache_path(table_hash: str, options: FitOptions, cache_dir) -> Path:
    return Path(cache_dir) / f"fit-{options.cache_key(table_hash)[:24]}.h5"


def fit(table, options: FitOptions, progress=None) -> FitResult:
    """The fit itself (no cache): ``fit_table`` with its options given whole."""
    t0 = time.perf_counter()
    P = _projection(table, options)
    streamed = isinstance(table, BlockedTable)
    if streamed:                           # the table on disk, read in blocks (fit.streamed)
        prob = StreamedProblem(table, options.weighting, options.f_causal_hz, P)
    else:
        prob = Problem(table, options.weighting, options.f_causal_hz)
    floor = hysteretic_floor(prob)
    settings = dict(options.settings(), rigid_corrected=P is not None)
    prov = {"source_table_hash": table.hash, "f_max_hz": float(table.frequencies_hz[-1]),
            "f_causal_hz": prob.f_c, "fit_settings": settings, "code": code_version()}
    search = OrderSearch(prob, options, P, prov, progress)
    stop = search.run()
    if options.enforce:
        best, attempts, failures, notes = enforce_candidates(search, stop, floor, progress)
        if best is None:
            raise FitError(f"no fitted order could be made passive within the work bounds (max_enforce = "
                           f"{options.max_enforce}, enforce_iter = {options.enforce_iter}): " + "; ".join(failures))
    else:
        first = candidates([fit[3] for fit in search.fits], options.tol, floor)[0]
        model = search.build(first)
        best, attempts, failures, notes = ((search.criterion(model), model,
                                            check_passive(model, method=options.passivity_method),
                                            search.fits[first][2]), [], [], [])
    err_after, model, prep, err_fit = best
    message = miss_message(search, best, stop, notes, floor)
    if message:
        warnings.warn(message, RuntimeWarning, stacklevel=3)
    report = (_report_streamed if streamed else _report)(prob, model, prep, err_fit, search.history, settings,
                                                           time.perf_counter() - t0)
    rigid = {} if P is None else (rigid_errors(model, None, prob.f, P, prob.band, Kt=prob.rigid_raw[prob.band])
                                  if streamed else rigid_errors(model, table.matrices, prob.f, P, prob.band))
    report = replace(report, tol_reached=bool(err_after <= options.tol), message=message, error_floor=float(floor),
                     stop_reason=stop, enforcement_attempts=[list(a) for a in attempts], rigid_errors=rigid)
    model = model.with_provenance(dict(model.provenance, **({"enforcement_fallback": failures} if failures else {}),
                                       max_rel_error=report.max_rel_error, passive=report.passive,
                                       passivity_margin=report.passivity_margin))
    # the steppers' passivity test (default settings), run once here and stored with the model
    return FitResult(with_verified_passivity(model), report)


def _projection(table, options: FitOptions):
    """P of the rigid-raft correction (``rigid_projection``), or None when it is off."""
    if not options.rigid_correction:
        return None
    try:
        P = rigid_projection(table, options.node_xy)
    except FitError:
        if options.rigid_correction is True:
            raise
        return None
    if P is None and options.rigid_correction is True:
        raise FitError(f"rigid_correction=True needs a gap table (DOFs {list(RIGID)} + w0..), got "
                       f"{table.dofs[:8]}: use rigid_correction='auto' or False")
    return P


def _report(prob, model, prep: PassivityReport, err_fit, history, settings, wall):
    Kfull = model.frequency_response(prob.f)
    Km = Kfull[:, prob.idx][:, :, prob.idx] * prob.S[None, :, None] * prob.S[None, None, :]
    e_t = rel_errors(Km, prob.Ks)
    e_un = rel_errors(Kfull, prob.table.matrices)
    blocks = {}
    dofs = [prob.table.dofs[i] for i in prob.idx]
    tot = np.linalg.norm(prob.Ks.reshape(prob.f.size, -1), axis=1)
    sel = prob.band
    for name, (r, c) in dof_blocks(dofs).items():
        d = np.linalg.norm((Km - prob.Ks)[:, r][:, :, c].reshape(prob.f.size, -1), axis=1)
        own = np.linalg.norm(prob.Ks[:, r][:, :, c].reshape(prob.f.size, -1), axis=1)
        blocks[name] = {"own": float(np.max(d[sel] / np.where(own[sel] > 0, own[sel], 1.0))),
                        "total": float(np.max(d[sel] / tot[sel]))}
    return _fit_report(prob, model, e_t, e_un, blocks, prep, err_fit, history, settings, wall)


def _report_streamed(prob, model, prep: PassivityReport, err_fit, history, settings, wall):
    """``_report`` of a ``StreamedProblem``: the same measures, summed block by block."""
    e_t, e_un, parts = prob.report_errors(model)
    sel = prob.band
    tot2 = prob.norm_Ks[sel] ** 2
    blocks = {}
    if parts is None:
        blocks["all"] = {"own": float(np.max(e_t[sel])), "total": float(np.max(e_t[sel]))}
    else:
        for name, (d2, o2) in parts.items():
            d, own = np.sqrt(d2[sel]), np.sqrt(o2[sel])
            blocks[name] = {"own": float(np.max(d / np.where(own > 0, own, 1.0))),
                            "total": float(np.max(d / np.sqrt(tot2)))}
    return _fit_report(prob, model, e_t, e_un, blocks, prep, err_fit, history, settings, wall)


def _fit_report(prob, model, e_t, e_un, blocks, prep: PassivityReport, err_fit, history, settings, wall):
    """The FitReport of ``model`` from its relative errors per frequency (scaled ``e_t``,
    unscaled ``e_un``) and per DOF block (``blocks``), measured over the problem's band."""
    low = ~prob.band
    return FitReport(order=int(model.order), max_rel_error=float(np.max(e_t[prob.band])),
                     rel_error=e_t, freq_hz=prob.f.copy(),
                     max_rel_error_fit=float(err_fit), max_rel_error_unscaled=float(np.max(e_un[prob.band])),
                     low_freq_error=float(e_t[low].max()) if low.any() else 0.0, f_causal_hz=float(prob.f_c),
                     block_errors=blocks, passive=bool(prep.passive), passivity_margin=float(prep.margin),
                     passivity=prep.to_dict(), order_history=history, settings=settings, wall_s=float(wall))
