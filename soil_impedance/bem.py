"""Surface BEM (subregion method): flexibility and nodal impedance of an interface mesh.

Tractions are piecewise constant on cells: the grid cells of regular meshes (squares of side
``mesh.cell``, or the lx/nx × ly/ny rectangles of a rectangle mesh), the true polygons of a
finite-element mesh (kind "cells": triangles and quadrilaterals), equal-area squares of side
``sqrt(area)`` for node lists; displacements are collocated at the cell centres: the square
centres, or the **area centroids** of the cells (kind "cells"), which are the mesh's nodes,
hence the structure's interface nodes and the points where the contact gaps are measured. With
a unit *force* on cell j, ``F[i, j]`` (3×3 block) is the displacement at node i::

    F_ij = ∫_{cell j} g_static(x_i - y) φ_j(y) dy   +   g_regular(|x_i - s_j|; ω)

with φ_j = 1/A_j and s_j = x_j, except in the cells of a finite-element mesh that share an edge
with the raft's outline (``EDGE_TRACTIONS`` = "sqrt"): there φ_j is the edge-singular shape of a
rigid raft's contact traction, ~ 1/sqrt(distance to the outline), as strips of constant value
(``edge_strips``; total force 1), and s_j its force centroid (s_j = x_j for i = j: the self term
at r = 0, see ``_IrregularOperator``). Constant tractions on such a mesh
converge at first order only, the error at the outline; with the edge shape at order ~1.5 and
5 times smaller at h = R/10 (docs/raft.md). Grids and node lists are unchanged.

The static part (Boussinesq/Cerruti with G*(ω) of the top material: the singular part of the
dynamic kernel at ω) is integrated in closed form over every cell, exactly from any field point
(inside, on or outside the cell): rectangles by corner primitives (``patch.static_patch_kernel``),
polygons (and the strips of an outline cell) by edge decomposition (``patch.polygon_integrals``).
The smooth regular part (``greens.regular_green``) is taken at the offset from the cell's force
centroid (one-point rule exact for a kernel linear over the cell, O(h²): a cell quadrature
would cost several kernel values per pair for no gain in order).

Grid meshes: the kernel is evaluated only at the distinct integer offsets, and
``regular_green`` only at the distinct radii (this path's arithmetic is unchanged: its tables
are cached). Irregular meshes (node lists, cells): memory O(n²) reals, never n² radii through
the Bessel transforms: the six static basis integrals are stored per pair (48 bytes), and per
frequency the regular kernel is evaluated on a radial grid refined until a cubic spline meets
``RADIAL_TOL`` (``RadialRegular``), interpolated at the pair radii and assembled into F by
blocks of rows; F is then symmetrised in place (collocation on unequal cells is not exactly
reciprocal).

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
from uplift_common.lazy import lazy_module

from .patch import radial_to_cartesian, static_patch_kernel
from uplift_common.errors import UserInputError

# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sla = lazy_module("scipy.linalg")

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
    radial_tol : irregular meshes only: relative interpolation tolerance of the regular part
        (None: ``RADIAL_TOL``; 0: ``regular_green`` at every pair radius, for verification)
    edge : the traction scheme of a finite-element mesh's outline cells, "sqrt-<m>" (m strips)
        or "constant"; None: ``edge_tractions(mesh)`` (what a table's provenance records).
        Ignored by grids and node lists (constant tractions).
    """

    def __init__(self, profile, mesh, contact="welded", rule=None, radial_tol=None, edge=None):
        if contact not in CONTACTS:
            raise BemError(f"contact = {contact!r}: use one of {CONTACTS}")
        self.profile, self.mesh, self.contact, self.rule = profile, mesh, contact, rule
        grid = _grid(mesh)
        self._grid = grid is not None
        self.regular_calls = 0
        if grid is None:                      # irregular mesh: bounded memory, see _IrregularOperator
            self._irregular = _IrregularOperator(profile, mesh, contact, rule, radial_tol, edge)
            return
        self._irregular = None
        ij, (hx, hy) = grid
        di = ij[:, None, 0] - ij[None, :, 0]
        dj = ij[:, None, 1] - ij[None, :, 1]
        # distinct offsets: a box of integer offsets, kernels indexed into it
        span = np.abs(di).max(initial=0), np.abs(dj).max(initial=0)
        width = 2 * span[1] + 1
        box = ((di + span[0]) * width + (dj + span[1])).ravel()
        used, self._pair_index = np.unique(box, return_inverse=True)
        self._pair_index = self._pair_index.ravel()
        self._ij = ij
        self._off_int = np.column_stack([used // width - span[0], used % width - span[1]])
        self._off = self._off_int * (hx, hy)
        hax = np.full(used.size, 0.5 * hx)
        hay = np.full(used.size, 0.5 * hy)
        self._static = static_patch_kernel(profile.top, self._off[:, 0], self._off[:, 1], hax, hay, 0.0)
        self._g_static = profile.top.complex_shear_modulus(0.0)
        r = np.hypot(self._off[:, 0], self._off[:, 1])
        scale = max(float(r.max(initial=0.0)), 1.0)
        self._radii, self._radius_index = np.unique(np.round(r / scale, 12) * scale, return_inverse=True)
        self._radius_index = self._radius_index.ravel()

    @property
    def n_dof(self) -> int:
        return 3 * self.mesh.n

    @property
    def n_radii(self) -> int:
        """Number of distinct radii sent to ``regular_green`` per frequency (irregular meshes: the
        radial interpolation grid of the last frequency, 0 before any)."""
        if self._irregular is not None:
            return self._irregular.n_radii
        return self._radii.size

    def flexibility(self, omega: float) -> np.ndarray:
        """Flexibility F(ω), shape (3N, 3N), complex, m/N (node-interleaved DOFs).

        Parameters
        ----------
        omega : float, rad/s, >= 0
        """
        _check_omega(omega)
        if self._irregular is not None:
            self.regular_calls += 1
            return self._irregular.flexibility(float(omega))
        blocks = self.offset_blocks(omega)
        n = self.mesh.n
        F = blocks[self._pair_index].reshape(n, n, 3, 3).transpose(0, 2, 1, 3).reshape(3 * n, 3 * n)
        if not self._grid:
            F = 0.5 * (F + F.T)   # unequal patches: collocation is not exactly reciprocal
        return F

    def offset_blocks(self, omega: float) -> np.ndarray:
        """Grid meshes: the 3×3 blocks of F(ω) at the distinct integer offsets between nodes,
        shape (n_off, 3, 3), complex, m/N; block k is F_ij for every pair whose integer grid offset
        ``grid_index[i] - grid_index[j]`` is ``grid_offsets[k]``. F is gathered from
        them (``flexibility``); the fast solver (``fastsolve``) convolves with them."""
        if self._irregular is not None:
            raise BemError("offset_blocks: an irregular mesh (node list or cells) has no grid offsets")
        _check_omega(omega)
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
        return blocks

    @property
    def grid_index(self) -> np.ndarray | None:
        """Integer grid coordinates (n, 2) of the nodes (grid meshes; None otherwise)."""
        return None if self._irregular is not None else self._ij

    @property
    def grid_offsets(self) -> np.ndarray | None:
        """The distinct integer offsets (n_off, 2) of ``offset_blocks`` (grid meshes; else None)."""
        return None if self._irregular is not None else self._off_int

    def solve(self, omega: float, rhs: np.ndarray) -> np.ndarray:
        """F(ω)⁻¹ rhs with one LU factorisation; rhs shape (3N, m)."""
        # LAPACK wants Fortran order: factor Fᵀ (a free view) and solve with trans=1
        lu = sla.lu_factor(self.flexibility(omega).T, overwrite_a=True, check_finite=False)
        return sla.lu_solve(lu, rhs, trans=1, check_finite=False)

    def impedance(self, omega: float) -> np.ndarray:
        """Nodal impedance K(ω) = F(ω)⁻¹, shape (3N, 3N), complex, N/m, symmetrised."""
        K = sla.inv(self.flexibility(omega).T, overwrite_a=True, check_finite=False).T
        return 0.5 * (K + K.T)


def _check_omega(omega):
    if not np.isfinite(omega) or omega < 0:
        raise BemError(f"omega = {omega!r} rad/s must be finite and >= 0 "
                       "(use K(-ω) = conj K(ω) for negative frequencies)")


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


#: relative tolerance of the radial interpolation of the regular kernel on irregular meshes: the
#: cubic spline through every other node of the radial grid must match the skipped nodes within
#: RADIAL_TOL × max|regular part| (a bound on the error of the spline through all nodes, about
#: 16 times smaller for a smooth kernel). Part of this module, so of the sweep's code digest.
RADIAL_TOL = 1.0e-6
#: most radial grid nodes per frequency (refinement stops there; ~21 kB of Bessel values each)
RADIAL_MAX_NODES = 1 << 12
#: pairs (i, j) assembled at once: bounds the temporaries of the irregular assembly (~30 arrays
#: of this many float64, about 16 MB each)
CHUNK_PAIRS = 1 << 16


def max_pair_distance(xy) -> float:
    """Largest distance between two of the points xy (n, 2), m, in O(n log n) (convex hull)."""
    xy = np.asarray(xy, dtype=float)
    if xy.shape[0] < 2:
        return 0.0
    pts = xy
    if xy.shape[0] > 3:
        from scipy.spatial import ConvexHull, QhullError
        try:
            pts = xy[ConvexHull(xy).vertices]
        except QhullError:                 # all on one line: the extreme points along it
            u = xy - xy[0]
            axis = u[np.argmax(np.hypot(u[:, 0], u[:, 1]))]
            s = u @ axis
            pts = xy[[np.argmin(s), np.argmax(s)]]
    d = pts[:, None, :] - pts[None, :, :]
    return float(np.hypot(d[..., 0], d[..., 1]).max())


#: traction shape in the cells of a finite-element mesh (kind "cells") that share an edge with the
#: raft's outline (outer boundary and holes): "sqrt", 1/sqrt(t) across the cell from that edge
#: (``edge_strips``), or "constant" (every cell; the scheme before, kept for verification)
EDGE_TRACTIONS = "sqrt"
#: strips of constant traction per outline cell, bounded by the lines t_k = (k/m)², k = 0..m
EDGE_STRIPS = 8


def edge_tractions(mesh) -> str:
    """The traction scheme of a mesh's cells, as recorded in a table's provenance: "constant"
    for grids and node lists, else ``EDGE_TRACTIONS`` with its strip count ("sqrt-8")."""
    if mesh.cells is None or _grid(mesh) is not None or EDGE_TRACTIONS == "constant":
        return "constant"
    return f"{EDGE_TRACTIONS}-{EDGE_STRIPS}"


def outline_edges(cells):
    """The edges of the raft's outline (outer boundary and holes): those of one cell only.

    Parameters
    ----------
    cells : ndarray (n, 4, 2), m     counter-clockwise cells, triangles with vertex 2 repeated

    Returns
    -------
    ndarray (n, 4) bool: ``[j, k]`` True when edge k of cell j (vertex k to its successor; for a
    triangle, edges 0, 1, 2 are v0v1, v1v2, v2v0) is on the outline. Vertices are matched by
    their exact coordinates (the cells were cut from one point list); an edge of one cell that
    lies along edges of other cells (a non-conforming joint) is not on the outline.
    """
    cells = np.asarray(cells, dtype=float)
    n = cells.shape[0]
    tri = np.all(cells[:, 2] == cells[:, 3], axis=1)
    order = np.where(tri[:, None], [0, 1, 2, 0], [0, 1, 2, 3])      # triangle: v0 v1 v2 (v0)
    verts = np.take_along_axis(cells, order[:, :, None], axis=1)
    _, vid = np.unique(verts.reshape(-1, 2), axis=0, return_inverse=True)
    vid = vid.reshape(n, 4)
    nxt = np.where(tri[:, None], [1, 2, 0, 0], [1, 2, 3, 0])
    a, b = vid, np.take_along_axis(vid, nxt, axis=1)
    live = ~(tri[:, None] & (np.arange(4) == 3))
    key = np.minimum(a, b).astype(np.int64) * (vid.max() + 1) + np.maximum(a, b)
    uniq, inverse, counts = np.unique(key[live], return_inverse=True, return_counts=True)
    out = np.zeros((n, 4), dtype=bool)
    out[live] = counts[inverse.ravel()] == 1
    # a non-conforming joint (a hanging node: cells touching along an edge without sharing its
    # nodes) leaves edges of one cell inside the raft: an edge overlapping another such edge of
    # opposite direction on the same line is not on the outline
    j, k = np.nonzero(out)
    if j.size > 1:
        a = verts[j, k]
        b = np.take_along_axis(verts, nxt[:, :, None], axis=1)[j, k]
        e = b - a
        length = np.hypot(e[:, 0], e[:, 1])
        t = e / length[:, None]
        tol = 1e-9 * max(float(np.abs(cells).max()), 1e-300)
        inner = np.zeros(j.size, dtype=bool)
        for i0 in range(0, j.size, 1024):
            i1 = min(j.size, i0 + 1024)
            ti = t[i0:i1, None, :]
            anti = (ti * t[None]).sum(-1) < -1 + 1e-9
            da, db = a[None] - a[i0:i1, None], b[None] - a[i0:i1, None]
            off = np.maximum(np.abs(ti[..., 0] * da[..., 1] - ti[..., 1] * da[..., 0]),
                             np.abs(ti[..., 0] * db[..., 1] - ti[..., 1] * db[..., 0]))
            sa, sb = (ti * da).sum(-1), (ti * db).sum(-1)       # the other edge along this one
            overlap = np.minimum(np.maximum(sa, sb), length[i0:i1, None]) - np.maximum(np.minimum(sa, sb), 0.0)
            inner[i0:i1] = np.any(anti & (off <= tol) & (overlap > tol), axis=1)
        out[j[inner], k[inner]] = False
    return out


def edge_strips(mesh, scheme=None):
    """The edge-singular traction shape of the cells sharing an edge with the raft's outline
    (``scheme`` "sqrt-<m>"; None: ``edge_tractions(mesh)``).

    A rigid raft's contact traction grows like 1/sqrt(d) toward its outline (d: distance to
    it). In such a cell (its longest outline edge AB, the opposite side DC, or the opposite
    vertex C = D of a triangle) the cell is the image of the unit square by
    y(s, t) = (1-t)(A + s(B-A)) + t(D + s(C-D)): t = 0 on the outline, 1 across the cell
    (t = d/H in a triangle, H its height over AB). The shape is 1/sqrt(t) taken as its mean on
    m = ``EDGE_STRIPS`` strips t_k <= t <= t_(k+1), t_k = (k/m)² (quadrilaterals, exact images
    of the square's strips), scaled so that the cell's total force is its nodal force: strip k
    carries the fraction f_k = [P(t_(k+1)) - P(t_k)]/P(1) of it, P(t) = ∫₀ᵗ τ^(-1/2) ρ(τ) dτ =
    2ρ0 √t + (2/3)ρ1 t^(3/2), ρ(t) = ρ0 + ρ1 t the area per unit t (linear in t: ρ0 the cross
    product (B-A) × ((D-A) + (C-B))/2, ρ1 = 2(area - ρ0)). The strips are polygons: the static kernel is
    integrated over them exactly (``patch.polygon_integrals``), so the cell's static integral
    is exact for this shape. The strip means regularise the singularity: the largest traction,
    on the strip along the outline, is about m times the cell's mean (0.75 m in a triangle).

    Returns
    -------
    cells : int array (k,)            the outline cells
    strips : ndarray (k, m, 4, 2), m  their strips, counter-clockwise
    weights : ndarray (k, m), 1/m²    traction of each strip per unit force on the cell, f/area
    source : ndarray (n, 2), m        every cell's force centroid (the node, but Σ f_k c_k for an
                                      outline cell, c_k the strip centroids): where the regular
                                      part is taken (one-point rule exact for linear kernels)
    """
    from .mesh import polygon_area_centroid
    scheme = edge_tractions(mesh) if scheme is None else scheme
    m = int(scheme.split("-")[1])
    cells = mesh.cells
    on = outline_edges(cells)
    tri = np.all(cells[:, 2] == cells[:, 3], axis=1)
    length = np.hypot(*(np.roll(cells, -1, axis=1) - cells).transpose(2, 0, 1))
    # a triangle's edge 2 is v2 -> v0 (stored as v3 -> v0 with v3 = v2, edge 2 being v2 -> v3 = 0)
    length[tri, 2] = length[tri, 3]
    which = np.flatnonzero(on.any(axis=1))
    k = np.argmax(np.where(on[which], length[which], -1.0), axis=1)
    P = cells[which]
    idx = np.arange(which.size)
    t3 = tri[which]
    A = P[idx, k]
    B = P[idx, np.where(t3, (k + 1) % 3, (k + 1) % 4)]
    C = P[idx, np.where(t3, (k + 2) % 3, (k + 2) % 4)]
    D = np.where(t3[:, None], C, P[idx, (k + 3) % 4])
    t = (np.arange(m + 1) / m) ** 2
    lo, hi = t[:-1, None], t[1:, None]
    strips = np.stack([A[:, None] + lo * (D - A)[:, None], B[:, None] + lo * (C - B)[:, None],
                       B[:, None] + hi * (C - B)[:, None], A[:, None] + hi * (D - A)[:, None]], axis=2)
    ab, side = B - A, 0.5 * ((D - A) + (C - B))
    rho0 = ab[:, 0] * side[:, 1] - ab[:, 1] * side[:, 0]
    rho1 = 2 * (mesh.area[which] - rho0)
    prim = 2 * rho0[:, None] * np.sqrt(t) + (2 / 3) * rho1[:, None] * t ** 1.5
    frac = np.diff(prim, axis=1) / prim[:, -1:]
    area, centroid = polygon_area_centroid(strips.reshape(-1, 4, 2))
    area, centroid = area.reshape(which.size, m), centroid.reshape(which.size, m, 2)
    source = mesh.xy.copy()
    source[which] = np.einsum("km,kmc->kc", frac, centroid)
    return which, strips, frac / area, source


class RadialRegular:
    """The regular kernel (A, B, C, D)(r) of one frequency: exact at r = 0, and on [r_lo, r_max]
    a uniform radial grid interpolated by cubic splines (not-a-knot).

    r_lo is the smallest non-zero pair distance of the mesh: the pair radii are 0 (the self
    terms) and [r_lo, r_max], and the spline never spans the kernel's non-smooth point r = 0
    (terms like r² ln r: a spline across it converges like h² only, measured). Grid spacing: at
    most the smaller of ``h0`` (the mesh's typical cell size) and an eighth of the shortest
    shear wavelength 2π min(Vs)/ω; then halved (deterministically) until the spline through
    every other node reproduces the skipped nodes within ``tol`` × max|A, B, C, D| (a bound for
    the spline through all nodes, whose error is ~16 times smaller), or until
    ``RADIAL_MAX_NODES`` (``converged`` False; ``error`` says by how much). Every call of
    ``regular_green`` includes r_max, so the wavenumber rule is that of a direct evaluation at
    the mesh's pair radii (whose largest is r_max): interpolation is the only difference.
    """

    def __init__(self, profile, omega, r_lo, r_max, h0, rule=None, tol=RADIAL_TOL):
        from scipy.interpolate import CubicSpline
        vs_min = min(m.vs for m in list(profile.layers) + [profile.halfspace])
        h = min(h0, 2 * np.pi * vs_min / omega / 8) if omega > 0 else h0
        r_lo = min(r_lo, r_max)
        self.calls = 0
        if r_max - r_lo <= 1e-9 * max(r_max, 1.0):       # one non-zero radius (or none): exact values
            values, self.at_zero = self._evaluate(profile, omega, np.array([r_max, 0.0]), r_max, rule)
            self.r, self.error, self.converged, self._spline = np.array([r_max]), 0.0, True, None
            self._single = values[0]
            return
        m = max(8, 2 * int(np.ceil((r_max - r_lo) / h / 2)))
        r = np.linspace(r_lo, r_max, m + 1)
        values, self.at_zero = self._evaluate(profile, omega, np.append(r, 0.0), r_max, rule)
        values = values[:-1]
        while True:
            scale = max(float(np.abs(values).max()), float(np.abs(self.at_zero).max()))
            coarse = CubicSpline(r[::2], values[::2], axis=0)
            err = float(np.abs(coarse(r[1::2]) - values[1::2]).max()) / scale if scale > 0 else 0.0
            if err <= tol or 2 * r.size - 1 > RADIAL_MAX_NODES:
                break
            extra, _ = self._evaluate(profile, omega, 0.5 * (r[:-1] + r[1:]), r_max, rule)
            both = np.empty((2 * r.size - 1,) + values.shape[1:], dtype=complex)
            both[::2], both[1::2] = values, extra
            r, values = np.linspace(r_lo, r_max, 2 * r.size - 1), both
        self.r, self.error, self.converged = r, err, err <= tol
        self._spline = CubicSpline(r, values, axis=0)

    def _evaluate(self, profile, omega, r, r_max, rule, batch=512):
        """regular_green at r (with r_max appended to every batch: the same wavenumber rule),
        as (len(r), 4) complex; and the last value (for r = 0 when asked)."""
        out = np.empty((r.size, 4), dtype=complex)
        for k in range(0, r.size, batch):
            part = np.append(r[k:k + batch], r_max)
            out[k:k + batch] = np.stack(_regular_green(profile, omega, part, rule), axis=-1)[:-1]
            self.calls += 1
        return out, out[-1].copy()

    def __call__(self, r):
        """A, B, C, D at radii r (any shape; 0 or in [r_lo, r_max]), complex, m/N."""
        r = np.asarray(r, dtype=float)
        v = np.broadcast_to(self._single, r.shape + (4,)).copy() if self._spline is None else self._spline(r)
        zero = r == 0
        if zero.any():
            v[zero] = self.at_zero
        return v[..., 0], v[..., 1], v[..., 2], v[..., 3]


class _IrregularOperator:
    """Flexibility of an irregular mesh (node list or cells) in memory O(n²) reals.

    Stored per pair: the six static basis integrals (``patch.polygon_integrals`` over the true
    cell, or ``patch.rectangle_integrals`` over the equal-area square of a node), divided by the
    source cell's area, float64 (48 bytes per pair); for an outline cell (``edge_strips``) the
    integrals over its strips weighted by their tractions, in the same 48 bytes. Per frequency,
    F is assembled in blocks of rows from them and the regular kernel interpolated at the pair
    radii, node i to force centroid j (``RadialRegular``; the self terms at r = 0, its exact
    value: a centroid a fraction of the cell from its node would stretch the radial grid down
    toward the kernel's non-smooth point r = 0, two to four times the nodes, for a change of
    (kr)² there): never an (n², n_k) Bessel matrix. Collocation at the nodes (the cells' area
    centroids).
    """

    def __init__(self, profile, mesh, contact, rule, radial_tol, edge=None):
        from scipy.spatial import cKDTree
        from .patch import polygon_integrals, rectangle_integrals
        self.profile, self.mesh, self.contact, self.rule = profile, mesh, contact, rule
        self.tol = RADIAL_TOL if radial_tol is None else float(radial_tol)
        n, xy = mesh.n, mesh.xy
        self.rows = max(1, CHUNK_PAIRS // max(n, 1))
        self.basis = np.empty((6, n, n))
        self.edge = edge_tractions(mesh) if edge is None else edge
        if mesh.cells is None:
            self.edge = "constant"
        strips = None
        self.source = xy                      # where each cell's force acts for the regular part
        if self.edge != "constant":
            cells, strips, weights, self.source = edge_strips(mesh, self.edge)
        half = 0.5 * np.sqrt(mesh.area)
        for i0 in range(0, n, self.rows):
            i1 = min(n, i0 + self.rows)
            if mesh.cells is not None:
                q = xy[i0:i1, None, None, :] - mesh.cells[None, :, :, :]    # p = x_i - y, still CCW
                self.basis[:, i0:i1] = polygon_integrals(q) / mesh.area
            else:
                d = xy[i0:i1, None, :] - xy[None, :, :]
                self.basis[:, i0:i1] = rectangle_integrals(d[..., 0], d[..., 1], half, half) / (4 * half * half)
        if strips is not None and cells.size:     # outline cells: the edge-singular shape, strip by strip
            rows = max(1, CHUNK_PAIRS // max(strips.shape[0] * strips.shape[1], 1))
            for i0 in range(0, n, rows):
                i1 = min(n, i0 + rows)
                q = xy[i0:i1, None, None, None, :] - strips[None]
                self.basis[:, i0:i1, cells] = np.einsum("aikm,km->aik", polygon_integrals(q), weights)
        self.r_max = max_pair_distance(np.concatenate([xy, self.source]) if strips is not None else xy)
        self.h0 = float(np.median(np.sqrt(mesh.area)))      # typical cell size
        self.r_lo = self.r_max
        if n > 1:
            dist, _ = cKDTree(xy).query(xy, k=2)
            self.h0 = min(self.h0, 2 * float(np.median(dist[:, 1])))
            if strips is not None:                   # node i != j to the force point of cell j
                dist, idx = cKDTree(xy).query(self.source, k=min(n, 3))
                dist = dist[idx != np.arange(n)[:, None]]
            self.r_lo = float(dist[dist > 0].min())            # smallest non-zero pair distance
        self.radial = None

    @property
    def n_radii(self) -> int:
        return 0 if self.radial is None else self.radial.r.size

    def flexibility(self, omega):
        profile, n, xy = self.profile, self.mesh.n, self.mesh.xy
        top = profile.top
        G = top.complex_shear_modulus(omega)
        nu = top.poisson
        c = 1.0 / (2 * np.pi * G)
        b0 = (1 - 2 * nu) / (4 * np.pi * G)
        static_only = omega == 0 and profile.is_homogeneous
        self.radial = None
        if not static_only and self.tol > 0:
            self.radial = RadialRegular(profile, omega, self.r_lo, self.r_max, self.h0, self.rule, self.tol)
        F = np.zeros((3 * n, 3 * n), dtype=complex)
        V = F.reshape(n, 3, n, 3)
        for i0 in range(0, n, self.rows):
            i1 = min(n, i0 + self.rows)
            one_r, xx, yy, xy_, x_r2, y_r2 = self.basis[:, i0:i1]
            gxx, gyy, gxy = c * (one_r - nu * yy), c * (one_r - nu * xx), c * nu * xy_
            gzz, gxz, gyz = c * (1 - nu) * one_r, b0 * x_r2, b0 * y_r2
            if not static_only:
                d = xy[i0:i1, None, :] - self.source[None, :, :]
                d[np.arange(i1 - i0), np.arange(i0, i1)] = 0.0      # self terms: r = 0, exact
                r = np.hypot(d[..., 0], d[..., 1])
                if self.radial is not None:
                    A, B, C, D = self.radial(np.minimum(r, self.r_max))
                else:                      # direct evaluation (verification): same rule via r_max
                    A, B, C, D = (v[:-1].reshape(r.shape) for v in
                                  _regular_green(profile, omega, np.append(r.ravel(), self.r_max), self.rule))
                pos = r > 0
                safe = np.where(pos, r, 1.0)
                cs, sn = np.where(pos, d[..., 0] / safe, 0.0), np.where(pos, d[..., 1] / safe, 0.0)
                c2, s2 = np.where(pos, cs * cs, 0.5), np.where(pos, sn * sn, 0.5)
                gxx = gxx + C * c2 + D * s2
                gyy = gyy + C * s2 + D * c2
                gxy = gxy + (C - D) * sn * cs
                gzz = gzz + A
                gxz, gyz = gxz + B * cs, gyz + B * sn
            rows = V[i0:i1]
            rows[:, 0, :, 0], rows[:, 1, :, 1], rows[:, 2, :, 2] = gxx, gyy, gzz
            rows[:, 0, :, 1] = rows[:, 1, :, 0] = gxy
            if self.contact == "welded":
                rows[:, 0, :, 2], rows[:, 1, :, 2] = gxz, gyz
                rows[:, 2, :, 0], rows[:, 2, :, 1] = -gxz, -gyz
        _symmetrise(F, 3 * self.rows)
        return F


def _symmetrise(F, block):
    """F <- (F + Fᵀ)/2 in place, by blocks of ``block`` rows (no full-size temporary):
    collocation on unequal cells is not exactly reciprocal."""
    m = F.shape[0]
    for i0 in range(0, m, block):
        i1 = min(m, i0 + block)
        for j0 in range(i0, m, block):
            j1 = min(m, j0 + block)
            s = 0.5 * (F[i0:i1, j0:j1] + F[j0:j1, i0:i1].T)
            F[i0:i1, j0:j1] = s
            F[j0:j1, i0:i1] = s.T
