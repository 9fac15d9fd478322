"""Vector fitting kernels: common poles for many frequency responses (array functions only).

Relaxed vector fitting (Gustavsen 2006) with the fast QR of Deschrijver et al. (2008): each
column's residue unknowns are eliminated by a QR, only the pole-identification rows are kept.
Many columns are first compressed by a real SVD (``compress``): a real combination of real-model
responses is itself a real-model response with the same poles, so the poles are identified on a
few dominant combinations and the residues of every column are then one linear least squares
(``fit_coefficients``) with the shared basis.

Real basis (``real_basis``): a real pole p contributes 1/(s − p); a conjugate pair (p, p̄), Im p > 0,
contributes φ1 = 1/(s−p) + 1/(s−p̄) and φ2 = i/(s−p) − i/(s−p̄), so real coefficients (c1, c2) give
the residues c1 + i c2 on p and c1 − i c2 on p̄ (real impulse response by construction). Optional
columns 1 (the constant D) and s (the E term) follow the pole columns.

Shapes: s (F,) complex (usually iω, normalised); Y (F, q) complex; weights (F,) real.
"""
from __future__ import annotations

import numpy as np


def canonical_poles(poles, rtol=1e-10) -> np.ndarray:
    """Conjugate-closed, stable pole list: real poles first, then pairs (p, p̄) with Im p > 0.

    Unstable poles are flipped into the left half-plane (Re p → −|Re p|); near-real poles
    (|Im p| <= rtol |p|) become real; each pole with Im p > 0 is kept with its conjugate.
    """
    p = np.asarray(poles, complex).reshape(-1)
    p = -np.abs(p.real) + 1j * p.imag
    p = np.where(p.real == 0, -1e-12 * np.maximum(np.abs(p), 1.0) + 1j * p.imag, p)
    near_real = np.abs(p.imag) <= rtol * np.abs(p)
    real = np.sort(p[near_real].real)
    upper = p[(~near_real) & (p.imag > 0)]
    upper = upper[np.argsort(upper.imag)]
    out = [complex(r) for r in real]
    for q in upper:
        out += [q, np.conj(q)]
    return np.array(out, complex)


def pole_kinds(poles) -> np.ndarray:
    """Per pole: 0 real, 1 first of a pair (Im > 0), 2 second of a pair (the conjugate)."""
    p = np.asarray(poles, complex)
    kind = np.zeros(p.size, int)
    k = 0
    while k < p.size:
        if p[k].imag != 0:
            kind[k], kind[k + 1] = 1, 2
            k += 2
        else:
            k += 1
    return kind


def real_basis(s, poles, const=True, linear=True) -> np.ndarray:
    """Basis matrix, shape (F, m + const + linear), complex: pole columns, then 1, then s."""
    s = np.asarray(s, complex).reshape(-1)
    p = np.asarray(poles, complex)
    kind = pole_kinds(p)
    cols = []
    for k, kk in enumerate(kind):
        if kk == 0:
            cols.append(1.0 / (s - p[k]))
        elif kk == 1:
            a, b = 1.0 / (s - p[k]), 1.0 / (s - np.conj(p[k]))
            cols += [a + b, 1j * a - 1j * b]
    if const:
        cols.append(np.ones_like(s))
    if linear:
        cols.append(s)
    return np.column_stack(cols) if cols else np.zeros((s.size, 0), complex)


def coefficients_to_residues(coef, poles) -> np.ndarray:
    """Real pole coefficients, shape (m, ...), to complex residues, shape (m, ...)."""
    coef = np.asarray(coef, float)
    res = coef.astype(complex)
    for k, kk in enumerate(pole_kinds(poles)):
        if kk == 1:
            r = coef[k] + 1j * coef[k + 1]
            res[k], res[k + 1] = r, np.conj(r)
    return res


def residues_to_coefficients(res, poles) -> np.ndarray:
    """Inverse of ``coefficients_to_residues``."""
    res = np.asarray(res, complex)
    coef = res.real.copy()
    for k, kk in enumerate(pole_kinds(poles)):
        if kk == 1:
            coef[k], coef[k + 1] = res[k].real, res[k].imag
    return coef


def initial_poles(n_pairs, w_max, w_min=0.0, damping=0.1) -> np.ndarray:
    """``n_pairs`` conjugate pairs, Im p spread linearly over [w_min, w_max], Re p = −damping·Im p."""
    if n_pairs <= 0:
        return np.zeros(0, complex)
    beta = np.linspace(max(w_min, w_max / (4 * n_pairs)), w_max, n_pairs)
    return canonical_poles(-damping * beta + 1j * beta)


