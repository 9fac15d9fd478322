"""Figures for reports (matplotlib, Agg backend, imported lazily by the CLI)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

RIGID_GROUPS = (("ux", "horizontal"), ("uz", "vertical"), ("rx", "rocking"), ("rz", "torsion"))


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
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
    plt = _pyplot()
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
