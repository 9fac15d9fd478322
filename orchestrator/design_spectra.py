"""In-structure (floor) response spectra for design: computed at the damping values asked,
broadened in frequency about their peaks, enveloped over soil cases (and routes), exported as
tables ([output] design_spectra; docs/design_basis.md).

Rule (ASCE 4-16 §6.2.3, US NRC RG 1.122): the raw spectrum of each case is broadened by ±r
(r = ``broadening``, default 0.15) in frequency: every ordinate S(f_k) is spread over
[f_k (1 - r), f_k (1 + r)], i.e. at each frequency f the broadened spectrum is the maximum of
the raw one over [f / (1 + r), f / (1 - r)] (``orchestrator.spectra.broaden``, on the
spectrum's frequency grid). A spectrum with one narrow peak at f0 thus has the peak's value
over [f0 (1 - r), f0 (1 + r)], and the broadened spectrum is never below the raw one. The design
spectrum is the envelope (the maximum at each frequency) of the broadened spectra of every soil
case, per route, and over the routes too when ``envelope_routes`` is true.

Spectra are 5 %-style pseudo-accelerations ω² max|u| of a unit oscillator driven by the
absolute floor acceleration (orchestrator.spectra, Nigam-Jennings), over a log-spaced grid
(``range_hz``), in m/s² in the results file and in g in the CSV tables.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from orchestrator.motion import G
from orchestrator.spectra import broaden, excited, response_spectra
from structure.spec import check_keys, check_number, show
from uplift_common.errors import UserInputError
from uplift_common.files import atomic_output


class SpectraConfigError(UserInputError):
    """An invalid [output] design_spectra table; the message names the key and the fix."""


_keys = partial(check_keys, error=SpectraConfigError)
_number = partial(check_number, error=SpectraConfigError)

BROADENING = 0.15
DAMPING = (0.02, 0.05)
RANGE_HZ = (0.2, 50.0, 200)
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class DesignSpectraConfig:
    """[output] design_spectra: nodes (None: the scene's output nodes), directions (None: x, y and
    z, each where the floor moves above round-off: rocking makes vertical floor motion under a
    horizontal shake), damping (ratios), broadening (r, the relative half-width),
    frequencies_hz (log-spaced from range_hz = [first, last, count]), envelope_routes (also the
    envelope over routes), routes (the routes that enter; None: every route with floor histories)."""

    nodes: tuple | None = None
    directions: tuple | None = None
    damping: tuple = DAMPING
    broadening: float = BROADENING
    range_hz: tuple = RANGE_HZ
    envelope_routes: bool = False
    routes: tuple | None = None

    @property
    def frequencies_hz(self) -> np.ndarray:
        first, last, count = self.range_hz
        return np.geomspace(first, last, count)


def parse_design_spectra(table) -> DesignSpectraConfig:
    """[output] design_spectra = { nodes, directions, damping, broadening, range_hz, envelope_routes,
    routes }: every key optional (``true`` alone is every default)."""
    where = "output.design_spectra"
    if table is True:
        return DesignSpectraConfig()
    _keys(table, ("nodes", "directions", "damping", "broadening", "range_hz", "envelope_routes", "routes"), where)
    kw = {}
    for key in ("nodes", "routes", "directions"):
        if key in table:
            v = table[key]
            if not isinstance(v, list) or not v or not all(isinstance(x, str) and x for x in v) or len(set(v)) < len(v):
                raise SpectraConfigError(f"{where}.{key} = {show(v)} must be a non-empty list of distinct names")
            kw[key] = tuple(v)
    if "directions" in kw and not set(kw["directions"]) <= set(AXES):
        raise SpectraConfigError(f"{where}.directions = {show(table['directions'])}: use axes among \"x\", \"y\", \"z\"")
    if "damping" in table:
        d = table["damping"]
        if not isinstance(d, list) or not d:
            raise SpectraConfigError(f"{where}.damping = {show(d)} must be a list of damping ratios, e.g. [0.02, 0.05]")
        kw["damping"] = tuple(float(_number(f"{where}.damping[{i}]", x, 0.0, 0.5, hi_open=True,
                                            expect="a damping ratio in (0, 0.5), e.g. 0.05")) for i, x in enumerate(d))
    if "broadening" in table:
        kw["broadening"] = float(_number(f"{where}.broadening", table["broadening"], 0.0, 0.5, lo_open=False,
                                         hi_open=True, expect="a relative half-width in [0, 0.5), e.g. 0.15"))
    if "range_hz" in table:
        r = table["range_hz"]
        if not isinstance(r, list) or len(r) != 3:
            raise SpectraConfigError(f"{where}.range_hz = {show(r)} must be [first (Hz), last (Hz), count]")
        first = float(_number(f"{where}.range_hz[0]", r[0], 0.0, expect="a frequency > 0 Hz"))
        last = float(_number(f"{where}.range_hz[1]", r[1], first, expect=f"a frequency > {first:g} Hz"))
        count = int(_number(f"{where}.range_hz[2]", r[2], 10, 2000, lo_open=False, integer=True,
                            expect="an integer count in [10, 2000]"))
        kw["range_hz"] = (first, last, count)
    if "envelope_routes" in table:
        if not isinstance(table["envelope_routes"], bool):
            raise SpectraConfigError(f"{where}.envelope_routes = {show(table['envelope_routes'])} must be true or false")
        kw["envelope_routes"] = table["envelope_routes"]
    return DesignSpectraConfig(**kw)


@dataclass(frozen=True)
class DesignSpectra:
    """Floor spectra for design, m/s². raw, broadened : (case, route, node, direction, damping,
    frequency); envelope : (route, node, direction, damping, frequency), the maximum of
    ``broadened`` over cases (route "all": over cases and routes, when asked). NaN: a direction
    the motion leaves at round-off, or a route without that node."""

    cases: tuple
    routes: tuple
    nodes: tuple
    directions: tuple
    damping: tuple
    frequencies_hz: np.ndarray
    broadening: float
    raw: np.ndarray
    broadened: np.ndarray
    envelope_routes: tuple
    envelope: np.ndarray


def raw_spectra(acc: dict, dt: float, nodes, directions, damping, frequencies_hz) -> np.ndarray:
    """(node, direction, damping, frequency) pseudo-accelerations, m/s², of the histories
    ``acc`` {node: (nt, 3) m/s²}; NaN for a node missing or a direction at round-off."""
    out = np.full((len(nodes), len(directions), len(damping), len(frequencies_hz)), np.nan)
    which, cols = [], []
    for i, node in enumerate(nodes):
        a = acc.get(node)
        if a is None or np.shape(a)[0] < 2:
            continue
        live = excited(a)
        for j, d in enumerate(directions):
            if live[AXES.index(d)]:
                which.append((i, j))
                cols.append(np.asarray(a)[:, AXES.index(d)])
    if cols:
        stack = np.stack(cols, axis=1)
        for k, zeta in enumerate(damping):
            for (i, j), sp in zip(which, response_spectra(stack, dt, 1.0 / np.asarray(frequencies_hz), zeta)):
                out[i, j, k] = sp.psa
    return out


def broadened(frequencies_hz, spectra, ratio: float) -> np.ndarray:
    """``spectra`` (..., frequency) broadened by ±ratio (``orchestrator.spectra.broaden``) along its
    last axis; all-NaN rows stay NaN."""
    spectra = np.asarray(spectra, float)
    flat = spectra.reshape(-1, spectra.shape[-1])
    res = np.full(flat.shape, np.nan)               # its own C-ordered array (a reshape of a strided one is a copy)
    for k, row in enumerate(flat):
        if np.isfinite(row).all():
            res[k] = broaden(frequencies_hz, row, ratio)
    return res.reshape(spectra.shape)


def envelope(spectra, axis=0) -> np.ndarray:
    """The maximum over ``axis`` ignoring NaN (NaN where every one is NaN)."""
    return np.fmax.reduce(np.asarray(spectra, float), axis=axis)


def design_spectra(cases: dict, config: DesignSpectraConfig, default_nodes, axes=AXES) -> DesignSpectra:
    """The design spectra of ``cases`` = {case: {route: RouteResult}}: per case and route the raw
    spectra of ``config``'s nodes (default ``default_nodes``: None, every node of the results)
    and directions (default ``axes``), broadened, and their envelope over cases per route (and
    over routes, "all"); a direction at round-off in every case and route is left out."""
    names = list(cases)
    routes = tuple(config.routes) if config.routes is not None else \
        tuple(dict.fromkeys(r for c in cases.values() for r, res in c.items() if res.acc and res.nt > 1))
    nodes = tuple(config.nodes or default_nodes
                  or dict.fromkeys(n for c in cases.values() for res in c.values() for n in res.acc))
    directions = tuple(config.directions or axes)
    f = config.frequencies_hz
    raw = np.full((len(names), len(routes), len(nodes), len(directions), len(config.damping), f.size), np.nan)
    for c, case in enumerate(names):
        for r, route in enumerate(routes):
            res = cases[case].get(route)
            if res is None or not res.acc or res.nt < 2:
                continue
            raw[c, r] = raw_spectra(res.acc, float(res.time[1] - res.time[0]), nodes, directions,
                                    config.damping, f)
    if config.directions is None:                                   # keep the directions that move
        live = [j for j in range(len(directions)) if np.isfinite(raw[:, :, :, j]).any()]
        raw, directions = raw[:, :, :, live], tuple(directions[j] for j in live)
    wide = broadened(f, raw, config.broadening)
    env = envelope(wide, axis=0)                                     # over cases: (route, ...)
    env_routes = routes
    if config.envelope_routes and routes:
        env = np.concatenate([env, envelope(env, axis=0)[None]], axis=0)
        env_routes = routes + ("all",)
    return DesignSpectra(cases=tuple(names), routes=routes, nodes=nodes, directions=directions,
                         damping=tuple(config.damping), frequencies_hz=f, broadening=config.broadening,
                         raw=raw, broadened=wide, envelope_routes=env_routes, envelope=env)


def table_name(route: str, node: str, direction: str, damping: float) -> str:
    """File name of one table: ``fs_<route>_<node>_<direction>_<damping in %>pct.csv``."""
    return f"fs_{route}_{node}_{direction}_{100 * damping:g}pct.csv"


def write_tables(ds: DesignSpectra, folder) -> list:
    """One CSV table per envelope route, node, direction and damping in ``folder``: frequency (Hz),
    the design envelope (g), then each case's broadened and raw spectrum (g); rows of NaN-only
    spectra are left out. Returns the paths written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for r, route in enumerate(ds.envelope_routes):
        for i, node in enumerate(ds.nodes):
            for j, d in enumerate(ds.directions):
                for k, zeta in enumerate(ds.damping):
                    env = ds.envelope[r, i, j, k]
                    if not np.isfinite(env).any():
                        continue
                    cols, header = [ds.frequencies_hz, env / G], ["frequency_hz", "envelope_g"]
                    if route != "all":
                        for c, case in enumerate(ds.cases):
                            cols += [ds.broadened[c, r, i, j, k] / G, ds.raw[c, r, i, j, k] / G]
                            header += [f"{case}_broadened_g", f"{case}_raw_g"]
                    over = "cases and routes" if route == "all" else "cases"
                    notes = [f"floor response spectrum for design: node {node}, direction {d}, damping "
                             f"{100 * zeta:g} %, route {route}",
                             f"pseudo-acceleration in g; broadened +-{100 * ds.broadening:g} % in frequency "
                             "(at f: max of the raw spectrum over [f/(1+r), f/(1-r)]), enveloped over "
                             f"{over} ({', '.join(ds.cases)})"]
                    path = folder / table_name(route, node, d, zeta)
                    with atomic_output(path) as tmp:
                        np.savetxt(tmp, np.column_stack(cols), delimiter=",", fmt="%.6e",
                                   header="\n".join(notes + [",".join(header)]), comments="# ")
                    paths.append(path)
    return paths


