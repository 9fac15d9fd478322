"""Surface BEM (subregion method): flexibility and nodal impedance of an interface mesh.

Tractions are piecewise constant on patches: the grid cells of regular meshes (squares of side
``mesh.cell``, or the lx/nx × ly/ny rectangles of a rectangle mesh), equal-area squares of side
``sqrt(area)`` for node lists; displacements are collocated at the patch centres. With a
unit *force* on patch j, ``F[i, j]`` (3×3 block) is the displacement at node i::

    F_ij = (1/A_j) ∫_{patch j} g_static(x_i - y) dy   +   g_regular(x_i - x_j; ω)

The static part (Boussinesq/Cerruti with G*(ω) of the top material: the singular part of the
dynamic kernel at ω) is integrated in closed form over every patch (``patch.static_patch_kernel``,
once at ω = 0, then scaled by G*(0)/G*(ω): it is proportional to 1/G*); the smooth regular part
(``greens.regular_green``) is taken at the patch centre (midpoint rule, O(h²), below the O(h)
error of constant tractions). On grid meshes the kernel is evaluated only at the distinct
integer offsets, and ``regular_green`` only at the distinct radii.

DOF ordering is node-interleaved: ``[ux0, uy0, uz0, ux1, uy1, uz1, ...]`` (m, N).
The nodal impedance ``K = F⁻¹`` maps interface displacements to the forces applied to the soil.

Contact assumption:
  ``"welded"``  full 3×3 coupling (the paper);
  ``"relaxed"`` no coupling between normal and tangential tractions (the xz, yz, zx, zy
                entries of F are dropped before inversion; classical disk formulas).
"""
from __future__ import annotations

import importlib

import numpy as np
import scipy.linalg as sla

from .patch import radial_to_cartesian, static_patch_kernel
from uplift_common.errors import UserInputError

CONTACTS = ("welded", "relaxed")


class BemError(UserInputError):
    """An invalid BEM input (contact keyword, frequency, missing Green's functions)."""


def _regular_green(profile, omega, r, rule):
    """``greens.regular_green`` if available; the exact zero for a homogeneous static case."""
    try:
        greens = importlib.import_module(".greens", __package__)
    except ModuleNotFoundError:
        greens = None
    if greens is not None and hasattr(greens, "regular_green"):
        return greens.regular_green(profile, omega, r, rule=rule)
    if omega == 0 and profile.is_homogeneous:
        z = np.zeros(np.shape(r), dtype=complex)
        return z, z, z, z
    raise BemError("soil_impedance.greens.regular_green is not available: only the static "
                   "homogeneous case (omega = 0, one material) can be computed without it")


