"""Passivity enforcement from ``CHOLESKY_SWEEP_NA`` active DOFs: the grid re-screen bounded by the change
(``passivity._Rescreen``) against the full screen, the planes from partial eigensolutions against the full
eigh's, and an enforced model of 400 DOFs against the exact (Hamiltonian) test."""
import numpy as np
import pytest

import soil_impedance.passivity as pv
from helpers.passive_models import with_notch
from soil_impedance.rational import RationalModel

F_MAX = 25.0


def _low_rank_model(n, rank=6, seed=0):
    """A passive model of n DOFs whose residues have low rank (so that the exact test's eigenproblem,
    Σ rank R_k, stays small at hundreds of DOFs): D and E ⪰ 0 of full rank (kernel matrices), a Maxwell
    element k·s/(s + a)·W and a damped oscillator −α ω0²/(s² + 2ζω0 s + ω0²)·W', W and W' PSD of rank
    ``rank`` (each term passive: Im K(iω)/ω ⪰ 0)."""
    rng = np.random.default_rng(seed)
    x = np.linspace(-1.0, 1.0, n)
    w_ref = 2 * np.pi * F_MAX
    kern = np.eye(n) + 0.3 * np.exp(-4 * np.abs(x[:, None] - x[None, :]))

    def shape():
        B = rng.standard_normal((n, rank)) / np.sqrt(rank)
        return B @ B.T
    a = 0.6 * w_ref
    poles, res = [-a + 0j], [-0.5 * a * shape() + 0j]                    # k s/(s + a) W, k = 0.5
    w0, z = 0.4 * w_ref, 0.2
    p = -z * w0 + 1j * w0 * np.sqrt(1 - z * z)
    r = -0.3 * w0 ** 2 / (p - np.conj(p)) * shape()
    poles += [p, np.conj(p)]
    res += [r, np.conj(r)]
    poles, res = np.array(poles), np.array(res)
    static = np.real(np.sum(-res / poles[:, None, None], axis=0))
    return RationalModel(poles, res, 3 * kern - static + 2 * np.eye(n), 0.05 / w_ref * kern,
                         [f"d{i}" for i in range(n)], {"f_max_hz": F_MAX})


def _notched(n, seed=0):
    """``_low_rank_model`` with two violations the dense grid sees (half-widths 0.12 and 0.15 Hz)."""
    x = np.linspace(-1.0, 1.0, n)
    model = with_notch(_low_rank_model(n, seed=seed), 6.0, 2e-2, 1.5, np.cos(np.pi * x))
    return with_notch(model, 15.0, 1e-2, 1.5, np.sin(2 * np.pi * x) + 0.3)


@pytest.mark.slow
def test_rescreen_finds_the_full_screens_bands_and_factorises_only_where_the_change_reaches():
    """600 DOFs, two grid-visible violations: the re-screen's bands are the full screen's, on the model
    and after two changes of its coefficients (the notches halved; then E lowered along one pattern,
    G indefinite from 0 up); after the notches' change it factorises fewer than half the grid, with no
    change only the violating points."""
    sc = _notched(600).scaled
    grid = pv._default_grid()
    rs = pv._Rescreen(grid)
    first = rs(sc)[0]
    assert first == pv._screen(sc, grid)[0] and len(first) == 2
    assert rs.calls[-1] == grid.size
    m = sc.poles.size
    C = np.array(sc.C)
    C[m - 4:m] *= 0.5                                       # the two notches' coefficients
    halved = sc.with_coefficients(C)
    bands = rs(halved)[0]
    assert bands == pv._screen(halved, grid)[0] and len(bands) == 2
    assert rs.calls[-1] < grid.size / 2, rs.calls
    rs(halved)
    inside = sum(int(np.sum((grid > lo) & (grid < hi))) for lo, hi in bands)
    assert rs.calls[-1] == inside
    v = np.cos(3 * np.pi * np.linspace(-1, 1, sc.na))
    v /= np.linalg.norm(v)
    top = (pv._M_basis(grid, sc.poles) @ np.einsum("i,bij,j->b", v, C, v)).max()     # max of vᵀ M(ν) v
    C[m + 1] -= 2.0 * top * np.outer(v, v)                  # vᵀ M(ν) v < 0 at every ν
    lowered = sc.with_coefficients(C)
    assert rs(lowered)[0] == pv._screen(lowered, grid)[0] == [(0.0, np.inf)]