def plot_design_spectra(ds: DesignSpectra, folder) -> list:
    """One figure per node and direction (``design_<node>_<direction>.png``), one panel per damping:
    the raw spectra of each case (thin, one line style per case) and the design envelope of each
    route (thick; black: the envelope over the routes too, when asked). Returns the paths written."""
    from orchestrator.plots import pyplot          # matplotlib: only when figures are drawn
    plt = pyplot()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    styles = ("-", "--", ":", "-.")
    paths = []
    for i, node in enumerate(ds.nodes):
        for j, d in enumerate(ds.directions):
            if not np.isfinite(ds.envelope[:, i, j]).any():
                continue
            fig, axes = plt.subplots(1, len(ds.damping), figsize=(5.5 * len(ds.damping), 4.5), squeeze=False,
                                     sharey=True)
            for k, (ax, zeta) in enumerate(zip(axes[0], ds.damping)):
                for r, route in enumerate(ds.envelope_routes):
                    if route == "all":
                        ax.plot(ds.frequencies_hz, ds.envelope[r, i, j, k] / G, color="k", lw=2.6,
                                label="design envelope, all routes")
                        continue
                    for c, case in enumerate(ds.cases):
                        ax.plot(ds.frequencies_hz, ds.raw[c, r, i, j, k] / G, color=f"C{r}", lw=0.8,
                                ls=styles[c % len(styles)], alpha=0.8, label=f"{route} {case} raw")
                    ax.plot(ds.frequencies_hz, ds.envelope[r, i, j, k] / G, color=f"C{r}", lw=1.8,
                            label=f"{route} design envelope")
                ax.set_xscale("log")
                ax.set_xlabel("frequency (Hz)")
                ax.set_title(f"damping {100 * zeta:g} %")
                ax.grid(True, which="both", alpha=0.3)
            axes[0, 0].set_ylabel("pseudo-acceleration (g)")
            axes[0, -1].legend(fontsize=7, loc="upper right")
            fig.suptitle(f"{node}, {d}: floor spectra broadened ±{100 * ds.broadening:g} %, enveloped over "
                         f"{', '.join(ds.cases)}")
            fig.tight_layout()
            path = folder / f"design_{node}_{d}.png"
            with atomic_output(path) as tmp:
                fig.savefig(tmp, dpi=100, format="png")
            plt.close(fig)
            paths.append(path)
    return paths
