"""The march's fast paths against their plain forms: the far field with the springs and dashpots
in closed form (farfield.AffineSplit) against one application of S on the grid, its kernel head
against the inverse FFT of every entry of S, the head of a symmetric S from one triangle, the
residual's S through the split against the operator's, a table's packed band against its formed
matrices, and the look-ahead (march.AHEAD) against the plain causal kernel: the same fixed
point."""
import dataclasses

import numpy as np
import pytest

from structure import ContactSettings

from orchestrator.timefreq import GridOptions, WorkerPool, prepare
from orchestrator.timefreq.farfield import AffineSplit, generic_far_field, packed_product
from orchestrator.timefreq.march import AHEAD, CausalSweep, defect_correction, kernel_lags
from orchestrator.timefreq.soil import MatrixBand, SplineBand, upper_pairs
from helpers import COARSE_RAFT, hysteretic_table, rel
from helpers import broadband as motion

MODEL, soil = COARSE_RAFT.model, COARSE_RAFT.soil
GRID = GridOptions().resolved(bilinear=True, window=True)


def problem(s, pga=0.3, duration=1.0):
    return prepare(MODEL, s, motion(pga, duration=duration), 0.005, grid=GRID, contact=ContactSettings(enabled=True))


def asymmetric_table():
    """The hysteretic table with a non-reciprocal coupling added (K[w0, w1] != K[w1, w0])."""
    tab = hysteretic_table()
    M = tab.matrices.copy()
    M[:, 6, 7] += 0.01 * M[:, 6, 6]
    return dataclasses.replace(tab, matrices=M)


def reference_lags(op, grid, n_lags, n_ahead):
    """h_0 .. h_{n_lags-1} and h_{-1} .. h_{-n_ahead}: the inverse FFT of every entry of S,
    window undone."""
    rows = np.arange(op.N)
    hw = np.fft.irfft(op.S_sub(rows, rows).transpose(1, 2, 0), n=grid.nfft, axis=-1)
    k = np.arange(n_lags)
    ka = np.arange(1, n_ahead + 1)
    head = hw[..., k] * np.exp(grid.eta * grid.dt * k)
    ahead = hw[..., grid.nfft - ka] * np.exp(-grid.eta * grid.dt * ka)
    return head.transpose(2, 0, 1), ahead.transpose(2, 0, 1)


@pytest.mark.parametrize("name", ["table", "winkler", "asymmetric table"])
def test_kernel_lags_and_the_split_kernel_are_the_inverse_fft_of_s(name):
    """kernel_lags (one triangle when S is symmetric) and AffineSplit.kernel (A and B times
    s's scalar kernel, a DFT restricted to the dense band, the rank-6 term from its affine
    parts) against the inverse FFT of every entry of S: 1e-12 of the largest entry, the first
    negative lags too; the split's kernel in single precision (a march in correction form) to
    1e-6."""
    s = {"table": hysteretic_table, "winkler": soil, "asymmetric table": asymmetric_table}[name]()
    prob = problem(s)
    op, g = prob.op, prob.grid
    assert op.symmetric() is (name != "asymmetric table")
    ref_head, ref_ahead = reference_lags(op, g, 20, 3)
    scale = np.abs(ref_head).max()
    head, ahead = kernel_lags(op, g, 20, 3)
    assert rel(head, ref_head) < 1e-12 and np.abs(ahead - ref_ahead).max() < 1e-12 * scale
    split = AffineSplit(op, g)
    assert split.usable
    head, ahead = split.kernel(20, 3)
    assert rel(head, ref_head) < 1e-12 and np.abs(ahead - ref_ahead).max() < 1e-12 * scale
    head32, ahead32 = split.kernel(20, 3, np.float32)          # a march's head in correction form
    assert head32.dtype == ahead32.dtype == np.float32
    assert rel(head32, ref_head) < 1e-6 and np.abs(ahead32 - ref_ahead).max() < 1e-6 * scale


