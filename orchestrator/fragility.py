"""Fragility curves from an ensemble: P(limit state exceeded | PGA = x) = Phi(ln(x / median) / beta).

A *limit state* is a condition on one per-cell number of an ensemble file
(``orchestrator.ensemble``): ``max_uplift > 5 mm``, ``min_contact_ratio < 75 %``,
``floor_spectrum[node=top, direction=x, frequency=5.0] > 1.2 g`` (``parse_limit``). Each
converged cell either exceeds it or not; per PGA level j (a "stripe") that gives n_j cells and
z_j exceedances. Cells that did not converge (failed, stopped, refused) and converged cells
whose number is undefined (NaN: a floor spectrum in a direction of round-off response) are left
out and counted.

The fit is maximum likelihood on the counts (Baker, Earthquake Spectra 2015): with
u_j = ln(x_j / median) / beta,

    ln L(median, beta) = sum_j [ ln C(n_j, z_j) + z_j ln Phi(u_j) + (n_j - z_j) ln Phi(-u_j) ],

maximised over (ln median, beta) inside MEDIAN_FACTOR and BETA_BOUNDS by L-BFGS-B (analytic
gradient) from the best point of a fixed grid: deterministic. ln L is concave in
(1 / beta, ln median / beta) (probit regression), so the maximum is unique when it exists. It
does not exist when the data cannot fix both parameters; such fits are flagged with the reason
and give no curve (``Fit.reason``): no exceedance, all exceed, one PGA level only, exceedances
separated by PGA (no cell holds at a PGA above one that exceeds: beta -> 0), or the optimum
on a bound. The seeded bootstrap over records (``bootstrap``) resamples whole records (each
with its cells at every PGA) and refits, for a percentile band on the median and beta.

``fragility(ds, limits)`` gives an ``xarray.Dataset`` (its docstring) that ``store_fragility``
writes as the group ``fragility`` of the ensemble file
(``xarray.open_dataset(path, group="fragility", engine="h5netcdf")``).
"""
from __future__ import annotations

import operator
import re
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from scipy.optimize import minimize
from scipy.special import gammaln, log_ndtr, ndtr

from uplift_common.files import atomic_update, require_checksum

from uplift_common.errors import UserInputError
from orchestrator.motion import G

#: the fitted median lies within [lowest PGA / MEDIAN_FACTOR, highest PGA * MEDIAN_FACTOR]
MEDIAN_FACTOR = 10.0
#: the dispersion beta (standard deviation of ln capacity) lies within these bounds
BETA_BOUNDS = (0.01, 2.0)
#: a fitted parameter closer to a bound than this share of its range is "on the bound"
ON_BOUND = 1e-6
#: the start of the optimiser: best of a GRID x GRID grid over (ln median, ln beta)
GRID = 41
#: a stationary point: |d ln L / d(ln median, beta)| below this times the number of cells
GRADIENT_TOL = 1e-7
OPERATORS = {">": operator.gt, ">=": operator.ge, "<": operator.lt, "<=": operator.le}
#: units a threshold may be given in, per units of the file's variable: unit -> factor to the file's
UNITS = {"m": {"m": 1.0, "cm": 1e-2, "mm": 1e-3},
         "rad": {"rad": 1.0, "mrad": 1e-3},
         "1": {"1": 1.0, "%": 1e-2},
         "m s-2": {"m s-2": 1.0, "m/s2": 1.0, "m/s^2": 1.0, "g": G},
         "s": {"s": 1.0}}
#: floor_spectrum[...] keys
SPECTRUM_KEYS = ("node", "direction", "frequency")
CELL_DIMS = ("record", "pga", "route")
#: why a cell is left out: its status, or "undefined" (converged, its number NaN)
LEFT_OUT = ("failed", "stopped", "refused", "undefined")
GROUP = "fragility"
_LIMIT = re.compile(r"^\s*(?P<var>[A-Za-z_]\w*)\s*(?:\[(?P<sel>[^\]]*)\])?\s*(?P<op><=|>=|<|>)\s*"
                    r"(?P<value>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(?P<unit>\S*)\s*$")


