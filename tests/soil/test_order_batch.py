"""The streamed order search fits every order at once (issue 37, fit.streamed.StreamedProblem.search_orders):
one pass over the table for every order's E, a second only when some E is projected on the PSD cone; the
errors from the columns' R factor, the rigid-raft criterion from Pᵀ K_target P. Checked against the
order-by-order streamed fit (the same poles, errors and rigid-raft models up to round-off) and the fit in
memory, on a BEM gap table and on synthetic gap tables whose E is positive definite (the Cholesky branch)
and clearly indefinite (the projection's terms are not round-off there)."""
import numpy as np
import pytest

from helpers.passive_models import random_passive_model
from soil_impedance import ImpedanceTable, Material, SoilProfile, circle_mesh, impedance_sweep
from soil_impedance.blocked import BlockedTable, TableWriter
from soil_impedance.fit import FitOptions
from soil_impedance.fit.options import RIGID
from soil_impedance.fit.pipeline import _projection
from soil_impedance.fit.rigid import rigid_model
from soil_impedance.fit.search import FIRST_ORDERS, OrderSearch
from soil_impedance.fit.streamed import StreamedProblem, fit_order_streamed
from soil_impedance.fit.target import Problem, fit_order
from soil_impedance.vectfit import real_basis

#: round-off of the order errors between routes (measured: up to 5e-7 between the order-by-order streamed
#: fit and the fit in memory at 18 poles, where the pole basis is ill-conditioned; 1e-13 at a few poles)
ERR_RTOL = 2e-6


def _write(table, path, chunk):
    with TableWriter(path, table.frequencies_hz, table.dofs, table.provenance, chunk=chunk) as w:
        for k, K in enumerate(table.matrices):
            w[k] = K
    return BlockedTable.open(path)


@pytest.fixture(scope="module")
def bem_table():
    """Disk R = 10 m, 29 nodes (35 DOFs), hysteretic 3 % half-space, 21 frequencies (the causal target's
    faded offset below f_causal). Its E are positive definite on the active DOFs; with the gap table's zero
    rows, eigh finds round-off negative eigenvalues (-1e-15) and the order-by-order fit projects E."""
    soil = SoilProfile((), Material(vs=500.0, rho=2000.0, nu=0.3, damping=0.03, damping_model="hysteretic"))
    return impedance_sweep(soil, circle_mesh(10, 3.3), np.linspace(0, 25, 21), outputs=("gap",))["gap"]


def _synthetic(E_sign, seed=3):
    """A gap table of 14 nodes (20 DOFs), 26 frequencies 0-25 Hz: a passive rational model (3 pole pairs)
    with E made positive definite (E_sign = +1) or given a negative eigenvalue of the size of its largest
    (E_sign = -1), plus 1e-3 relative noise (seeded), symmetric."""
    rng = np.random.default_rng(seed)
    xy = np.array([(x, y) for x in (-6.0, -2.0, 2.0, 6.0) for y in (-4.0, 0.0, 4.0, 8.0)])[:14]
    n = 6 + len(xy)
    model = random_passive_model(n, 3, 1, seed=seed)
    A = rng.standard_normal((n, n))
    E = A @ A.T / n
    lam, V = np.linalg.eigh(E)
    if E_sign < 0:
        lam[:2] = -lam[-1]
    E = (V * (lam + (0.2 * lam[-1] if E_sign > 0 else 0.0))) @ V.T
    f = np.linspace(0.0, 25.0, 26)
    s = 2j * np.pi * f
    K = model.frequency_response(f) + s[:, None, None] * (E * np.abs(model.D).max() / np.abs(E).max() / (2 * np.pi * 25))[None]
    noise = rng.standard_normal(K.shape) + 1j * rng.standard_normal(K.shape)
    K = K + 1e-3 * np.abs(K).max(axis=(1, 2))[:, None, None] * noise
    dofs = list(RIGID) + [f"w{i}" for i in range(len(xy))]
    return ImpedanceTable(f, 0.5 * (K + K.transpose(0, 2, 1)), dofs, {"source": "synthetic"}), xy


def _streamed(table, tmp_path, chunk, weighting, node_xy=None):
    lazy = _write(table, tmp_path / f"t{chunk}.h5", chunk)
    opt = FitOptions.make(node_xy, tol=1e-6, weighting=weighting)
    P = _projection(lazy, opt)
    assert P is not None
    return lazy, P, StreamedProblem(lazy, weighting, opt.f_causal_hz, P)


def _check_orders(table, prob, P, pairs, n_iter):
    """search_orders against fit_order_streamed order by order and fit_order in memory."""
    reads = []
    block = prob.table.block
    prob.table.block = lambda r, c: reads.append((r, c)) or block(r, c)
    batch = prob.search_orders(pairs, n_iter, {})
    one_pass = len(list(prob.table.blocks(prob.block)))
    assert len(reads) == one_pass * (2 if prob.projected else 1)       # one pass, two with an E projected
    mem = Problem(table, prob.weighting, "auto")
    reads.clear()
    for k, (poles, err, rigid) in enumerate(batch):
        p1, C, e1 = fit_order_streamed(prob, k + 1, n_iter)
        assert np.array_equal(poles, p1)                              # the same vector fitting
        assert err == pytest.approx(e1, rel=ERR_RTOL)
        pm, _, em = fit_order(mem, k + 1, n_iter)
        assert np.allclose(pm, poles, rtol=1e-6, atol=0) and err == pytest.approx(em, rel=ERR_RTOL)
        ref = rigid_model(prob.model(p1, C, {}), P)                   # Pᵀ K P of the order's full model
        for a, b in ((rigid.residues, ref.residues), (rigid.D, ref.D), (rigid.E, ref.E)):
            assert np.abs(a - b).max() <= 1e-9 * np.abs(b).max()
    assert len(reads) >= one_pass * len(batch)                        # order by order: a pass per order at least
    return batch