def test_refined_rescreen_sees_a_band_between_the_grids_points():
    """A violation 0.005 Hz wide at 13.0123 Hz (ζ = 2e-4), between the grid's points: the re-screen sees
    nothing; refined with the exact band it factorises only the REFINE_POINTS new points and returns one
    band around the exact one, narrower than a grid step."""
    base = _low_rank_model(150)
    model = with_notch(base, 13.0123, 2e-4, 3.0, np.cos(np.pi * np.linspace(-1, 1, 150)))
    sc = model.scaled
    exact = pv._assess(sc, method="hamiltonian")["bands"]
    assert len(exact) == 1
    grid = pv._default_grid()
    rs = pv._Rescreen(grid)
    assert rs(sc)[0] == []
    rs.refine(exact)
    (lo, hi), = rs(sc)[0]
    assert rs.calls[-1] == pv.REFINE_POINTS
    (elo, ehi), = exact
    assert lo <= elo < ehi <= hi and hi - lo < grid[1] - grid[0]


@pytest.mark.parametrize("seed", [0, 1])
def test_planes_from_partial_eigensolutions_are_the_full_eighs(seed):
    """On 150 DOFs with two violations (exact bands), the planes from the eigenpairs below the margin only
    (a Cholesky factorisation first, then dsyevr on the ones that fail) are the full eigh's: the same
    frequencies, the rank-one planes v vᵀ and the deficit planes to round-off, the same sampled depth."""
    sc = _notched(150, seed).scaled
    bands = pv._assess(sc, method="hamiltonian")["bands"]
    assert len(bands) == 2
    margin = 1e-3
    full, w_full = pv._planes(sc, bands, margin, partial=False)
    part, w_part = pv._planes(sc, bands, margin, partial=True)
    assert full.size > 0 and np.array_equal(full.nu1, part.nu1) and np.array_equal(full.nud, part.nud)
    P_full = np.einsum("pi,pj->pij", full.V, full.V)
    P_part = np.einsum("pi,pj->pij", part.V, part.V)
    assert np.abs(P_full - P_part).max() < 1e-8
    assert full.N.shape == part.N.shape and (full.N.size == 0 or np.abs(full.N - part.N).max() < 1e-8)
    assert w_part[1] == w_full[1] and w_part[0] == pytest.approx(w_full[0], rel=1e-9, abs=1e-14)


@pytest.mark.slow
def test_enforced_model_of_400_dofs_is_passive_by_the_exact_test():
    """400 active DOFs (the re-screen and the partial planes): the enforcement makes the model with two
    violations passive, as the exact Hamiltonian test confirms on the returned model, poles unchanged and
    a change small against the response."""
    model = _notched(400)
    assert model.scaled.na >= pv.CHOLESKY_SWEEP_NA
    assert not pv._assess(model.scaled, method="hamiltonian")["passive"]
    f = np.linspace(0, F_MAX, 51)
    fixed, rep, it = pv.enforce_passivity(model, f, margin=1e-3, max_iter=20)
    assert rep.passive and it >= 1 and np.array_equal(fixed.poles, model.poles)
    exact = pv._assess(fixed.scaled, method="hamiltonian")
    assert exact["passive"] and exact["bands"] == [], exact["bands"]
    K = model.frequency_response(f)
    assert np.abs(fixed.frequency_response(f) - K).max() < 0.05 * np.abs(K).max()