class FragilityError(UserInputError):
    """Bad input to a fragility fit (a limit, a route, a file); the message names it and the fix."""


@dataclass(frozen=True)
class Limit:
    """A limit state ``variable[select] op value unit``; ``text`` is its normalised form."""
    text: str
    variable: str
    op: str
    value: float
    unit: str = ""
    select: tuple = ()          # ((key, value as written), ...) of floor_spectrum[...]


def parse_limit(text: str) -> Limit:
    """``"VAR OP VALUE [UNIT]"`` or ``"floor_spectrum[node=N, direction=D, frequency=F] OP VALUE
    [UNIT]"`` with OP one of > >= < <=; the unit (optional) is checked against the file later."""
    m = _LIMIT.match(text or "")
    if m is None:
        raise FragilityError(f"--limit {text!r}: write VARIABLE > VALUE or VARIABLE < VALUE with an optional "
                             "unit, e.g. 'max_uplift > 5 mm', 'min_contact_ratio < 75 %', "
                             "'floor_spectrum[node=top, direction=x, frequency=5.0] > 1.2 g'")
    select = ()
    if m["sel"] is not None:
        pairs = [p.split("=", 1) for p in m["sel"].split(",")]
        if any(len(p) != 2 or not p[0].strip() or not p[1].strip() for p in pairs):
            raise FragilityError(f"--limit {text!r}: write the selection as [key=value, ...], e.g. "
                                 "[node=top, direction=x, frequency=5.0]")
        select = tuple((k.strip(), v.strip()) for k, v in pairs)
        keys = [k for k, _ in select]
        if len(set(keys)) < len(keys):
            raise FragilityError(f"--limit {text!r}: a key of [...] is given twice")
    value = float(m["value"])
    sel = f"[{', '.join(f'{k}={v}' for k, v in select)}]" if select else ""
    norm = f"{m['var']}{sel} {m['op']} {m['value']}" + (f" {m['unit']}" if m["unit"] else "")
    return Limit(text=norm, variable=m["var"], op=m["op"], value=value, unit=m["unit"], select=select)


def limit_values(ds, limit: Limit):
    """The number of each cell the limit reads, shape (record, pga, route), in the file's units,
    and the threshold in those units. Unknown variable, selection or unit: FragilityError."""
    numeric = [n for n, v in ds.data_vars.items() if v.dims[:3] == CELL_DIMS and v.dtype.kind == "f"]
    where = f"--limit {limit.text!r}"
    if limit.variable not in numeric:
        raise FragilityError(f"{where}: no per-cell variable {limit.variable!r} in the ensemble file "
                             f"(its variables: {', '.join(numeric)})")
    da = ds[limit.variable]
    extra = da.dims[3:]
    if limit.variable == "floor_spectrum":
        da = _spectral_ordinate(da, dict(limit.select), where)
    elif limit.select:
        raise FragilityError(f"{where}: {limit.variable} is one number per cell: drop the [...]")
    elif extra:
        raise FragilityError(f"{where}: {limit.variable} has dimensions {extra} besides record, pga, route: "
                             "only floor_spectrum[...] selects within a cell")
    units = da.attrs.get("units", "")
    factors = UNITS.get(units, {units: 1.0})
    if limit.unit and limit.unit not in factors:
        raise FragilityError(f"{where}: unit {limit.unit!r} is not one of {limit.variable}'s "
                             f"({', '.join(factors)}; no unit: {units or 'dimensionless'})")
    return np.asarray(da.transpose(*CELL_DIMS).values, dtype=float), limit.value * factors.get(limit.unit, 1.0)


