"""Passive RationalModels from mechanical building blocks: test and benchmark factories
(``oscillator_model``, ``random_passive_model``). Import as ``from helpers import ...``
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
