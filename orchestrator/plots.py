"""Figures for reports (matplotlib, Agg backend, imported lazily by the CLI)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

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


def _edges(xy):
    """Indices of the interface nodes at the raft edges along x (min x and max x on y ≈ 0)."""
    on_axis = np.abs(xy[:, 1]) <= np.abs(xy[:, 1]).min() + 1e-9
    idx = np.flatnonzero(on_axis)
    return idx[np.argmin(xy[idx, 0])], idx[np.argmax(xy[idx, 0])]


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


def run_figures(results: dict, motion, scene_name: str):
    """Figures of the paper's kind for each route, yielded as (name, matplotlib Figure): uplift
    at the raft edges (fig. 3-4), raft edge displacements and rotation (``<route>_raft``),
    floor response spectra at the output nodes (fig. 5-6, ``<route>_floor_spectra``).
    When the ``linear`` route (no uplift) is among the results, it is drawn dashed on the other
    routes' figures: the paper's "with and without uplift" comparison. ``motion`` (may be None)
    adds the ground spectrum. The caller closes each figure."""
    plt = pyplot()
    label = motion.label if motion is not None else ""
    linear = results.get("linear")
    for route, res in results.items():
        left, right = _edges(res.xy)
        t = res.time
        lin = linear if linear is not None and route != "linear" else None
        fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True, constrained_layout=True)
        for i, side in ((left, "edge x-"), (right, "edge x+")):
            axes[0].plot(t, 1e3 * res.gap[:, i], label=f"{side} ({res.xy[i, 0]:.1f} m)")
            x, y = res.xy[i]
            trace = res.raft[:, 2] + res.raft[:, 3] * y - res.raft[:, 4] * x
            line, = axes[1].plot(t, 1e3 * trace, label=side)
            if lin is not None:
                trace0 = lin.raft[:, 2] + lin.raft[:, 3] * y - lin.raft[:, 4] * x
                axes[1].plot(lin.time, 1e3 * trace0, "--", color=line.get_color(), lw=0.8,
                             label=f"{side}, no uplift")
        axes[0].set_ylabel("uplift (mm)")
        axes[1].set_ylabel("raft vertical displacement (mm)")
        axes[2].plot(t, 1e3 * res.raft[:, 4], label="ry")
        axes[2].plot(t, 1e3 * res.raft[:, 3], label="rx")
        axes[2].set_ylabel("raft rotation (mrad)")
        axes[2].set_xlabel("time (s)")
        for ax in axes:
            ax.grid(True, alpha=0.3)
            ax.legend(loc="upper right")
        fig.suptitle(f"{scene_name} [{route}]: raft response, {label}")
        yield f"{route}_raft", fig
        if res.acc:
            f = np.geomspace(0.5, 40.0, 120)
            fig, ax = plt.subplots(figsize=(8, 5), constrained_layout=True)
            for name, acc in res.acc.items():
                s = response_spectrum(acc[:, 0], res.time[1] - res.time[0], 1 / f, 0.05)
                line, = ax.semilogx(f, s.psa / 9.81, label=name)
                if lin is not None and name in lin.acc:
                    s0 = response_spectrum(lin.acc[name][:, 0], lin.time[1] - lin.time[0], 1 / f, 0.05)
                    ax.semilogx(f, s0.psa / 9.81, "--", color=line.get_color(), lw=0.8,
                                label=f"{name}, no uplift")
            if motion is not None:
                ground = response_spectrum(motion.acc[: res.nt, 0], motion.dt, 1 / f, 0.05)
                ax.semilogx(f, ground.psa / 9.81, "k--", label="ground")
            ax.set_xlabel("frequency (Hz)")
            ax.set_ylabel("pseudo-acceleration, 5 % (g)")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
            ax.set_title(f"{scene_name} [{route}]: floor response spectra (x)")
            yield f"{route}_floor_spectra", fig