def _spectral_ordinate(da, select: dict, where: str):
    """floor_spectrum at one node, direction and frequency (Hz; linear in ln f between the two
    grid frequencies around it, the grid's own value on a grid point)."""
    if set(select) != set(SPECTRUM_KEYS):
        raise FragilityError(f"{where}: floor_spectrum needs [node=..., direction=..., frequency=...] "
                             f"(Hz), e.g. floor_spectrum[node={da['node'].values[0]}, direction=x, frequency=5.0]")
    for key in ("node", "direction"):
        names = [str(v) for v in da[key].values]
        if select[key] not in names:
            raise FragilityError(f"{where}: {key} {select[key]!r} is not in the file ({key}s: {', '.join(names)})")
    f = da["frequency"].values
    try:
        freq = float(select["frequency"])
    except ValueError:
        freq = np.nan
    if not f[0] <= freq <= f[-1]:
        raise FragilityError(f"{where}: frequency {select['frequency']!r} must be a number of Hz within the "
                             f"file's spectra, {f[0]:g} to {f[-1]:g} Hz")
    da = da.sel(node=select["node"], direction=select["direction"])
    k = int(np.clip(np.searchsorted(f, freq), 1, f.size - 1))
    w = (np.log(freq) - np.log(f[k - 1])) / (np.log(f[k]) - np.log(f[k - 1]))
    out = (1 - w) * da.isel(frequency=k - 1) + w * da.isel(frequency=k) if 0 < w < 1 else \
        da.isel(frequency=k if w >= 1 else k - 1)
    return out.assign_attrs(da.attrs)


# ---- the likelihood and its maximum -------------------------------------------------------------

def log_likelihood(median_g, beta, pga, cells, exceedances):
    """ln L of the module docstring (binomial coefficients included).

    median_g, beta : array_like, broadcast together (g, 1); pga, cells, exceedances : shape (L,)
    per level (g, counts). Returns an ndarray of the broadcast shape of median_g and beta."""
    n, z = np.asarray(cells, float), np.asarray(exceedances, float)
    u = (np.log(np.asarray(pga, float)) - np.log(np.asarray(median_g, float))[..., None]) / \
        np.asarray(beta, float)[..., None]
    const = gammaln(n + 1) - gammaln(z + 1) - gammaln(n - z + 1)
    return (const + z * log_ndtr(u) + (n - z) * log_ndtr(-u)).sum(axis=-1)


def _objective(p, lnx, n, z):
    """-ln L (without the constant) and its gradient in (ln median, beta)."""
    mu, beta = p
    u = (lnx - mu) / beta
    lp, lq = log_ndtr(u), log_ndtr(-u)
    log_phi = -0.5 * u * u - 0.5 * np.log(2 * np.pi)
    g = z * np.exp(log_phi - lp) - (n - z) * np.exp(log_phi - lq)          # d lnL / du
    return -(z * lp + (n - z) * lq).sum(), np.array([g.sum() / beta, (g * u).sum() / beta])


@dataclass(frozen=True)
class Fit:
    """A fitted fragility: median (g), beta, ln L at the optimum; or, when the data cannot fix
    them, ``reason`` (then the three are None)."""
    median_g: float | None
    beta: float | None
    log_likelihood: float | None
    reason: str = ""

    @property
    def identified(self) -> bool:
        return not self.reason

    def probability(self, pga):
        """P(exceed | PGA = pga), ndarray like pga (g)."""
        return ndtr(np.log(np.asarray(pga, float) / self.median_g) / self.beta)


def not_identifiable(pga, cells, exceedances) -> str:
    """Why the likelihood has no maximum for these counts ("" when it has one)."""
    pga, n, z = (np.asarray(a) for a in (pga, cells, exceedances))
    used = n > 0
    if not used.any():
        return "no usable cell (every cell failed, stopped, was refused or is undefined)"
    x = pga[used]
    if z.sum() == 0:
        return (f"no exceedance: no cell exceeds the limit at any PGA up to {x.max():g} g; the median lies "
                "above: add higher PGA levels")
    if z.sum() == n.sum():
        return (f"all exceed: every cell exceeds the limit at every PGA from {x.min():g} g; the median lies "
                "below: add lower PGA levels")
    if used.sum() == 1:
        return (f"one PGA level only ({x[0]:g} g): one fraction cannot fix both median and beta; add PGA "
                "levels around it")
    holds, exceeds = pga[used & (n > z)].max(), pga[used & (z > 0)].min()
    if holds <= exceeds:
        where, near = (f"at {holds:g} g", f"around {holds:g} g") if holds == exceeds else \
            (f"between {holds:g} and {exceeds:g} g",) * 2
        return (f"exceedances separated by PGA: no cell exceeds below and every cell exceeds above the median, "
                f"which lies {where}; the likelihood grows without bound as beta -> 0: add records or PGA "
                f"levels {near}")
    return ""