@pytest.mark.parametrize("weighting", ["relative", "uniform"])
def test_every_order_at_once_equals_the_fit_order_by_order(bem_table, tmp_path, weighting):
    lazy, P, prob = _streamed(bem_table, tmp_path, 12, weighting)
    _check_orders(bem_table, prob, P, 6, 5)
    assert prob.projected == []                                       # Cholesky on the active DOFs: definite


@pytest.mark.parametrize("sign", [1, -1])
def test_a_definite_and_an_indefinite_E(tmp_path, sign):
    """E positive definite: the orders whose fitted E is positive definite are not projected (Cholesky
    proves it; here all but the 4-pole one, whose E comes out indefinite). E with two negative eigenvalues
    as large as the largest: every order projected, and the projection's correction is no round-off
    (from 4 poles the projected fit's error is 1.3 to 50 times the unprojected least squares')."""
    table, xy = _synthetic(sign)
    lazy, P, prob = _streamed(table, tmp_path, 8, "relative", xy)
    batch = _check_orders(table, prob, P, 4, 8)
    if sign > 0:
        assert prob.projected == [1]
        return
    assert prob.projected == list(range(len(batch)))
    mem = Problem(table, "relative", "auto")
    for poles, err, _ in batch[1:]:
        free = mem._solve(poles, mem.X, linear=True)                   # the least squares without the projection
        lam = np.linalg.eigvalsh(mem._matrix(free[-1]))
        assert lam.min() < -0.1 * lam.max()                            # its E: clearly indefinite
        res = np.linalg.norm(real_basis(mem.s, poles) @ free - mem.X, axis=1) / np.linalg.norm(mem.X, axis=1)
        assert err > 1.3 * res[mem.band].max()                         # the projection costs error: not round-off


def test_the_search_takes_the_batched_orders_with_its_own_rules(bem_table, tmp_path):
    """OrderSearch.run on a streamed problem: the same stop reason, orders, poles and criteria as the
    order-by-order search (``batched`` False; it stops at the fifth order, in the second batch), no
    coefficients held, and the enforcement's refit of an
    order equals that order's fit bit for bit; the "entry" weighting stays order by order."""
    lazy, P, prob = _streamed(bem_table, tmp_path, 12, "relative")
    opt = FitOptions(tol=0.05, patience=2, n_iter=5)
    a = OrderSearch(prob, opt, P, {}, None)
    a.batched = False
    b = OrderSearch(prob, opt, P, {}, None)
    assert a.run() == b.run()
    assert a.batch is None and FIRST_ORDERS < len(a.fits) == len(b.fits) < b.max_pairs
    assert len(b.batch) == b.max_pairs                                  # the second batch: every order up to max_pairs
    for fa, fb in zip(a.fits, b.fits):
        assert np.array_equal(fa[0], fb[0])
        assert fb[2] == pytest.approx(fa[2], rel=ERR_RTOL) and fb[3] == pytest.approx(fa[3], rel=ERR_RTOL)
    assert b.held() == 0
    c = OrderSearch(prob, FitOptions(tol=0.07, n_iter=5), P, {}, None)
    assert c.run() == "tol reached" and len(c.fits) == 3 and len(c.batch) == FIRST_ORDERS      # the first batch only
    assert [f[3] for f in c.fits] == [f[3] for f in b.fits[:3]]
    i = int(np.argmin([f[3] for f in b.fits]))
    assert np.array_equal(b.coefficients(i), a.coefficients(i)) and b.refits == 1
    entry = OrderSearch(StreamedProblem(lazy, "entry", "auto", P), FitOptions(tol=0.05, patience=1, n_iter=3,
                                                                               weighting="entry"), P, {}, None)
    entry.run()
    assert entry.batch is None and entry.held() == 1


def test_without_the_rigid_raft_correction(bem_table, tmp_path):
    """rigid_correction off (P None): the batched errors alone, equal to the order-by-order search's; the
    search goes to max_order, so the orders come in two batches, at most four passes in all."""
    lazy = _write(bem_table, tmp_path / "t.h5", 12)
    prob = StreamedProblem(lazy, "relative", "auto", None)
    opt = FitOptions(tol=1e-6, max_order=10, patience=None, n_iter=5, rigid_correction=False)
    a, b = OrderSearch(prob, opt, None, {}, None), OrderSearch(prob, opt, None, {}, None)
    a.batched = False
    assert a.run() == "max_order"
    reads = []
    block = prob.table.block
    prob.table.block = lambda r, c: reads.append((r, c)) or block(r, c)
    assert b.run() == "max_order" and len(b.batch) == b.max_pairs == FIRST_ORDERS + 1     # two batches
    assert len(reads) <= 4 * len(list(prob.table.blocks(prob.block)))                   # two passes each at most
    assert all(rigid is None for _, _, rigid in b.batch)
    for ha, hb in zip(a.history, b.history):
        assert ha[0] == hb[0] and len(hb) == 2 and hb[1] == pytest.approx(ha[1], rel=ERR_RTOL)
