"""Figures for reports (matplotlib, Agg backend, imported lazily by the CLI)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from uplift_common.files import atomic_folder, save_figure

from orchestrator.motion import G
from orchestrator.results_file import contact_pressure, patch_polygons, peak_uplift_step
from orchestrator.spectra import FLOOR_DAMPING, FLOOR_FREQUENCIES_HZ, excited, floor_spectra, response_spectrum

RIGID_GROUPS = (("ux", "horizontal"), ("uz", "vertical"), ("rx", "rocking"), ("rz", "torsion"))
#: units of the static stiffness K0 of each rigid DOF
K0_UNITS = {"ux": "N/m", "uy": "N/m", "uz": "N/m", "rx": "N·m/rad", "ry": "N·m/rad", "rz": "N·m/rad"}
#: what tells the routes (or series) of one panel apart besides colour: the k-th gets the k-th
#: marker and line style (cycled), and DODGE x its index about the middle as a relative x offset
MARKERS = ("o", "s", "^", "D", "v", "P", "X")
LINESTYLES = ("-", "--", "-.", ":")
DODGE = 0.012


def route_style(k: int) -> dict:
    """The colour, marker and line style of the k-th route of a figure (matplotlib keywords)."""
    return {"color": f"C{k}", "marker": MARKERS[k % len(MARKERS)], "linestyle": LINESTYLES[k % len(LINESTYLES)]}


def dodged(x, k: int, n: int):
    """``x`` (>= 0, e.g. PGAs in g) moved by (k - (n - 1) / 2) DODGE x its span, so that the
    points of n routes at the same x are side by side rather than on top of each other."""
    x = np.asarray(x, float)
    span = float(x.max() - x.min()) if x.size > 1 else float(abs(x).max(initial=1.0))
    return x + (k - (n - 1) / 2) * DODGE * (span or 1.0)


def pyplot():
    """matplotlib.pyplot on the Agg backend (imported on first use: it costs ~0.5 s at start-up)."""
    import matplotlib  # start-up cost (~0.5 s): only the commands that draw pay it
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # (same)
    return plt


def impedance_coefficients(table, static, radius: float, vs: float):
    """Dimensionless coefficients of K = K_static (k(a0) + i a0 c(a0)), a0 = ωR/Vs.

    Parameters
    ----------
    table : ImpedanceTable with rigid DOFs
    static : ndarray, shape (6, 6)   K(ω = 0)
    Returns a0 (F,), k (F, 6), c (F, 6) for the diagonal terms (c is NaN at a0 = 0).
    """
    a0 = 2 * np.pi * np.asarray(table.frequencies_hz) * radius / vs
    diag = np.diagonal(table.matrices, axis1=1, axis2=2)
    k_stat = np.real(np.diagonal(static))
    k = diag.real / k_stat
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(a0[:, None] > 0, diag.imag / (a0[:, None] * k_stat), np.nan)
    return a0, k, c


def plot_impedance(table, scene, path: Path, static=None):
    """Write ``impedance_figure`` to ``path`` (PNG); returns ``path``."""
    plt = pyplot()
    fig = impedance_figure(table, scene, static)
    save_figure(fig, path, dpi=130)
    plt.close(fig)
    return path


def impedance_figure(table, scene, static=None):
    """k(a0) and c(a0) (dimensionless) for each rigid DOF (horizontal, vertical, rocking,
    torsion), K0 = Re K(0) (N/m or N·m/rad) in each title. ``static``: K(0) (6, 6), default the
    table's 0 Hz entry. A Figure (the caller closes it)."""
    plt = pyplot()
    if static is None:
        if table.frequencies_hz[0] != 0.0:
            raise ValueError("the impedance plot needs K(0): include 0 Hz in the scene's frequencies")
        static = table.matrices[0]
    vs = scene.profile.top.vs
    a0, k, c = impedance_coefficients(table, static, scene.mesh.radius, vs)
    fig, axes = plt.subplots(2, 4, figsize=(13, 6), sharex=True, constrained_layout=True)
    for col, (dof, label) in enumerate(RIGID_GROUPS):
        j = table.dofs.index(dof)
        axes[0, col].plot(a0, k[:, j], "o-", ms=3)
        axes[0, col].set_title(f"{label} ({dof})\nK0 = {np.real(static[j, j]):.3e} {K0_UNITS[dof]}")
        axes[1, col].plot(a0, c[:, j], "o-", ms=3, color="C1")
        axes[1, col].set_xlabel(r"$a_0 = \omega R / V_s$ (-)")
        for ax in axes[:, col]:
            ax.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel(r"$k(a_0) = \mathrm{Re}\,K / K_0$ (-)")
    axes[1, 0].set_ylabel(r"$c(a_0) = \mathrm{Im}\,K / (a_0 K_0)$ (-)")
    fig.suptitle(f"{scene.name}: rigid-raft impedance, R = {scene.mesh.radius:g} m, "
                 f"Vs = {vs:g} m/s, {scene.mesh.n} nodes, {scene.contact_kind}")
    return fig


