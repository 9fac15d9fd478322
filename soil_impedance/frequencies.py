"""Fewer frequencies where the impedance is smooth: a sweep over a subset of a frequency grid, refined
where a held-out frequency shows the interpolation missing ``tol``, never silent.

``thinned_sweep`` sweeps every ``step``-th frequency of the grid (and the last), then, in each interval
of swept frequencies with grid frequencies inside, the middle one: the held-out frequency, swept by the
BEM and compared with the cubic-spline interpolation (``ImpedanceTable.at``) of the frequencies swept
before it. An interval whose held-out error (relative Frobenius norm of the whole matrix, the largest
over the outputs) is within ``tol`` is accepted: its other grid frequencies are interpolated. Otherwise
it is split at the held-out frequency and each half is tested the same way, until every interval is
accepted or every grid frequency is swept. The error reported is the largest held-out error of the
accepted intervals, measured against the coarser interpolation (before the held-out frequency joined
it): an upper estimate of the final interpolation's error, measured, not guessed.

The result is either the tables on the whole grid (``"interpolated"``: the swept frequencies exact, the
others interpolated; what a route on the scene's grid needs) or on the swept frequencies only
(``"swept"``: what the rational fit can take directly). Either way the table's provenance records the
thinning (tol, step, the swept frequencies, the measured error and where), so its hash differs from the
full sweep's, and ``ThinReport.lines`` says it for the run notes.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uplift_common.errors import UserInputError

from .table import ImpedanceTable

MODES = ("interpolated", "swept")


class ThinningError(UserInputError):
    """An invalid frequency-thinning request."""


@dataclass
class ThinReport:
    """What a thinned sweep did: grid size, swept frequencies, the held-out errors (Hz -> error)."""

    n_grid: int
    swept_hz: list
    held_out: dict = field(default_factory=dict)       # Hz -> measured relative error
    accepted_error: float = 0.0                        # max held-out error of the accepted intervals
    accepted_at_hz: float | None = None
    tol: float = 0.0

    def to_dict(self) -> dict:
        return {"n_grid": self.n_grid, "n_swept": len(self.swept_hz), "swept_hz": [float(x) for x in self.swept_hz],
                "held_out": {f"{k:.6g}": float(v) for k, v in sorted(self.held_out.items())},
                "max_error": float(self.accepted_error), "max_error_at_hz": self.accepted_at_hz,
                "tol": float(self.tol)}

    def lines(self) -> list[str]:
        at = "" if self.accepted_at_hz is None else f" (at {self.accepted_at_hz:.3g} Hz)"
        return [f"impedance sweep thinned: {len(self.swept_hz)} of {self.n_grid} frequencies swept, "
                f"{len(self.held_out)} of them held out to measure the interpolation; measured interpolation "
                f"error {self.accepted_error:.2e}{at}, tol {self.tol:g} (relative Frobenius, whole matrix)"]


def _rel(a, b) -> float:
    den = np.linalg.norm(b)
    return float(np.linalg.norm(a - b) / (den if den > 0 else 1.0))


def thinned_sweep(sweep, frequencies_hz, tol: float, step: int = 4, mode: str = "interpolated"):
    """Tables over a thinned subset of ``frequencies_hz`` (module docstring).

    sweep : callable(frequencies_hz array) -> {output: ImpedanceTable}, e.g.
        ``lambda f: impedance_sweep(profile, mesh, f, contact, outputs, cache_dir)``: called once per
        refinement round with the frequencies new to that round (each call is its own cache entry)
    tol : largest relative Frobenius error of the interpolation accepted at a held-out frequency (e.g. 1e-3)
    step : the first pass sweeps every ``step``-th grid frequency (and the last)
    mode : "interpolated" (tables on the whole grid) or "swept" (tables on the swept frequencies)

    Returns ({output: ImpedanceTable}, ThinReport). The tables are in memory (a gap table of more than a
    few hundred nodes: sweep the whole grid, ``sweep.impedance_sweep`` streams it to disk).
    """
    f = np.asarray(frequencies_hz, float).reshape(-1)
    if not (isinstance(tol, (int, float)) and np.isfinite(tol) and tol > 0):
        raise ThinningError(f"frequency_tol = {tol!r} must be a positive number (relative error, e.g. 1e-3)")
    if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 2:
        raise ThinningError(f"thinning step = {step!r} must be an integer >= 2 (every step-th frequency first)")
    if mode not in MODES:
        raise ThinningError(f"thinning mode = {mode!r}: use one of {MODES}")
    n = f.size
    coarse = sorted(set(range(0, n, step)) | {n - 1})
    got: dict[int, dict] = {}                # grid index -> {output: (n, n) matrix}
    dofs, prov = {}, {}

    def run(idx):
        idx = sorted(i for i in set(idx) if i not in got)
        if not idx:
            return
        tables = sweep(f[idx])
        for o, t in tables.items():
            dofs[o], prov[o] = t.dofs, t.provenance
            for k, i in enumerate(idx):
                got.setdefault(i, {})[o] = np.array(t.matrices[k])

    report = ThinReport(n_grid=n, swept_hz=[], tol=float(tol))
    intervals = [(a, b) for a, b in zip(coarse[:-1], coarse[1:]) if b - a >= 2]
    run(coarse)
    while intervals:
        held = {(a, b): (a + b) // 2 for a, b in intervals}
        before = sorted(got)
        run(held.values())
        nxt = []
        for (a, b), h in held.items():
            err = 0.0
            for o in got[h]:
                base = ImpedanceTable(f[before], np.stack([got[i][o] for i in before]), dofs[o])
                err = max(err, _rel(base.at(f[h]), got[h][o]))
            report.held_out[float(f[h])] = err
            if err <= tol:
                if err >= report.accepted_error:
                    report.accepted_error, report.accepted_at_hz = err, float(f[h])
                continue
            nxt += [(lo, hi) for lo, hi in ((a, h), (h, b)) if hi - lo >= 2]
        intervals = nxt
    swept = sorted(got)
    report.swept_hz = [float(f[i]) for i in swept]
    note = dict(report.to_dict(), step=int(step), mode=mode)
    out = {}
    for o in dofs:
        K = np.stack([got[i][o] for i in swept])
        p = dict(prov[o], frequency_thinning=note)
        if mode == "swept" or len(swept) == n:
            out[o] = ImpedanceTable(f[swept], K, dofs[o], p)
        else:
            out[o] = ImpedanceTable(f, ImpedanceTable(f[swept], K, dofs[o]).at(f), dofs[o], p)
    return out, report