def fit_fragility(pga, cells, exceedances) -> Fit:
    """The maximum-likelihood lognormal fragility of counts per PGA level.

    pga : shape (L,), g > 0; cells, exceedances : shape (L,), counts (levels with no cell are
    ignored). Returns a Fit (with its reason when not identifiable: ``not_identifiable`` or the
    optimum on a bound of MEDIAN_FACTOR, BETA_BOUNDS)."""
    pga, n, z = (np.asarray(a, float) for a in (pga, cells, exceedances))
    reason = not_identifiable(pga, n, z)
    if reason:
        return Fit(None, None, None, reason)
    used = n > 0
    lnx, n, z = np.log(pga[used]), n[used], z[used]
    bounds = [(lnx.min() - np.log(MEDIAN_FACTOR), lnx.max() + np.log(MEDIAN_FACTOR)), BETA_BOUNDS]
    mu_grid = np.linspace(*bounds[0], GRID)
    beta_grid = np.geomspace(*BETA_BOUNDS, GRID)
    ll = log_likelihood(np.exp(mu_grid)[:, None], beta_grid[None, :], np.exp(lnx), n, z)
    i, j = np.unravel_index(np.argmax(ll), ll.shape)
    res = minimize(_objective, np.array([mu_grid[i], beta_grid[j]]), args=(lnx, n, z), jac=True,
                   method="L-BFGS-B", bounds=bounds, options={"ftol": 1e-14, "gtol": 1e-10, "maxiter": 1000})
    mu, beta = res.x
    # a line search that stops on round-off next to the optimum is converged: judge by the gradient
    if not res.success and np.abs(_objective(res.x, lnx, n, z)[1]).max() > GRADIENT_TOL * n.sum():
        return Fit(None, None, None, f"the optimiser did not converge ({res.message})")
    on = lambda v, lo, hi: min(v - lo, hi - v) <= ON_BOUND * (hi - lo)
    if on(mu, *bounds[0]):
        return Fit(None, None, None, f"the median runs to the bound {np.exp(mu):.3g} g ({MEDIAN_FACTOR:g} times "
                                     "beyond the PGA levels): add PGA levels toward it")
    if on(beta, *BETA_BOUNDS):
        why = "the fractions barely rise with PGA" if beta > 1 else "the curve is nearly a step"
        return Fit(None, None, None, f"beta runs to its bound {beta:g} ({why}): add records or PGA levels")
    return Fit(float(np.exp(mu)), float(beta), float(log_likelihood(np.exp(mu), beta, np.exp(lnx), n, z)))


def bootstrap(pga, exceeds, usable, samples: int, seed: int, confidence: float) -> dict:
    """Percentile band of the median and beta over ``samples`` resamplings of the records (with
    replacement; a record brings its cells at every PGA), numpy's default_rng(seed).

    exceeds, usable : bool arrays, shape (record, pga). Returns {samples, seed, confidence,
    identified (resamples with a fit), median_g: [low, high], beta: [low, high]} (None bands
    when no resample is identified)."""
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, exceeds.shape[0], size=(samples, exceeds.shape[0]))
    hits = exceeds & usable
    fits = [fit_fragility(pga, usable[d].sum(axis=0), hits[d].sum(axis=0)) for d in draws]
    ok = np.array([(f.median_g, f.beta) for f in fits if f.identified]).reshape(-1, 2)
    q = ((1 - confidence) / 2, (1 + confidence) / 2)
    band = lambda k: [float(v) for v in np.quantile(ok[:, k], q)] if len(ok) else None
    return {"samples": samples, "seed": seed, "confidence": confidence, "identified": len(ok),
            "median_g": band(0), "beta": band(1)}


# ---- an ensemble's fragility: the dataset, JSON, the file -------------------------------------------

