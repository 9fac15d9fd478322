"""Figures for reports (matplotlib, Agg backend, imported lazily by the CLI)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from orchestrator.motion import G
from orchestrator.spectra import response_spectrum

RIGID_GROUPS = (("ux", "horizontal"), ("uz", "vertical"), ("rx", "rocking"), ("rz", "torsion"))


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
    """k(a0) and c(a0) for each rigid DOF (horizontal, vertical, rocking, torsion)."""
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
        axes[0, col].set_title(f"{label} ({dof}), K0 = {np.real(static[j, j]):.3e}")
        axes[1, col].plot(a0, c[:, j], "o-", ms=3, color="C1")
        axes[1, col].set_xlabel(r"$a_0 = \omega R / V_s$")
        for ax in axes[:, col]:
            ax.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel(r"$k(a_0) = \mathrm{Re}\,K / K_0$")
    axes[1, 0].set_ylabel(r"$c(a_0) = \mathrm{Im}\,K / (a_0 K_0)$")
    fig.suptitle(f"{scene.name}: rigid-raft impedance, R = {scene.mesh.radius:g} m, "
                 f"Vs = {vs:g} m/s, {scene.mesh.n} nodes, {scene.contact_kind}")
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def _edges(xy, axis: int = 0):
    """Indices of the interface nodes at the raft edges along ``axis`` (0: x, 1: y): min and max
    of that coordinate on the line through the centre (the other coordinate ≈ 0)."""
    other = np.abs(xy[:, 1 - axis])
    idx = np.flatnonzero(other <= other.min() + 1e-9)
    return idx[np.argmin(xy[idx, axis])], idx[np.argmax(xy[idx, axis])]


def plot_run(results: dict, motion, scene, directory) -> list:
    """Write the figures of ``run_figures`` as ``<directory>/<name>.png``; returns the paths."""
    plt = pyplot()
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, fig in run_figures(results, motion, scene.name):
        paths.append(directory / f"{name}.png")
        fig.savefig(paths[-1], dpi=120)
        plt.close(fig)
    return paths


#: a direction of a node whose floor acceleration stays below this share of the node's peak is
#: round-off (no spectrum drawn)
ROUNDOFF = 1e-6


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


def _spectra_figure(plt, res, lin, motion):
    """5 %-damped floor response spectra at the output nodes in x, y and z (round-off directions
    left out), the ground's spectrum per component of ``motion``; ``lin`` dashed."""
    f = np.geomspace(0.5, 40.0, 120)
    dt = res.time[1] - res.time[0]
    fig, axes = plt.subplots(1, 3, figsize=(15, 5), sharey=True, constrained_layout=True)
    for j, (ax, d) in enumerate(zip(axes, "xyz")):
        for name, acc in res.acc.items():
            if np.abs(acc[:, j]).max(initial=0.0) <= ROUNDOFF * np.abs(acc).max(initial=0.0):
                continue
            s = response_spectrum(acc[:, j], dt, 1 / f, 0.05)
            line, = ax.semilogx(f, s.psa / G, label=name)
            if lin is not None and name in lin.acc:
                s0 = response_spectrum(lin.acc[name][:, j], lin.time[1] - lin.time[0], 1 / f, 0.05)
                ax.semilogx(f, s0.psa / G, "--", color=line.get_color(), lw=0.8, label=f"{name}, no uplift")
        if motion is not None and d in motion.components:
            ground = response_spectrum(motion.acc[: res.nt, j], motion.dt, 1 / f, 0.05)
            ax.semilogx(f, ground.psa / G, "k--", label="ground")
        ax.set_title(f"{d} ({'vertical' if d == 'z' else 'horizontal'})")
        ax.set_xlabel("frequency (Hz)")
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="small")
    axes[0].set_ylabel("pseudo-acceleration, 5 % (g)")
    return fig


def run_figures(results: dict, motion, scene_name: str):
    """Figures of the paper's kind for each route, yielded as (name, matplotlib Figure): uplift
    at the raft edges along x and y (fig. 3-4), the raft's vertical response and its rocking
    about both axes (``<route>_raft``), floor response spectra at the output nodes in x, y and
    z (fig. 5-6, ``<route>_floor_spectra``). When the ``linear`` route (no uplift) is among the
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
        if res.acc:
            fig = _spectra_figure(plt, res, lin, motion)
            fig.suptitle(f"{scene_name} [{route}]: floor response spectra, {label}")
            yield f"{route}_floor_spectra", fig
