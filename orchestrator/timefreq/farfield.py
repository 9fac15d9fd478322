"""The march's far field: what a finished block of contact displacements adds to the later steps.

The generic way (``generic_far_field``) is one application of S on the grid: the block's d
zero-padded, windowed FFT, S per frequency, inverse FFT. On a table that reads the dense band
(~250 MB on the reactor) and multiplies the affine band's A and B with the block's spectrum on
every frequency above the table (858 frequencies on the reactor, ~40 % of the application).

``AffineSplit`` computes the same sum with the soil's springs and dashpots K_inf = A + s B
taken on *all* frequencies and removed from the dense band: S = K_inf + D - R6, D = K_ww -
K_inf on the dense band's frequencies (zero above), R6 the structure's rank-6 term. On the
bilinear grid K_inf's periodic kernel is closed form: A at lag 0 only, and s_d = (2/dt)
(z - 1)/(z + 1) has h_0 = (2/dt)(1 + r)/(1 - r) and h_k = (4/dt)(-1)^k / (1 - r) for 0 < k
< nfft, r = (-1)^nfft e^{-eta nfft dt} (the alternating tail of the trapezoidal rule's
velocity, wrapped around the period). So K_inf's far field from a block [a, b) is the
rank-one update (-1)^n c B sum_m (-1)^m d_m for n >= b, N^2 multiply-adds, and only D and R6
go through the FFTs. The same sums in another order: equal to round-off.
"""
from __future__ import annotations

import numpy as np

from orchestrator.timefreq.operator import _span
from orchestrator.timefreq.soil import AffineBand, DenseBand, dense

#: |h_k - c (-1)^k| <= ALTERNATING_RTOL |c| over the lags 1 .. nt-1 for the closed form to be used
ALTERNATING_RTOL = 1e-10


def generic_far_field(op, grid):
    """far(x_block, a, b, H): H[:, b:] += (S * x_block)[:, b:] for the block x[:, a:b] (N, b - a),
    by one application of S on the grid."""
    N, nt = op.N, grid.nt

    def far(xb, a, b, H):
        X = np.zeros((N, nt))
        X[:, a:b] = xb
        H[:, b:] += grid.to_time(op.apply_S(grid.to_freq(X)))[:, b:]
    return far


class AffineSplit:
    """The far field with the affine band taken on all frequencies (module notes). ``usable``
    tells whether the soil and grid allow it: one AffineBand, the other bands dense, the
    bilinear grid (checked on s's kernel itself)."""

    def __init__(self, op, grid):
        self.op, self.grid = op, grid
        bands = op.soil.bands
        affine = [b for b in bands if isinstance(b, AffineBand)]
        self.usable = grid.bilinear and len(affine) == 1 and \
            all(isinstance(b, (AffineBand, DenseBand)) for b in bands)
        if not self.usable:
            return
        nt = grid.nt
        sig = grid.to_time(op.s, n=nt)                      # the kernel of s on the grid
        alt = (-1.0) ** np.arange(nt)
        c = -sig[1] if nt > 1 else 0.0
        if nt > 1 and np.abs(sig[1:] - c * alt[1:]).max() > ALTERNATING_RTOL * abs(c):
            self.usable = False
            return
        self.c, self.alt = c, alt
        Aw, Bw = affine[0].ww()
        self.Bw = Bw
        Ad, Bd = dense(Aw), dense(Bw)
        self.dense = [(b.idx, self._minus_affine(b.ww(), Ad, Bd, op.s[b.idx]))
                      for b in bands if isinstance(b, DenseBand)]

    @staticmethod
    def _minus_affine(K, A, B, s):
        """D = K - (A + s B) (Fb, N, N), one frequency at a time (no band-sized temporaries)."""
        D = np.empty(K.shape, complex)
        for f in range(K.shape[0]):
            np.subtract(K[f], A, out=D[f])
            D[f] -= s[f] * B
        return D

    def __call__(self, xb, a, b, H):
        """H[:, b:] += (S * x_block)[:, b:] for the block x[:, a:b] (N, b - a)."""
        op, g = self.op, self.grid
        op.n_apply += 1
        N, nt = H.shape
        X = np.zeros((N, nt))
        X[:, a:b] = xb
        Xf = np.ascontiguousarray(g.to_freq(X).T)[:, :, None]             # (F, N, 1)
        Y = np.empty_like(Xf)

        def task(sel):
            def run():
                Y[sel] = -(op.Vr[sel] @ (op.ZV[sel] @ Xf[sel]))
            return run
        F = Xf.shape[0]
        op.pool.run([task(h) for h in op.pool.chunks(F)])

        def dense_task(idx, D, h):
            def run():
                i = _span(idx[h])
                Y[i] += D[h] @ Xf[i]
            return run
        tasks = []
        for idx, D in self.dense:
            tasks += [dense_task(idx, D, h) for h in op.pool.chunks(idx.size)]
        if tasks:
            op.pool.run(tasks)
        H[:, b:] += g.to_time(Y[:, :, 0].T)[:, b:]
        gamma = xb @ self.alt[a:b]                                          # sum_m (-1)^m d_m
        H[:, b:] += (self.c * (self.Bw @ gamma))[:, None] * self.alt[None, b:]
