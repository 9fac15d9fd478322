"""Winkler mattress route (paper §4.2): springs, dashpots and RCC-G modal damping.

Springs
  * ``springs_from_moduli``: subgrade moduli kv, kh (N/m^3) times tributary area.
  * ``springs_from_rigid_impedance``: the rigid static 6x6 impedance shared by tributary area,
    kv_i = Kv A_i / sum A, kh_i = Kh A_i / sum A. Area sharing reproduces Kv and Kh exactly
    but gives the rocking stiffness Kv I/A (for a disk Kv R^2/4 = 0.375 Kr of the rigid disk).
    No non-negative spring distribution on a disk can reproduce both: it would need
    Kr/Kv = 2R^2/3 while springs give at most R^2/2 (all on the rim). ``match="rocking"``
    scales the vertical springs to the exact rocking stiffness instead (the paper tunes
    springs iteratively on the rocking frequencies, §4.2).
  * ``springs_from_nodal_diagonal``: K_so = Diag(K_s22(omega = 0)) of a nodal (3N, 3N) static
    impedance, DOFs [ux0, uy0, uz0, ux1, ...] (the paper's flexible-raft choice).
Dashpots
  * ``dashpots_from_waves``: cv_i = rho Vp A_i, ch_i = rho Vs A_i (1D plane-wave radiation).
  * ``springs_from_rigid_impedance(..., C6=...)``: rigid 6x6 dashpots (e.g. Im K(omega)/omega)
    shared by area like the springs.
Modal damping (RCC-G rule, paper §4.2): ``rccg_modal_damping``. Use it *instead of*
dashpots (soil damping must not be counted twice).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from uplift_common.lazy import lazy_module

from .errors import StructureError
from .model import StructureModel
from .soil_interface import WinklerSoil, _rigid

# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sla = lazy_module("scipy.linalg")


def disk_static_stiffness(G: float, nu: float, R: float) -> np.ndarray:
    """Rigid circular disk on a homogeneous half-space, static (6, 6), diagonal:
    Kh = 8GR/(2-nu), Kv = 4GR/(1-nu), Kr = 8GR^3/(3(1-nu)), Kt = 16GR^3/3."""
    kh, kv = 8 * G * R / (2 - nu), 4 * G * R / (1 - nu)
    kr, kt = 8 * G * R**3 / (3 * (1 - nu)), 16 * G * R**3 / 3
    return np.diag([kh, kh, kv, kr, kr, kt])


def springs_from_moduli(xy, area, kv, kh, cv=0.0, ch=0.0) -> WinklerSoil:
    area = np.asarray(area, float)
    return WinklerSoil(xy, kv * area, kh * area, cv * area, ch * area)


def _share(K6, xy, area, match):
    area = np.asarray(area, float)
    w = area / area.sum()
    kv = K6[2, 2] * w
    if match == "rocking":
        x, y = np.asarray(xy, float).T
        kr = 0.5 * (K6[3, 3] + K6[4, 4])
        kv = kv * kr / (0.5 * (kv * (x * x + y * y)).sum())
    elif match != "vertical":
        raise StructureError(f"match = {match!r} must be 'vertical' or 'rocking'")
    return kv, K6[0, 0] * w, K6[1, 1] * w


def springs_from_rigid_impedance(K6, xy, area, C6=None, match: str = "vertical") -> WinklerSoil:
    """Share a rigid static 6x6 stiffness (and optional 6x6 dashpots) by tributary area.
    match="vertical": kv_i = Kv A_i / sum A (Kv exact, rocking Kv I/A); "rocking": the same
    shape scaled so that the mean rocking stiffness is exact (Kv then too large)."""
    K6 = np.real(np.asarray(K6))
    if K6.shape != (6, 6) or K6[2, 2] <= 0 or K6[0, 0] < 0:
        raise StructureError(f"rigid static impedance must be (6, 6) with Kv > 0, got {K6.shape}")
    kv, kx, ky = _share(K6, xy, area, match)
    cv = cx = cy = 0.0
    if C6 is not None:
        cv, cx, cy = _share(np.real(np.asarray(C6)), xy, area, match)
    return WinklerSoil(xy, kv, kx, cv, cx, ky=ky, cy=cy)


def springs_from_nodal_diagonal(kdiag, xy, cdiag=None) -> WinklerSoil:
    """Springs (and dashpots) from the diagonal (3N,) of a nodal static impedance."""
    xy = np.asarray(xy, float)
    n = xy.shape[0]
    k = np.real(np.asarray(kdiag)).reshape(n, 3)
    c = np.zeros((n, 3)) if cdiag is None else np.real(np.asarray(cdiag)).reshape(n, 3)
    return WinklerSoil(xy, k[:, 2], k[:, 0], c[:, 2], c[:, 0], ky=k[:, 1], cy=c[:, 1])


def dashpots_from_waves(area, rho: float, vp: float, vs: float):
    """(cv, ch) (N,), N s/m: rho Vp A_i and rho Vs A_i."""
    area = np.asarray(area, float)
    return rho * vp * area, rho * vs * area


# ---- modes on soil springs and the RCC-G composite damping ---------------------------------
@dataclass(frozen=True, eq=False)
class SoilModes:
    """Modes of the structure on the soil springs with the raft bonded (w = raft trace).
    freq (m,) Hz; shapes (n_struct, m) mass-normalised; energy: strain-energy fractions,
    structure (m,), soil per direction (m, 6) [ux, uy, uz, rx, ry, rz]; ratio (m,) the
    composite damping ratios when computed by rccg_modal_damping."""
    freq: np.ndarray
    shapes: np.ndarray
    structure_energy: np.ndarray
    soil_energy: np.ndarray
    ratio: np.ndarray | None = None


def modes_on_soil(model: StructureModel, soil) -> SoilModes:
    """All modes of the structure on the soil's static springs, raft bonded to the soil."""
    ns = model.n_struct
    K = model.stiffness.toarray()
    Kr = _rigid(soil.static_stiffness(), model.raft.xy)
    rd = model.raft_dofs
    Ksys = K.copy()
    Ksys[np.ix_(rd, rd)] += Kr
    m = model.mass
    a, z = np.flatnonzero(m > 0), np.flatnonzero(m <= 0)
    Kaa = Ksys[np.ix_(a, a)]
    X = None
    if z.size:
        X = -np.linalg.solve(Ksys[np.ix_(z, z)], Ksys[np.ix_(z, a)])
        Kaa = Kaa + Ksys[np.ix_(a, z)] @ X
    w2, phi_a = sla.eigh(0.5 * (Kaa + Kaa.T), np.diag(m[a]))
    phi = np.zeros((ns, a.size))
    phi[a] = phi_a
    if z.size:
        phi[z] = X @ phi_a
    Es = 0.5 * np.einsum("im,ij,jm->m", phi, K, phi)
    q = phi[rd]
    Ed = 0.5 * q * (Kr @ q)                    # (6, m) directional split
    tot = Es + Ed.sum(axis=0)
    return SoilModes(np.sqrt(np.maximum(w2, 0)) / (2 * np.pi), phi, Es / tot, (Ed / tot).T)