class SurfaceBem:
    """BEM operator of one profile on one mesh; holds the frequency-independent parts.

    Parameters
    ----------
    profile : SoilProfile
    mesh : InterfaceMesh
    contact : "welded" or "relaxed"
    rule : passed unchanged to ``greens.regular_green`` (integration rule), or None
    """

    def __init__(self, profile, mesh, contact="welded", rule=None):
        if contact not in CONTACTS:
            raise BemError(f"contact = {contact!r}: use one of {CONTACTS}")
        self.profile, self.mesh, self.contact, self.rule = profile, mesh, contact, rule
        n = mesh.n
        grid = _grid(mesh)
        if grid is not None:
            ij, (hx, hy) = grid
            di = ij[:, None, 0] - ij[None, :, 0]
            dj = ij[:, None, 1] - ij[None, :, 1]
            # distinct offsets: a box of integer offsets, kernels indexed into it
            span = np.abs(di).max(initial=0), np.abs(dj).max(initial=0)
            width = 2 * span[1] + 1
            box = ((di + span[0]) * width + (dj + span[1])).ravel()
            used, self._pair_index = np.unique(box, return_inverse=True)
            self._pair_index = self._pair_index.ravel()
            self._off = np.column_stack([used // width - span[0], used % width - span[1]]) * (hx, hy)
            hax = np.full(used.size, 0.5 * hx)
            hay = np.full(used.size, 0.5 * hy)
        else:
            d = mesh.xy[:, None, :] - mesh.xy[None, :, :]
            self._off = d.reshape(-1, 2)
            self._pair_index = np.arange(n * n)
            hax = hay = np.broadcast_to(mesh.patch_half_sides[None, :], (n, n)).ravel()
        self._grid = grid is not None
        self._static = static_patch_kernel(profile.top, self._off[:, 0], self._off[:, 1], hax, hay, 0.0)
        self._g_static = profile.top.complex_shear_modulus(0.0)
        r = np.hypot(self._off[:, 0], self._off[:, 1])
        scale = max(float(r.max(initial=0.0)), 1.0)
        self._radii, self._radius_index = np.unique(np.round(r / scale, 12) * scale, return_inverse=True)
        self._radius_index = self._radius_index.ravel()
        self.regular_calls = 0

    @property
    def n_dof(self) -> int:
        return 3 * self.mesh.n

    @property
    def n_radii(self) -> int:
        """Number of distinct radii sent to ``regular_green`` per frequency."""
        return self._radii.size

    def flexibility(self, omega: float) -> np.ndarray:
        """Flexibility F(ω), shape (3N, 3N), complex, m/N (node-interleaved DOFs).

        Parameters
        ----------
        omega : float, rad/s, >= 0
        """
        if not np.isfinite(omega) or omega < 0:
            raise BemError(f"omega = {omega!r} rad/s must be finite and >= 0 "
                           "(use K(-ω) = conj K(ω) for negative frequencies)")
        A, B, C, D = _regular_green(self.profile, float(omega), self._radii, self.rule)
        self.regular_calls += 1
        k = self._radius_index
        static = self._static
        scale = self._g_static / self.profile.top.complex_shear_modulus(float(omega))
        if scale != 1.0:   # frequency-dependent (causal) modulus
            static = static * scale
        blocks = static + radial_to_cartesian(np.asarray(A)[k], np.asarray(B)[k],
                                                    np.asarray(C)[k], np.asarray(D)[k],
                                                    self._off[:, 0], self._off[:, 1])
        if self.contact == "relaxed":
            blocks[:, 0:2, 2] = 0.0
            blocks[:, 2, 0:2] = 0.0
        n = self.mesh.n
        F = blocks[self._pair_index].reshape(n, n, 3, 3).transpose(0, 2, 1, 3).reshape(3 * n, 3 * n)
        if not self._grid:
            F = 0.5 * (F + F.T)   # unequal patches: collocation is not exactly reciprocal
        return F

    def solve(self, omega: float, rhs: np.ndarray) -> np.ndarray:
        """F(ω)⁻¹ rhs with one LU factorisation; rhs shape (3N, m)."""
        # LAPACK wants Fortran order: factor Fᵀ (a free view) and solve with trans=1
        lu = sla.lu_factor(self.flexibility(omega).T, overwrite_a=True, check_finite=False)
        return sla.lu_solve(lu, rhs, trans=1, check_finite=False)

    def impedance(self, omega: float) -> np.ndarray:
        """Nodal impedance K(ω) = F(ω)⁻¹, shape (3N, 3N), complex, N/m, symmetrised."""
        K = sla.inv(self.flexibility(omega).T, overwrite_a=True, check_finite=False).T
        return 0.5 * (K + K.T)


def _grid(mesh):
    """Integer grid coordinates (n, 2) and cell sides (hx, hy) of a regular mesh, else None.

    Square-cell meshes use ``mesh.cell``; a rectangle with non-square cells (cell None) has
    sides lx/nx, ly/ny. Node lists have no grid (pairwise assembly, equal-area squares).
    """
    if mesh.cell is not None:
        h = (mesh.cell, mesh.cell)
    elif mesh.kind == "rectangle" and len(mesh.size) == 2:
        h = (mesh.size[0] / np.unique(np.round(mesh.xy[:, 0], 9)).size,
             mesh.size[1] / np.unique(np.round(mesh.xy[:, 1], 9)).size)
    else:
        return None
    rel = (mesh.xy - mesh.xy[0]) / h
    ij = np.rint(rel).astype(int)
    if not np.allclose(rel, ij, rtol=0, atol=1e-6):
        return None
    return ij, h


def nodal_impedance(profile, mesh, omega, contact="welded", rule=None) -> np.ndarray:
    """K(ω) = F(ω)⁻¹ for one frequency; shape (3N, 3N), DOFs [ux0, uy0, uz0, ux1, ...]."""
    return SurfaceBem(profile, mesh, contact, rule).impedance(omega)


def nodal_dofs(n: int) -> list[str]:
    """Labels of the nodal DOFs: ['ux0', 'uy0', 'uz0', 'ux1', ...]."""
    return [f"u{c}{i}" for i in range(n) for c in "xyz"]