def _edges(xy, axis: int = 0):
    """Indices of the interface nodes at the raft edges along ``axis`` (0: x, 1: y): min and max
    of that coordinate on the line through the centre (the other coordinate ≈ 0)."""
    other = np.abs(xy[:, 1 - axis])
    idx = np.flatnonzero(other <= other.min() + 1e-9)
    return idx[np.argmin(xy[idx, axis])], idx[np.argmax(xy[idx, axis])]


def plot_run(results: dict, motion, scene, directory) -> list:
    """Write the figures of ``run_figures`` and the uplift map (``uplift_map_figure``, on the
    scene's interface mesh) as ``<directory>/<name>.png``; returns the paths."""
    plt = pyplot()
    directory = Path(directory)
    paths = []
    source = scene.mesh_source.as_dict() if scene.mesh_source is not None else None
    figures = list(run_figures(results, motion, scene.name))
    figures += uplift_map_figures(results, patch_polygons(scene.mesh), scene.name, source)
    with atomic_folder(directory) as stage:          # every figure, or none (the old ones)
        for name, fig in figures:
            paths.append(directory / f"{name}.png")
            save_figure(fig, stage / paths[-1].name, dpi=120)
            plt.close(fig)
    return paths


def _edge_nodes(xy):
    """[(label, node index)] of the raft edges along x and y (see ``_edges``)."""
    (xm, xp), (ym, yp) = _edges(xy, 0), _edges(xy, 1)
    return [(f"edge x- ({xy[xm, 0]:.1f} m)", xm), (f"edge x+ ({xy[xp, 0]:.1f} m)", xp),
            (f"edge y- ({xy[ym, 1]:.1f} m)", ym), (f"edge y+ ({xy[yp, 1]:.1f} m)", yp)]


def _raft_figure(plt, res, lin):
    """Uplift at the four raft edges, the raft's vertical response (edges and centre), its
    rocking about x and y and the rocking magnitude sqrt(rx² + ry²); ``lin`` dashed."""
    t = res.time
    fig, axes = plt.subplots(4, 1, figsize=(10, 12), sharex=True, constrained_layout=True)
    trace = lambda r, x, y: r.raft[:, 2] + r.raft[:, 3] * y - r.raft[:, 4] * x
    for label, i in _edge_nodes(res.xy):
        axes[0].plot(t, 1e3 * res.gap[:, i], label=label)
        x, y = res.xy[i]
        line, = axes[1].plot(t, 1e3 * trace(res, x, y), label=label.split(" (")[0], lw=0.9)
        if lin is not None:
            axes[1].plot(lin.time, 1e3 * trace(lin, x, y), "--", color=line.get_color(), lw=0.6)
    axes[1].plot(t, 1e3 * res.raft[:, 2], "k", lw=1.2, label="centre uz")
    if lin is not None:
        axes[1].plot(lin.time, 1e3 * lin.raft[:, 2], "k--", lw=0.8, label="centre uz, no uplift")
    axes[2].plot(t, 1e3 * res.raft[:, 3], label="rx (about x)")
    axes[2].plot(t, 1e3 * res.raft[:, 4], label="ry (about y)")
    axes[3].plot(t, 1e3 * np.hypot(res.raft[:, 3], res.raft[:, 4]), "k", label="sqrt(rx² + ry²)")
    if lin is not None:
        axes[3].plot(lin.time, 1e3 * np.hypot(lin.raft[:, 3], lin.raft[:, 4]), "k--", lw=0.8, label="no uplift")
    for ax, ylabel in zip(axes, ("uplift (mm)", "raft vertical displacement (mm)", "raft rotation (mrad)",
                                 "rocking magnitude (mrad)")):
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    axes[-1].set_xlabel("time (s)")
    return fig


