"""Passive RationalModels from mechanical building blocks: test and benchmark factories
(``oscillator_model``, ``random_passive_model``, ``null_noise_model``) and ``with_notch`` (a narrow violation
added). Import as ``from helpers import ...``
(tests/ is on the path under pytest; benchmarks add it)."""
import numpy as np

from soil_impedance.rational import RationalModel


def oscillator_model(D, E=None, terms=(), maxwell=(), dofs=None) -> RationalModel:
    """A passive RationalModel from mechanical building blocks (for tests and benchmarks).

    D, E : (n, n) PSD springs and dashpots to ground.
    terms : iterable of (k, c, m, W): an internal mass m, tied by a spring k to the interface
        and by a dashpot c to ground, seen through the PSD shape W (n, n): the scalar
        k − k^2/(m s^2 + c s + k) = k + Σ r/(s − p) times W (passive: a condensed mechanical
        system); complex pair when c^2 < 4 m k.
    maxwell : iterable of (k, c, W): spring k in series with dashpot c, k s/(s + k/c) W.
    """
    D = np.array(D, float)
    n = D.shape[0]
    E = np.zeros((n, n)) if E is None else np.array(E, float)
    poles, res = [], []
    for k, c, m, W in terms:
        W = np.asarray(W, float)
        p1, p2 = np.roots([m, c, k]).astype(complex)
        D = D + k * W
        poles += [p1, p2]
        res += [-k * k / (m * (p1 - p2)) * W, -k * k / (m * (p2 - p1)) * W]
    for k, c, W in maxwell:
        W = np.asarray(W, float)
        a = k / c
        D = D + k * W
        poles.append(-a + 0j)
        res.append(-k * a * W + 0j)
    return RationalModel(np.array(poles, complex), np.array(res, complex).reshape(len(poles), n, n),
                         D, E, dofs=dofs or [], provenance={"source": "oscillator_model"})


def random_passive_model(n: int, n_pairs: int, n_real: int = 0, seed: int = 0,
                         f_range=(0.5, 20.0)) -> RationalModel:
    """Random passive model: n DOFs, n_pairs oscillator pairs with resonances log-spread over
    f_range (Hz) and damping ratios 5-40 %, n_real Maxwell poles, full-rank PSD shapes."""
    rng = np.random.default_rng(seed)

    def psd():
        G = rng.standard_normal((n, n)) / np.sqrt(n)
        return G @ G.T + 0.05 * np.eye(n)

    fr = np.geomspace(*f_range, max(n_pairs, 1))[:n_pairs]
    terms = []
    for f in fr:
        w0, zeta = 2 * np.pi * f, rng.uniform(0.05, 0.4)
        k = rng.uniform(0.5, 2.0)
        m = k / w0**2
        terms.append((k, 2 * zeta * np.sqrt(k * m), m, psd()))
    maxwell = [(rng.uniform(0.5, 2.0), rng.uniform(0.5, 2.0) / (2 * np.pi * f), psd())
               for f in np.geomspace(*f_range, max(n_real, 1))[:n_real]]
    return oscillator_model(psd(), 0.02 * psd(), terms, maxwell)


def kernel_passive_model(xy, n_pairs: int, n_real: int = 0, seed: int = 0, f_range=(0.5, 20.0)) -> RationalModel:
    """A passive model of a raft on nodes xy (N, 2), m, with n = 6 + N DOFs [q, w] whose shapes
    have the soil kernel's structure: W = Tᵀ G T + 0.05 I, T = [B | I] (B the nodes' vertical
    traces of uz, rx, ry), G_ij = h exp(−r_ij / λ) / sqrt(r_ij² + h²) (PSD: a product of PSD
    kernels), h the mean node spacing and λ from h to the raft's size, one per term: its
    blocks between well-separated node groups are numerically of low rank, as a fit's residues
    (an oscillator per pair, a Maxwell element per real pole, as ``random_passive_model``)."""
    xy = np.asarray(xy, float)
    N = xy.shape[0]
    rng = np.random.default_rng(seed)
    T = np.zeros((N, 6 + N))
    T[:, 2], T[:, 3], T[:, 4] = 1.0, xy[:, 1], -xy[:, 0]
    T[:, 6:] = np.eye(N)
    r = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    size = float(np.ptp(xy, axis=0).max())
    h = np.sqrt(np.ptp(xy[:, 0]) * np.ptp(xy[:, 1]) / N)
    lams = iter(np.geomspace(h, size, n_pairs + n_real + 1)[::-1])

    def shape():
        lam = next(lams)
        G = h * np.exp(-r / lam) / np.sqrt(r ** 2 + h ** 2)
        W = T.T @ G @ T / N
        W[np.arange(3), np.arange(3)] += 1.0
        W[5, 5] += 1.0
        return 0.5 * (W + W.T) + 0.05 * np.eye(6 + N)

    fr = np.geomspace(*f_range, max(n_pairs, 1))[:n_pairs]
    terms = []
    for f in fr:
        w0, zeta = 2 * np.pi * f, rng.uniform(0.05, 0.4)
        k = rng.uniform(0.5, 2.0)
        m = k / w0 ** 2
        terms.append((k, 2 * zeta * np.sqrt(k * m), m, shape()))
    maxwell = [(rng.uniform(0.5, 2.0), rng.uniform(0.5, 2.0) / (2 * np.pi * f), shape())
               for f in np.geomspace(*f_range, max(n_real, 1))[:n_real]]
    D = shape()
    return oscillator_model(D, 0.02 * D, terms, maxwell)