def exceedances(values, status, op: str, threshold: float):
    """The cells of one route that count and those that exceed: values, status : shape
    (record, pga) (file units; status strings); op in OPERATORS. Returns (usable, hit) bool
    arrays (record, pga) and the left-out counts, shape (len(LEFT_OUT),)."""
    converged = status == "converged"
    usable = converged & np.isfinite(values)
    with np.errstate(invalid="ignore"):
        hit = OPERATORS[op](values, threshold) & usable
    left = [(status == why).sum() for why in LEFT_OUT[:-1]] + [(converged & ~usable).sum()]
    return usable, hit, np.array(left)


def _check_bootstrap(samples, seed, confidence) -> None:
    whole = lambda v: not isinstance(v, bool) and isinstance(v, (int, np.integer)) and v >= 0
    if not whole(samples):
        raise FragilityError(f"--bootstrap {samples!r}: a number of resamples >= 0 (e.g. 200; 0: none)")
    if not whole(seed):
        raise FragilityError(f"--seed {seed!r}: the bootstrap's seed is an integer >= 0")
    if not 0 < confidence < 1:
        raise FragilityError(f"--confidence {confidence!r}: a share in (0, 1), e.g. 0.9")


def fragility(ds, limits, routes=None, samples: int = 0, seed: int = 0, confidence: float = 0.9):
    """The fits of ``limits`` (texts or Limits) on ``routes`` (default: all) of an ensemble
    dataset (``orchestrator.ensemble.read_ensemble``) as an xarray.Dataset:

    coordinates limit (its normalised text), route, pga (g), left_out (LEFT_OUT), bound (low,
    high); per limit: variable, operator, threshold (file units), units; per limit and route:
    median_g, beta, log_likelihood (NaN when not identified), reason ("" when identified), and
    with ``samples`` > 0 the bootstrap's median_g_band, beta_band, bootstrap_identified; per
    limit, route and pga: cells, exceedances; per limit, route and reason: left_out_cells."""
    import xarray as xr  # start-up cost (~0.5 s, pandas): only ensembles pay it
    limits = [lim if isinstance(lim, Limit) else parse_limit(lim) for lim in limits]
    if not limits:
        raise FragilityError("--limit: give at least one limit state, e.g. --limit 'max_uplift > 5 mm'")
    if len({lim.text for lim in limits}) < len(limits):
        raise FragilityError("--limit: the same limit state is given twice")
    in_file = [str(r) for r in ds["route"].values]
    routes = list(routes) if routes else in_file
    for r in routes:
        if r not in in_file:
            raise FragilityError(f"--route {r!r} is not in the ensemble file (its routes: {', '.join(in_file)})")
    _check_bootstrap(samples, seed, confidence)
    pga = ds["pga"].values.astype(float)
    status = ds["status"].transpose(*CELL_DIMS).values.astype(str)
    L, R, P = len(limits), len(routes), pga.size
    nan = lambda *shape: np.full(shape, np.nan)
    out = {"median_g": nan(L, R), "beta": nan(L, R), "log_likelihood": nan(L, R),
           "reason": np.full((L, R), "", dtype=object), "cells": np.zeros((L, R, P), int),
           "exceedances": np.zeros((L, R, P), int), "left_out_cells": np.zeros((L, R, len(LEFT_OUT)), int),
           "median_g_band": nan(L, R, 2), "beta_band": nan(L, R, 2), "bootstrap_identified": np.zeros((L, R), int)}
    thresholds, units = [], []
    for a, lim in enumerate(limits):
        values, threshold = limit_values(ds, lim)
        thresholds.append(threshold)
        units.append(ds[lim.variable].attrs.get("units", ""))
        for b, route in enumerate(routes):
            k = in_file.index(route)
            usable, hit, out["left_out_cells"][a, b] = exceedances(values[:, :, k], status[:, :, k], lim.op,
                                                                   threshold)
            out["cells"][a, b], out["exceedances"][a, b] = usable.sum(axis=0), hit.sum(axis=0)
            fit = fit_fragility(pga, out["cells"][a, b], out["exceedances"][a, b])
            out["reason"][a, b] = fit.reason
            if not fit.identified:
                continue
            out["median_g"][a, b], out["beta"][a, b], out["log_likelihood"][a, b] = \
                fit.median_g, fit.beta, fit.log_likelihood
            if samples:
                bs = bootstrap(pga, hit, usable, samples, seed, confidence)
                out["bootstrap_identified"][a, b] = bs["identified"]
                if bs["identified"]:
                    out["median_g_band"][a, b], out["beta_band"][a, b] = bs["median_g"], bs["beta"]
    dims = {"median_g": ("limit", "route"), "beta": ("limit", "route"), "log_likelihood": ("limit", "route"),
            "reason": ("limit", "route"), "cells": ("limit", "route", "pga"),
            "exceedances": ("limit", "route", "pga"), "left_out_cells": ("limit", "route", "left_out"),
            "median_g_band": ("limit", "route", "bound"), "beta_band": ("limit", "route", "bound"),
            "bootstrap_identified": ("limit", "route")}
    keep = dims if samples else [k for k in dims if "band" not in k and k != "bootstrap_identified"]
    frag = xr.Dataset(
        {name: (dims[name], out[name].astype(str) if name == "reason" else out[name]) for name in keep},
        coords={"limit": [lim.text for lim in limits], "route": routes,
                "pga": ("pga", pga, {"units": "g"}), "left_out": list(LEFT_OUT), "bound": ["low", "high"]})
    frag["variable"] = ("limit", [lim.variable for lim in limits])
    frag["operator"] = ("limit", [lim.op for lim in limits])
    frag["threshold"] = ("limit", np.array(thresholds), {"long_name": "threshold in the variable's units"})
    frag["units"] = ("limit", units)
    frag["median_g"].attrs.update(units="g", long_name="median of the lognormal fragility")
    frag.attrs.update(bootstrap_samples=int(samples), bootstrap_seed=int(seed), confidence=float(confidence))
    return frag