def rccg_modal_damping(model: StructureModel, soil, structure_ratio=0.07, radiation=None,
                       soil_material: float = 0.0):
    """Composite modal damping per the RCC-G rule, as a matrix C (n_struct, n_struct).

    Per mode k of the structure on springs: xi_k = xi_struct e_struct,k
      + sum_j (xi_rad,j(f_k) + soil_material) e_soil,j,k, with e the strain-energy fractions.
    radiation : callable f (Hz) -> (6,) directional radiation ratios, or a tuple
      (freqs (nf,), ratios (nf, 6)) interpolated linearly; None -> 0.
    Returns (C, SoilModes with .ratio). C = M Phi diag(2 xi w) Phi^T M acts on motions
    relative to the free field; use it with soil springs *without* dashpots.
    """
    sm = modes_on_soil(model, soil)
    f = sm.freq
    if radiation is None:
        rad = np.zeros((f.size, 6))
    elif callable(radiation):
        rad = np.array([np.broadcast_to(radiation(fk), (6,)) for fk in f], float)
    else:
        ff, rr = np.asarray(radiation[0], float), np.asarray(radiation[1], float)
        rad = np.column_stack([np.interp(f, ff, rr[:, j]) for j in range(6)])
    xi = structure_ratio * sm.structure_energy + ((rad + soil_material) * sm.soil_energy).sum(axis=1)
    Mphi = model.mass[:, None] * sm.shapes
    C = (Mphi * (2 * xi * 2 * np.pi * f)) @ Mphi.T
    return C, SoilModes(sm.freq, sm.shapes, sm.structure_energy, sm.soil_energy, xi)


def radiation_ratios(freqs, K6, K6_static=None):
    """Directional damping ratios xi_j(f) = Im K_jj(f) / (2 K_jj(0)) from a rigid impedance
    K6 (nf, 6, 6) (e^{+i w t}); for a spring K(0) with dashpot Im K/w this is the ratio at
    resonance. Returns (freqs, (nf, 6)) for rccg_modal_damping(radiation=...)."""
    K6 = np.asarray(K6)
    K0 = np.real(K6[0] if K6_static is None else K6_static)
    d = np.diagonal(K6, axis1=1, axis2=2)
    return np.asarray(freqs, float), np.imag(d) / (2 * np.real(np.diag(K0)))


def disk_radiation_ratios(freq_hz, R: float, vs: float) -> np.ndarray:
    """Approximate radiation damping ratios (6,) of a rigid disk on a homogeneous
    half-space, xi_j = a0 c_j / 2 with a0 = 2 pi f R / Vs and the usual dashpot coefficients
    (Veletsos & Verbic 1973, Gazetas 1991, nu ~ 0.3): c_h = 0.58, c_v = 0.85,
    c_r = 0.3 a0^2 / (1 + a0^2), c_t = 0.2 a0^2 / (1 + a0^2). Order [ux, uy, uz, rx, ry, rz].
    For use as ``rccg_modal_damping(radiation=lambda f: disk_radiation_ratios(f, R, vs))``
    when no BEM impedance is at hand; with one, prefer ``radiation_ratios``."""
    a0 = 2 * np.pi * float(freq_hz) * R / vs
    xr = 0.15 * a0**3 / (1 + a0**2)
    return np.array([0.29 * a0, 0.29 * a0, 0.425 * a0, xr, xr, 0.1 * a0**3 / (1 + a0**2)])