def with_kernel_terms(model: RationalModel, xy, n_terms: int = 2, share: float = 0.3, f_range=(1.0, 10.0),
                      pairs: bool = True) -> RationalModel:
    """``model`` (n = 6 + N DOFs [q, w] on the nodes xy (N, 2), m; passive) with ``n_terms``
    passive terms of the soil kernel's structure added: shapes W = Tᵀ S G S T, T = [B | I] (B
    the nodes' vertical traces of uz, rx, ry), S = diag(sqrt(K(0)_ww)) of the model, G_ij =
    exp(−r_ij / λ) h / sqrt(r_ij² + h²) (PSD: a product of PSD kernels; h the mean node spacing,
    λ from the raft's size down), each worth ``share`` of the model's static node stiffness: an
    oscillator (a conjugate pair, ``pairs``) or a Maxwell element (a real pole) per term, with
    resonance or corner frequencies over f_range, Hz. Its history blocks between well-separated
    node groups are numerically of low rank, as a fit's residues."""
    xy = np.asarray(xy, float)
    N, n = xy.shape[0], model.n
    T = np.zeros((N, n))
    T[:, 2], T[:, 3], T[:, 4] = 1.0, xy[:, 1], -xy[:, 0]
    T[:, 6:] = np.eye(N)
    s = np.sqrt(np.diag(model.static)[6:])
    r = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    h = float(np.sqrt(np.ptp(xy[:, 0]) * np.ptp(xy[:, 1]) / N))
    lams = np.geomspace(float(np.ptp(xy, axis=0).max()), 2 * h, max(n_terms, 1))
    terms, maxwell = [], []
    for lam, f in zip(lams, np.geomspace(*f_range, max(n_terms, 1))):
        G = h * np.exp(-r / lam) / np.sqrt(r ** 2 + h ** 2)
        W = T.T @ (s[:, None] * G * s[None, :]) @ T
        W = share * 0.5 * (W + W.T)
        w0 = 2 * np.pi * f
        if pairs:
            terms.append((1.0, 2 * 0.3 / w0, 1.0 / w0 ** 2, W))    # k = 1, damping ratio 0.3
        else:
            maxwell.append((1.0, 1.0 / w0, W))
    extra = oscillator_model(np.zeros((n, n)), None, terms, maxwell)
    return RationalModel(np.concatenate([model.poles, extra.poles]),
                         np.concatenate([model.residues, extra.residues]), model.D + extra.D, model.E,
                         dofs=list(model.dofs), provenance={"source": "with_kernel_terms"})


def with_notch(model: RationalModel, f0: float, zeta: float, depth: float, v) -> RationalModel:
    """``model`` plus a negative damping peak α ω0²/(s² + 2ζω0 s + ω0²) v vᵀ at f0 (half-width ≈ ζ f0), α
    such that its Im is ``depth`` × vᵀ Im K(f0) v at f0: a violation band about 2ζ f0 wide at f0."""
    v = np.asarray(v, float) / np.linalg.norm(v)
    w0 = 2 * np.pi * f0
    alpha = depth * (v @ model.frequency_response([f0])[0].imag @ v) * 2 * zeta
    p = -zeta * w0 + 1j * w0 * np.sqrt(1 - zeta ** 2)
    r = alpha * w0 ** 2 / (p - np.conj(p)) * np.outer(v, v)
    return RationalModel(np.concatenate([model.poles, [p, np.conj(p)]]), np.concatenate([model.residues, [r, np.conj(r)]]),
                         model.D, model.E, model.dofs, model.provenance)


def null_noise_model(n, seed=0, noise=2e-3, f_max=25.0):
    """n DOFs, D = I, E a rank-3 dashpot (the radiating patterns) and three real poles with small random
    symmetric residues: on the n − 3 other directions Im K is ±noise·ν, half of them negative at every
    frequency (an undamped soil's evanescent patterns as a fit leaves them)."""
    rng = np.random.default_rng(seed)
    w = 2 * np.pi * f_max
    W = rng.standard_normal((n, 3)) / np.sqrt(n)
    poles = -w * np.array([0.5, 1.0, 2.0])
    R = [noise * p * p / w * (lambda X: (X + X.T) / np.sqrt(2 * n))(rng.standard_normal((n, n))) for p in poles]
    return RationalModel(poles + 0j, np.array(R, complex), np.eye(n), W @ W.T / w, [f"d{i}" for i in range(n)],
                         {"f_max_hz": f_max})