def fragility_json(frag) -> dict:
    """``{"fragility": [...]}`` of ``uplift fragility --json``: one entry per limit and route."""
    opt = lambda v: float(v) if np.isfinite(v) else None
    band = lambda v: [float(x) for x in v] if np.isfinite(v).all() else None      # no resample fitted: None
    entries = []
    for a, lim in enumerate(frag["limit"].values):
        for b, route in enumerate(frag["route"].values):
            reason = str(frag["reason"].values[a, b])
            e = {"limit": str(lim), "route": str(route), "variable": str(frag["variable"].values[a]),
                 "operator": str(frag["operator"].values[a]), "threshold": float(frag["threshold"].values[a]),
                 "units": str(frag["units"].values[a]), "median_g": opt(frag["median_g"].values[a, b]),
                 "beta": opt(frag["beta"].values[a, b]),
                 "log_likelihood": opt(frag["log_likelihood"].values[a, b]), "identifiable": not reason,
                 "reason": reason or None, "pga_g": [float(p) for p in frag["pga"].values],
                 "cells": [int(c) for c in frag["cells"].values[a, b]],
                 "exceedances": [int(c) for c in frag["exceedances"].values[a, b]],
                 "left_out": dict(zip(LEFT_OUT, map(int, frag["left_out_cells"].values[a, b]))), "bootstrap": None}
            if frag.attrs["bootstrap_samples"] and not reason:
                e["bootstrap"] = {"samples": int(frag.attrs["bootstrap_samples"]),
                                  "seed": int(frag.attrs["bootstrap_seed"]),
                                  "confidence": float(frag.attrs["confidence"]),
                                  "identified": int(frag["bootstrap_identified"].values[a, b]),
                                  "median_g": band(frag["median_g_band"].values[a, b]),
                                  "beta": band(frag["beta_band"].values[a, b])}
            entries.append(e)
    return {"fragility": entries}


def store_fragility(path, frag) -> Path:
    """Write ``frag`` as the group ``fragility`` of the ensemble file ``path`` (replacing an
    earlier one), atomically: the file is verified and copied, the group written into the copy,
    the copy (in memory) re-stamped with its checksum and written onto ``path`` (``uplift_common.files.atomic_update``)."""
    path = Path(path)
    with atomic_update(path) as tmp:
        with h5py.File(tmp, "a") as f:
            if GROUP in f:
                del f[GROUP]
        frag.to_netcdf(tmp, mode="a", group=GROUP, engine="h5netcdf")
    return path