def excited_directions(res, motion) -> list:
    """The directions ("x", "y", "z") with a floor spectrum to draw: an output node of ``res``
    above round-off in it (``orchestrator.spectra.excited``), or a component of ``motion``."""
    hit = np.zeros(3, bool)
    for acc in res.acc.values():
        hit |= excited(acc)
    return [d for j, d in enumerate("xyz") if hit[j] or (motion is not None and d in motion.components)]


def _spectra_figure(plt, res, lin, motion):
    """5 %-damped floor response spectra at the output nodes (``floor_spectra``: those of the
    results file), one panel per excited direction (``excited_directions``; a direction with
    round-off response only is left out, and named so in the figure's note), the ground's
    spectrum per component of ``motion``; ``lin`` dashed. None when no direction is excited.
    Returns (Figure, note)."""
    directions = excited_directions(res, motion)
    if not directions:
        return None, ""
    f = FLOOR_FREQUENCIES_HZ
    spectra = floor_spectra(res.acc, float(res.time[1] - res.time[0]))
    ref = floor_spectra(lin.acc, float(lin.time[1] - lin.time[0])) if lin is not None else None
    names = list(res.acc)
    fig, axes = plt.subplots(1, len(directions), figsize=(5 * len(directions), 5), sharey=True, squeeze=False,
                             constrained_layout=True)
    for ax, d in zip(axes[0], directions):
        j = "xyz".index(d)
        for i, name in enumerate(names):
            if not np.isfinite(spectra[i, j]).any():
                continue
            line, = ax.semilogx(f, spectra[i, j] / G, label=name)
            if ref is not None and name in lin.acc and np.isfinite(ref[list(lin.acc).index(name), j]).any():
                ax.semilogx(f, ref[list(lin.acc).index(name), j] / G, "--", color=line.get_color(), lw=0.8,
                            label=f"{name}, no uplift")
        if motion is not None and d in motion.components:
            ground = response_spectrum(motion.acc[: res.nt, j], motion.dt, 1 / f, FLOOR_DAMPING)
            ax.semilogx(f, ground.psa / G, "k--", label="ground")
        ax.set_title(f"{d} ({'vertical' if d == 'z' else 'horizontal'})")
        ax.set_xlabel("frequency (Hz)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="small")
    axes[0, 0].set_ylabel(f"pseudo-acceleration, {100 * FLOOR_DAMPING:g} % (g)")
    left = [d for d in "xyz" if d not in directions]
    return fig, (f"; not drawn: {', '.join(left)} (no response above round-off)" if left else "")


def run_figures(results: dict, motion, scene_name: str):
    """Figures of the paper's kind for each route, yielded as (name, matplotlib Figure): uplift
    at the raft edges along x and y (fig. 3-4), the raft's vertical response and its rocking
    about both axes (``<route>_raft``), floor response spectra at the output nodes in x, y and
    z (fig. 5-6, ``<route>_floor_spectra``: one panel per excited direction, the others named in
    the title; no figure when none is excited). When the ``linear`` route (no uplift) is among the
    results, it is drawn dashed on the other routes' figures: the paper's "with and without
    uplift" comparison. ``motion`` (may be None) names the components and adds the ground
    spectra. Routes without histories (refused) have no figures. The caller closes each figure."""
    plt = pyplot()
    label = motion.label if motion is not None else ""
    linear = results.get("linear")
    if linear is not None and linear.nt < 2:
        linear = None
    for route, res in results.items():
        if res.nt < 2 or res.xy is None:          # refused, or stopped before its second sample: nothing to draw
            continue
        lin = linear if linear is not None and route != "linear" else None
        fig = _raft_figure(plt, res, lin)
        fig.suptitle(f"{scene_name} [{route}]: raft response, {label}")
        yield f"{route}_raft", fig
        fig, note = _spectra_figure(plt, res, lin, motion) if res.acc else (None, "")
        if fig is not None:
            fig.suptitle(f"{scene_name} [{route}]: floor response spectra, {label}{note}")
            yield f"{route}_floor_spectra", fig


def uplift_map_figures(results: dict, polygons, scene_name: str, mesh_source=None):
    """[("raft_uplift", Figure)]: the raft's interface mesh (its cells, or the square patches of
    a grid) coloured by the uplift (gap, mm) of each patch at the instant of the route's peak
    uplift (patches in contact grey), one panel per route that has histories (the linear route,
    which never lifts, left out when another route is there), one colour scale and bar for all,
    the raft centre marked.
    ``polygons`` (N, 4, 2) m about the raft centre (``results_file.patch_polygons``);
    ``mesh_source``: a mesh file's provenance (its centre in the file's coordinates is named).
    Empty when no route has histories on N nodes. The caller closes the figure."""
    from matplotlib.collections import PolyCollection  # with pyplot: only the commands that draw pay it
    polygons = np.asarray(polygons, float)
    runs = {r: res for r, res in results.items() if res.nt >= 1 and res.gap.shape[1:] == (polygons.shape[0],)}
    if len(runs) > 1:
        runs.pop("linear", None)
    if not runs:
        return []
    plt = pyplot()
    peaks = {r: int(np.argmax(res.gap.max(axis=1))) for r, res in runs.items()}
    top = max(1e3 * float(res.gap[peaks[r]].max()) for r, res in runs.items())
    vmax = top if top > 0 else 1.0
    n = len(runs)
    cols = min(n, 2)
    rows = -(-n // cols)
    span = np.ptp(polygons.reshape(-1, 2), axis=0)
    aspect = float(span[1] / span[0]) if span[0] > 0 else 1.0
    width = 5.2 * cols + 1.2
    fig, axes = plt.subplots(rows, cols, figsize=(width, 5.2 * rows * min(max(aspect, 0.5), 1.5) + 0.6),
                             squeeze=False, constrained_layout=True)
    cmap = plt.get_cmap("viridis").with_extremes(bad="0.85")   # patches in contact (no gap): light grey
    for ax, (route, res) in zip(axes.flat, runs.items()):
        k = peaks[route]
        gap = 1e3 * res.gap[k]
        coll = PolyCollection(polygons, array=np.ma.masked_less_equal(gap, 0.0), cmap=cmap, edgecolors="0.35",
                              linewidths=0.4)
        coll.set_clim(0.0, vmax)
        ax.add_collection(coll)
        ax.plot([0.0], [0.0], marker="+", color="red", ms=14, mew=2.0, ls="none", label="raft centre")
        lo, hi = polygons.reshape(-1, 2).min(axis=0), polygons.reshape(-1, 2).max(axis=0)
        pad = 0.04 * float(max(hi - lo))
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal")
        ax.set_xlabel("x about the raft centre (m)")
        ax.set_ylabel("y about the raft centre (m)")
        lifted = 100 * float((res.gap[k] > 0).mean())
        ax.set_title(f"{route}: t = {res.time[k]:.3f} s, max uplift {gap.max():.3g} mm, "
                     f"{lifted:.0f} % of the patches lifted", fontsize="medium")
        ax.legend(loc="upper right", fontsize="small")
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    bar = fig.colorbar(coll, ax=axes.ravel().tolist(), shrink=0.9)
    bar.set_label("uplift: gap between raft and soil (mm); grey: in contact")
    where = f"{polygons.shape[0]} patches"
    if mesh_source is not None:
        c = mesh_source["centre"]
        where += f" of {Path(mesh_source['path']).name}, raft centre at ({c[0]:.4g}, {c[1]:.4g}) m in its coordinates"
    fig.suptitle(f"{scene_name}: uplift over the raft at the instant of peak uplift\n({where})")
    return [("raft_uplift", fig)]


def _held_outline(res):
    """(k, 2) m: the held region's outline (the convex hull of its vertices, closed), None when
    the result does not say which vertices are held."""
    if res.plate_vertex_held is None or res.plate_vertices is None or res.plate_vertex_held.sum() < 3:
        return None
    from scipy.spatial import ConvexHull  # scipy.spatial (~0.2 s): only a plate's report pays it
    p = res.plate_vertices[res.plate_vertex_held]
    hull = p[ConvexHull(p).vertices]
    return np.vstack([hull, hull[:1]])


def plate_map_figures(results: dict, polygons, area, scene_name: str):
    """[("<route>_plate_maps", Figure)] per route of a plate raft (its results carry the plate's
    vertices): the interface cells at the instant of the route's peak uplift coloured by the
    uplift (mm; in contact: grey) and by the compressive contact pressure (kPa; lifted: grey),
    each with its colour bar, the held region (the stick base) outlined, the raft centre marked,
    and, beside them, the peak bending moment envelope max(|Mx|, |My|) (kN m/m) over the run when
    the route gives it. ``polygons`` (N, 4, 2) m, ``area`` (N,) m² of the interface cells. The
    caller closes the figures."""
    from matplotlib.collections import PolyCollection  # with pyplot: only the commands that draw pay it
    polygons, area = np.asarray(polygons, float), np.asarray(area, float)
    out = []
    plt = None
    for route, res in results.items():
        if res.plate_vertices is None or res.nt < 1 or res.gap.shape[1:] != (polygons.shape[0],):
            continue
        plt = plt or pyplot()
        k = peak_uplift_step(res.gap)
        gap = 1e3 * res.gap[k]
        kpa = 1e-3 * contact_pressure(res.contact_force[k], area)
        panels = [("uplift: gap between raft and soil (mm)", np.ma.masked_less_equal(gap, 0.0), "viridis",
                   (0.0, max(float(gap.max()), 1e-9)), "grey: in contact"),
                  ("compressive contact pressure (kPa)", np.ma.masked_less_equal(kpa, 0.0), "magma_r",
                   (0.0, max(float(kpa.max()), 1e-9)), "grey: lifted")]
        if res.plate_moment_peak is not None:
            env = 1e-3 * np.abs(res.plate_moment_peak[:, :2]).max(axis=1)
            panels.append(("peak bending moment over the run, max(|Mx|, |My|) (kN·m/m)", env, "cividis",
                           (0.0, max(float(env.max()), 1e-9)), ""))
        lo, hi = polygons.reshape(-1, 2).min(axis=0), polygons.reshape(-1, 2).max(axis=0)
        span = hi - lo
        aspect = float(span[1] / span[0]) if span[0] > 0 else 1.0
        n = len(panels)
        fig, axes = plt.subplots(1, n, figsize=(5.0 * n, 4.6 * min(max(aspect, 0.5), 1.5) + 0.9),
                                 squeeze=False, constrained_layout=True)
        outline = _held_outline(res)
        for ax, (label, values, cmap, clim, grey) in zip(axes[0], panels):
            coll = PolyCollection(polygons, array=values, cmap=plt.get_cmap(cmap).with_extremes(bad="0.85"),
                                  edgecolors="0.35", linewidths=0.4)
            coll.set_clim(*clim)
            ax.add_collection(coll)
            if outline is not None:
                ax.plot(outline[:, 0], outline[:, 1], color="red", lw=1.8, label="held region (stick base)")
            ax.plot([0.0], [0.0], marker="+", color="red", ms=12, mew=2.0, ls="none", label="raft centre")
            pad = 0.04 * float(span.max())
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            ax.set_aspect("equal")
            ax.set_xlabel("x about the raft centre (m)")
            ax.set_ylabel("y about the raft centre (m)")
            ax.legend(loc="upper right", fontsize="x-small")
            bar = fig.colorbar(coll, ax=ax, shrink=0.85, location="bottom")
            bar.set_label(label + (f"; {grey}" if grey else ""), fontsize="small")
        lifted = 100 * float((res.gap[k] > 0).mean())
        fig.suptitle(f"{scene_name} [{route}]: plate raft at the instant of peak uplift, t = {res.time[k]:.3f} s "
                     f"(max uplift {gap.max():.3g} mm, {lifted:.0f} % of the cells lifted, peak pressure "
                     f"{kpa.max():.4g} kPa)")
        out.append((f"{route}_plate_maps", fig))
    return out
