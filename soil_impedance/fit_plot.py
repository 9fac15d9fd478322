"""Figure of a rational fit against its table (matplotlib Agg, imported lazily)."""
from __future__ import annotations

import numpy as np

from uplift_common.files import save_figure


def plot_fit(result, table, path, dofs=None):
    """Table vs model for the rigid diagonal terms (Re and Im, DOF-scaled by K_ii(f_0)) and the
    relative Frobenius error per frequency; writes ``path`` and returns it."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    f = table.frequencies_hz
    fd = np.linspace(f[0], f[-1], 400)
    Km = result.model.frequency_response(fd)
    dofs = dofs or [d for d in ("ux", "uy", "uz", "rx", "ry", "rz") if d in table.dofs][:6] or table.dofs[:6]
    fig, axes = plt.subplots(2, 1, figsize=(8, 8), sharex=True)
    for j, d in enumerate(dofs):
        i = table.index(d)
        k0 = abs(table.matrices[0, i, i].real)
        if k0 == 0:
            continue
        c = f"C{j}"
        axes[0].plot(f, table.matrices[:, i, i].real / k0, "o", ms=3, color=c)
        axes[0].plot(fd, Km[:, i, i].real / k0, "-", color=c, label=f"{d} Re")
        axes[0].plot(f, table.matrices[:, i, i].imag / k0, "s", ms=3, mfc="none", color=c)
        axes[0].plot(fd, Km[:, i, i].imag / k0, "--", color=c, label=f"{d} Im")
    axes[0].set_ylabel("K_ii / K_ii(f0)  (markers: table, lines: model)")
    axes[0].legend(ncol=3, fontsize=7)
    rep = result.report
    axes[1].semilogy(rep.freq_hz, np.maximum(rep.rel_error, 1e-16), "k.-")
    axes[1].axhline(rep.settings.get("tol", 0.01), color="r", ls=":", label="tol")
    if rep.f_causal_hz > 0:
        axes[1].axvline(rep.f_causal_hz, color="g", ls="--", label="f_causal")
    axes[1].set_xlabel("frequency (Hz)")
    axes[1].set_ylabel("relative Frobenius error")
    axes[1].legend()
    axes[0].set_title(f"{rep.order} poles, max error {rep.max_rel_error:.2e}, "
                      f"{'passive' if rep.passive else 'NOT passive'} (margin {rep.passivity_margin:.2e})")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path