def read_fragility(path):
    """The stored fragility dataset of an ensemble file (loaded), or None without one."""
    import xarray as xr  # start-up cost, see fragility
    with h5py.File(path, "r") as f:
        require_checksum(f, path, "run `uplift ensemble` and `uplift fragility` again")
        if GROUP not in f:
            return None
    with xr.open_dataset(path, group=GROUP, engine="h5netcdf") as frag:
        return frag.load()


def fragility_figure(frag, title: str = ""):
    """One panel per limit state (titled with the limit, and the file's units when the limit
    gives none): per route (one colour, marker and line style:
    ``orchestrator.plots.route_style``) the observed fraction z/n at each PGA (labelled with
    z/n; the routes' points side by side about each PGA), the fitted curve, and the bootstrap
    band of the median at P = 0.5 when present (the routes' bands a little apart); a fit that
    is not identified is named with its reason, no curve. A Figure (the caller closes it)."""
    from orchestrator.plots import dodged, pyplot, route_style  # matplotlib: only drawing pays its import
    plt = pyplot()
    limits = [str(v) for v in frag["limit"].values]
    routes = [str(r) for r in frag["route"].values]
    fig, axes = plt.subplots(1, len(limits), figsize=(5.5 * len(limits), 4.5), squeeze=False,
                             constrained_layout=True)
    pga = frag["pga"].values
    x = np.linspace(0.0, 1.15 * pga.max(), 200)[1:]
    for ax, (a, lim) in zip(axes[0], enumerate(limits)):
        notes = []
        for b, route in enumerate(routes):
            style = route_style(b)
            n, z = frag["cells"].values[a, b], frag["exceedances"].values[a, b]
            used = n > 0
            at = dodged(pga, b, len(routes))[used]
            ax.plot(at, z[used] / n[used], style["marker"], color=style["color"], linestyle="none",
                    label=f"{route}: observed z/n")
            for p, zz, nn in zip(at, z[used], n[used]):
                ax.annotate(f"{zz}/{nn}", (p, zz / nn), textcoords="offset points",
                            xytext=(4, (5 if zz / nn < 0.5 else -10) + 8 * b * (1 if zz / nn < 0.5 else -1)),
                            fontsize="x-small", color=style["color"])
            reason = str(frag["reason"].values[a, b])
            if reason:
                notes.append(f"{route}: not identifiable: {reason.split(':')[0]}")
                continue
            fit = Fit(float(frag["median_g"].values[a, b]), float(frag["beta"].values[a, b]), None)
            ax.plot(x, fit.probability(x), linestyle=style["linestyle"], color=style["color"],
                    label=f"{route}: median {fit.median_g:.3g} g, beta {fit.beta:.2f}")
            if "median_g_band" in frag and np.isfinite(frag["median_g_band"].values[a, b]).all():
                lo, hi = frag["median_g_band"].values[a, b]
                level = 0.5 + 0.03 * (b - (len(routes) - 1) / 2)
                ax.plot([lo, hi], [level, level], "|-", color=style["color"], lw=3, alpha=0.5,
                        label=f"{route}: median, {100 * frag.attrs['confidence']:g} % bootstrap")
        if notes:
            ax.text(0.02, 0.98, "\n".join(notes), transform=ax.transAxes, va="top", fontsize="small")
        ax.set_ylim(-0.03, 1.03)
        ax.set_xlim(0, x[-1])
        ax.set_xlabel("PGA (g)")
        ax.set_ylabel("P(exceed | PGA) (-)")
        ax.set_title(_limit_title(lim, str(frag["units"].values[a]) if "units" in frag else ""))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    if title:
        fig.suptitle(title)
    return fig


def _limit_title(text: str, units: str) -> str:
    """A panel's title: the limit ``text``, with the file's ``units`` when it names none."""
    try:
        named = parse_limit(text).unit
    except FragilityError:
        named = ""
    if named or not units:
        return text
    return f"{text} ({'fraction' if units == '1' else units})"
