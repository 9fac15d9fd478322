"""Design floor spectra from ensembles: the fractile floor spectra of several ensemble files (one
per soil case: ``uplift ensemble SCENE --case NAME``) broadened in frequency about their peaks
and enveloped over the files (``uplift envelope``; docs/design_basis.md).

The rule is that of a single run (orchestrator.design_spectra): at each frequency f the
broadened spectrum is the maximum of the fractile spectrum over [f/(1 + r), f/(1 - r)]; the
envelope is the maximum over the files (cases) at each frequency, per PGA, route, node and
direction. The fractile is over the converged records of each PGA (the ensemble's
``floor_spectrum_fractile``, 5 % damping, at the ensemble's frequencies).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from orchestrator.design_spectra import broadened, envelope
from orchestrator.motion import G
from uplift_common.files import atomic_output

from .dataset import QUANTILES
from .plan import EnsembleError

#: the coordinates every file of an envelope must share
SHARED = ("pga", "route", "node", "direction", "frequency")


def fractile_design_spectra(datasets: dict, quantile: float = 0.84, ratio: float = 0.15) -> dict:
    """{"cases", "pga", "route", "node", "direction", "frequency", "quantile", "broadening", "raw",
    "broadened" (case, pga, route, node, direction, frequency) m/s², "envelope" (pga, route, node,
    direction, frequency) m/s²} of ``datasets`` = {case: ensemble Dataset}; the files must share
    their PGAs, routes, nodes, directions and frequencies (EnsembleError names the first that
    differs)."""
    if not datasets:
        raise EnsembleError("an envelope needs at least one ensemble file")
    if not any(abs(quantile - q) < 1e-12 for q in QUANTILES):
        raise EnsembleError(f"--quantile {quantile:g}: the ensembles keep the fractiles {', '.join(map(str, QUANTILES))}")
    names = list(datasets)
    first = datasets[names[0]]
    for name in names[1:]:
        for coord in SHARED:
            a, b = first[coord].values, datasets[name][coord].values
            if a.shape != b.shape or not np.array_equal(a, b):
                raise EnsembleError(f"ensembles {names[0]!r} and {name!r} differ in their {coord} ({list(a)} and "
                                    f"{list(b)}): run every case with the same --pga, routes and scene outputs")
    raw = np.stack([datasets[n]["floor_spectrum_fractile"].sel(quantile=quantile, method="nearest")
                    .transpose("pga", "route", "node", "direction", "frequency").values for n in names])
    freqs = first["frequency"].values
    wide = broadened(freqs, raw, ratio)
    out = {"cases": names, "quantile": quantile, "broadening": ratio, "raw": raw, "broadened": wide,
           "envelope": envelope(wide, axis=0)}
    out.update({c: [v.item() if hasattr(v, "item") else v for v in first[c].values] for c in SHARED})
    out["frequency"] = freqs
    return out


def write_fractile_tables(design: dict, folder) -> list:
    """One CSV per PGA, route, node and direction in ``folder``
    (``ens_<pga>g_<route>_<node>_<direction>_p<quantile x 100>.csv``): frequency (Hz), envelope (g),
    then each case's broadened and raw fractile spectrum (g); NaN-only spectra are left out."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    q = design["quantile"]
    for a, pga in enumerate(design["pga"]):
        for r, route in enumerate(design["route"]):
            for i, node in enumerate(design["node"]):
                for j, d in enumerate(design["direction"]):
                    env = design["envelope"][a, r, i, j]
                    if not np.isfinite(env).any():
                        continue
                    cols, header = [design["frequency"], env / G], ["frequency_hz", "envelope_g"]
                    for c, case in enumerate(design["cases"]):
                        cols += [design["broadened"][c, a, r, i, j] / G, design["raw"][c, a, r, i, j] / G]
                        header += [f"{case}_broadened_g", f"{case}_raw_g"]
                    notes = [f"{100 * q:g}th-percentile floor response spectrum over the records, 5 % damping, PGA "
                             f"{pga:g} g, route {route}, node {node}, direction {d}",
                             f"pseudo-acceleration in g; broadened +-{100 * design['broadening']:g} % in frequency "
                             "(at f: max over [f/(1+r), f/(1-r)]), enveloped over " + ", ".join(design["cases"])]
                    path = folder / f"ens_{pga:g}g_{route}_{node}_{d}_p{100 * q:g}.csv"
                    with atomic_output(path) as tmp:
                        np.savetxt(tmp, np.column_stack(cols), delimiter=",", fmt="%.6e",
                                   header="\n".join(notes + [",".join(header)]), comments="# ")
                    paths.append(path)
    return paths