def _stack(M):
    return np.concatenate([M.real, M.imag], axis=0)


def compress(Y, weights, max_columns=24, rtol=1e-8) -> np.ndarray:
    """Dominant real combinations of the columns of Y (F, M): Y V with V real, shape (F, q).

    The real SVD of [Re WY; Im WY] keeps singular values above rtol·σ1 (at most max_columns),
    scaled by σ so that the combinations carry the columns' weight.
    """
    if Y.shape[1] <= max_columns:
        return Y
    Yr = _stack(weights[:, None] * Y)
    u, sv, vt = np.linalg.svd(Yr, full_matrices=False)
    q = int(min(max_columns, np.sum(sv > rtol * sv[0])))
    return Y @ vt[:q].T


def relocate_poles(s, Y, weights, poles, const=True, linear=True) -> np.ndarray:
    """One relaxed vector-fitting iteration: the zeros of the weighting function σ(s).

    Y : (F, q) complex responses sharing the poles; weights : (F,) row weights.
    Returns the new (canonical, stable) poles, same count as ``poles``.
    """
    s = np.asarray(s, complex)
    F, q = Y.shape
    m = poles.size
    Phi = real_basis(s, poles, const=False, linear=False)           # (F, m)
    A0 = real_basis(s, poles, const=const, linear=linear)           # (F, nb)
    nb = A0.shape[1]
    Sig = np.column_stack([Phi, np.ones(F)])                         # σ basis (F, m+1)
    w = weights[:, None]
    rows = []
    scale = 0.0
    for j in range(q):
        M = np.hstack([w * A0, -(w * Y[:, j:j + 1]) * Sig])
        R = np.linalg.qr(_stack(M), mode="r")
        rows.append(R[nb:nb + m + 1, nb:])
        scale += np.linalg.norm(weights * Y[:, j]) ** 2
    scale = np.sqrt(scale) / F
    relax = (np.sum(Sig.real, axis=0) * scale)[None, :]
    AA = np.vstack(rows + [relax])
    bb = np.zeros(AA.shape[0])
    bb[-1] = F * scale
    col = np.linalg.norm(AA, axis=0)
    col[col == 0] = 1.0
    x = np.linalg.lstsq(AA / col, bb, rcond=None)[0] / col
    c, d = x[:m], x[m]
    if abs(d) < 1e-8:                      # relaxation collapsed: fix d and resolve (non-relaxed)
        d = 1e-8 * (np.sign(d) or 1.0) if abs(d) > 0 else 1.0
        rhs = -np.vstack(rows)[:, m] * d
        c = np.linalg.lstsq(np.vstack(rows)[:, :m], rhs, rcond=None)[0]
    # real state-space form of σ(s) − d... zeros = eig(A − b cᵀ / d)
    A = np.zeros((m, m))
    b = np.zeros(m)
    kind = pole_kinds(poles)
    for k, kk in enumerate(kind):
        if kk == 0:
            A[k, k] = poles[k].real
            b[k] = 1.0
        elif kk == 1:
            A[k:k + 2, k:k + 2] = [[poles[k].real, poles[k].imag], [-poles[k].imag, poles[k].real]]
            b[k] = 2.0
    z = np.linalg.eigvals(A - np.outer(b, c) / d)
    return canonical_poles(z)


def fit_coefficients(s, X, weights, poles, const=True, linear=True) -> np.ndarray:
    """Real coefficients of every column of X (F, M) on the shared basis: shape (nb, M).

    Weighted linear least squares min Σ_f w_f² |Σ_b φ_b(s_f) c_b − X_f|², one QR for all columns.
    """
    A = real_basis(s, poles, const=const, linear=linear) * weights[:, None]
    Ar = _stack(A)
    col = np.linalg.norm(Ar, axis=0)
    col[col == 0] = 1.0
    Q, R = np.linalg.qr(Ar / col)
    rhs = Q.T @ _stack(weights[:, None] * X)
    return np.linalg.lstsq(R, rhs, rcond=None)[0] / col[:, None]


def vector_fit(s, Y, weights, poles, n_iter=10, const=True, linear=True, tol=1e-6) -> np.ndarray:
    """Iterate ``relocate_poles`` from ``poles`` (at most n_iter times, stop when they settle)."""
    poles = canonical_poles(poles)
    for _ in range(n_iter):
        new = relocate_poles(s, Y, weights, poles, const, linear)
        if new.size != poles.size:      # a pair merged into two real poles or vice versa
            poles = new
            continue
        moved = np.max(np.abs(np.sort_complex(new) - np.sort_complex(poles)) / np.maximum(np.abs(new), 1e-12))
        poles = new
        if moved < tol:
            break
    return poles