@pytest.mark.parametrize("name", ["table", "winkler", "asymmetric table"])
def test_split_far_field_equals_one_application_of_s(name):
    """The far field of a block with the springs and dashpots in closed form (the trapezoidal
    dashpot's alternating tail as a rank-one update; the dense band packed when S is
    symmetric) equals one application of S on the grid: 1e-10 of the largest entry, for
    blocks at the start, middle and end of the record."""
    prob = problem({"table": hysteretic_table, "winkler": soil, "asymmetric table": asymmetric_table}[name]())
    op, g = prob.op, prob.grid
    split, plain = AffineSplit(op, g), generic_far_field(op, g)
    assert split.usable and split.packed is (name != "asymmetric table")
    rng = np.random.default_rng(5)
    N, nt = prob.f.shape
    for a in (0, nt // 2, nt - 70):
        b = a + 64
        xb = rng.standard_normal((N, 64))
        H1, H2 = np.zeros((N, nt)), np.zeros((N, nt))
        plain(xb, a, b, H1)
        split(xb, a, b, H2)
        assert np.abs(H2[:, :b]).max() == 0.0
        assert rel(H2, H1) < 1e-10


def test_split_needs_the_bilinear_grid():
    """On the continuous grid s's kernel is not the alternating tail: no split (the march
    falls back to applying S)."""
    prob = prepare(MODEL, hysteretic_table(), motion(0.3, duration=1.0), 0.005,
                   grid=GridOptions().resolved(bilinear=False, window=True), contact=ContactSettings(enabled=True))
    assert not AffineSplit(prob.op, prob.grid).usable


def test_look_ahead_keeps_the_fixed_point():
    """The march with its look-ahead (the first negative lags held at the step) against the
    plain causal kernel (method 'march-causal'), on the hysteretic table at 0.5 g: the same
    solution, max uplift to 1e-6 relative and histories to 1e-6, in no more sweeps."""
    with WorkerPool(1) as pool:
        prob = prepare(MODEL, hysteretic_table(), motion(0.5), 0.005, grid=GRID,
                       contact=ContactSettings(enabled=True), pool=pool)
        out = {a: defect_correction(prob, tol=1e-8, fold="auto", ahead=a) for a in (0, AHEAD)}
    gap = {a: np.maximum(0.0, -(prob.z0[:, None] + o.y)) for a, o in out.items()}
    assert all(o.converged for o in out.values()) and gap[0].max() > 1e-3
    assert abs(gap[AHEAD].max() - gap[0].max()) <= 1e-6 * gap[0].max()
    assert rel(out[AHEAD].y, out[0].y) < 1e-6
    assert len(out[AHEAD].history) <= len(out[0].history)


@pytest.mark.parametrize("name", ["table", "winkler", "asymmetric table"])
def test_split_applies_s_as_the_operator_does(name):
    """AffineSplit.apply (the residual's S in the march: K_inf X plus D X on the dense band,
    packed when S is symmetric, minus the rank-6 term above the table) equals op.apply_S on
    random spectra: 1e-12 of the largest entry. A table's band matrices at the grid (K, 260 MB
    on the reactor) are not formed by the split when its matrices are symmetric."""
    prob = problem({"table": hysteretic_table, "winkler": soil, "asymmetric table": asymmetric_table}[name]())
    op = prob.op
    split = AffineSplit(op, prob.grid)
    tables = [b for b in op.soil.bands if isinstance(b, SplineBand)]
    assert all("K" not in b.__dict__ for b in tables) is (name != "asymmetric table")
    rng = np.random.default_rng(7)
    X = rng.standard_normal((op.N, op.s.size)) + 1j * rng.standard_normal((op.N, op.s.size))
    Y = split.apply(X)
    assert all("K" not in b.__dict__ for b in tables) is (name != "asymmetric table")
    assert rel(Y, op.apply_S(X)) < 1e-12


def test_a_tables_packed_band_is_its_matrices_upper_triangles():
    """SplineBand.packed_ww (one product of the weights with the table's packed matrices, K not
    formed) against the upper triangles gathered from the formed K (MatrixBand.packed_ww):
    1e-14 of the largest entry; symmetric by construction for a reciprocal table, not known
    for the asymmetric one."""
    for make, sym in ((hysteretic_table, True), (asymmetric_table, False)):
        band = next(b for b in problem(make()).op.soil.bands if isinstance(b, SplineBand))
        assert band.symmetric_by_construction() is sym
        P = (band.T.shape[-1] - 6) * (band.T.shape[-1] - 5) // 2
        sel = slice(3, 3 + min(20, band.idx.size - 3))
        m = len(range(*sel.indices(band.idx.size)))
        packed = band.packed_ww(sel, np.empty((m, P), complex))
        assert "K" not in band.__dict__
        gathered = MatrixBand.packed_ww(band, sel, np.empty((m, P), complex))
        assert rel(packed, gathered) < 1e-14


@pytest.mark.parametrize("N, width", [(1, 32), (7, 3), (70, 32), (64, 32)])
def test_packed_product_is_the_upper_triangles_of_the_product(N, width):
    """farfield.packed_product (the rank-6 term's upper triangles, column blocks from the rows
    they need) against the upper triangles gathered from the formed product U V (upper_pairs'
    order): 1e-15 of the largest entry, for N below, at, and not a multiple of the width."""
    rng = np.random.default_rng(N)
    c = lambda *shape: rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    U, V = c(3, N, 6), c(3, 6, N)
    i, j = upper_pairs(N)
    out = packed_product(U, V, np.full((3, i.size), np.nan, complex), width)
    assert rel(out, (U @ V)[:, i, j]) < 1e-15


def test_single_precision_corrections_keep_the_float64_fixed_point():
    """The marches in correction form with float32 products (CausalSweep.single, the default)
    against float64 marches, on the hysteretic table at 0.5 g to 1e-10: the same residual per
    sweep to 1e-3 relative (the sweeps do not change), no stall at float32's rounding (1e-10
    reached in as many sweeps), max uplift to 1e-9 and histories to 1e-8 relative."""
    with WorkerPool(1) as pool:
        prob = prepare(MODEL, hysteretic_table(), motion(0.5), 0.005, grid=GRID,
                       contact=ContactSettings(enabled=True), pool=pool)
        assert CausalSweep(prob, single=True).hT.dtype == np.float32            # the products are float32
        out = {s: defect_correction(prob, tol=1e-10, single=s) for s in (False, True)}
    assert all(o.converged for o in out.values())
    res = {s: np.array([h.residual for h in o.history]) for s, o in out.items()}
    assert res[True].size == res[False].size and res[True][-1] <= 1e-10
    assert np.abs(res[True] / res[False] - 1).max() < 1e-3
    gap = {s: np.maximum(0.0, -(prob.z0[:, None] + o.y)) for s, o in out.items()}
    assert gap[False].max() > 1e-3
    assert abs(gap[True].max() - gap[False].max()) <= 1e-9 * gap[False].max()
    assert rel(out[True].y, out[False].y) < 1e-8


def test_a_stopped_march_leaves_no_correction_base():
    """A march stopped by its deadline keeps nothing for the next one (CausalSweep.prev): a
    correction on a partial march would start from a history that was not summed."""
    prob = problem(hysteretic_table())
    sweep = CausalSweep(prob, single=True)
    c0 = -prob.f
    sweep.run(c0)
    assert sweep.prev is not None
    x, done, _ = sweep.run(c0, deadline=0.0)
    assert done < prob.f.shape[1] and sweep.prev is None
