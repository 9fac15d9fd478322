"""Static (Boussinesq/Cerruti) surface kernel and its closed-form integrals over rectangles.

Kernel convention (the same as ``soil_impedance.greens``): ``g[a, b](d)`` is the surface
displacement in direction ``a`` at offset ``d = (dx, dy)`` from a unit point force applied to
the soil surface in direction ``b`` (a, b in x, y, z; z up). For a half-space of complex shear
modulus ``G*`` (``Material.complex_shear_modulus(ω)``) and Poisson ratio ν, with r = |d|::

    g_zz = (1-ν)/(2πG r)             g_xx = (1/r - ν dy²/r³)/(2πG)   g_yy = (1/r - ν dx²/r³)/(2πG)
    g_xy = g_yx = ν dx dy/(2πG r³)   g_xz = b0 dx/r², g_yz = b0 dy/r², g_zx = -g_xz, g_zy = -g_yz
    b0 = (1-2ν)/(4πG)

Every term is a combination of 1/r, dx²/r³, dy²/r³, dx dy/r³, dx/r², dy/r², whose double
integrals over a rectangle have closed forms (logs / asinh / atan); they are exact at any
distance, so the same formulas serve self, near and far patches (no quadrature switch).
"""
from __future__ import annotations

import math

import numpy as np


def static_radial(material, r, omega=None):
    """Static half-space surface kernel in radial form (fallback copy of ``greens.static_radial``).

    Parameters
    ----------
    material : Material      uses G*(omega) and ν
    r : array_like, m        radii, > 0
    omega : float, rad/s     frequency of G* (None: hysteretic materials only)

    Returns
    -------
    A, B, C, D : ndarrays like r, m/N   (see ``soil_impedance.greens`` for their meaning)
    """
    r = np.asarray(r, dtype=float)
    G = material.complex_shear_modulus(omega)
    nu = material.poisson
    A = (1 - nu) / (2 * math.pi * G * r)
    B = (1 - 2 * nu) / (4 * math.pi * G * r)
    C = 1 / (2 * math.pi * G * r)
    D = (1 - nu) / (2 * math.pi * G * r)
    return A, B, C, D


def _xlog(x, y, r):
    """x asinh(y/|x|) with its limit 0 at x = 0 (equals x ln(y + r) up to a function of x alone)."""
    out = np.zeros_like(r)
    nz = x != 0
    out[nz] = x[nz] * np.arcsinh(y[nz] / np.abs(x[nz]))
    return out


def _xatan(x, y):
    """x atan(y/x) with its limit 0 at x = 0."""
    out = np.zeros(np.broadcast(x, y).shape)
    nz = x != 0
    out[nz] = x[nz] * np.arctan(y[nz] / x[nz])
    return out


def _ylogr(y, r):
    """y ln r with its limit 0 at r = 0."""
    out = np.zeros_like(r)
    nz = r > 0
    out[nz] = y[nz] * np.log(r[nz])
    return out


def _primitives(x, y):
    """Corner primitives H(x, y) with ∂²H/∂x∂y equal to each of the six basis kernels.

    Returns an array shape (6,) + x.shape for: 1/r, x²/r³, y²/r³, xy/r³, x/r², y/r².
    Functions of x alone or y alone are dropped (they cancel in the corner sum).
    """
    r = np.hypot(x, y)
    xl = _xlog(x, y, r)   # x asinh(y/|x|): primitive of y²/r³
    yl = _xlog(y, x, r)   # y asinh(x/|y|): primitive of x²/r³
    return np.stack([
        xl + yl,                          # 1/r
        yl,                               # x²/r³
        xl,                               # y²/r³
        -r,                               # xy/r³
        _ylogr(y, r) + _xatan(x, y),      # x/r²
        _ylogr(x, r) + _xatan(y, x),      # y/r²
    ])


def rectangle_integrals(dx, dy, ax, ay):
    """Integrals of the six basis kernels over rectangles [dx-ax, dx+ax] × [dy-ay, dy+ay].

    Parameters
    ----------
    dx, dy : array_like, m     rectangle centres relative to the field point
    ax, ay : array_like, m     half sides, > 0 (broadcast with dx, dy)

    Returns
    -------
    ndarray, shape (6,) + broadcast shape, units m (for 1/r) or m^0... per kernel times m²
    """
    dx, dy, ax, ay = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (dx, dy, ax, ay)))
    x2, x1, y2, y1 = dx + ax, dx - ax, dy + ay, dy - ay
    return (_primitives(x2, y2) - _primitives(x1, y2)
            - _primitives(x2, y1) + _primitives(x1, y1))


def static_patch_kernel(material, dx, dy, ax, ay, omega=None):
    """Static surface displacement at a field point from a unit *total* force spread
    uniformly over a rectangle of half sides (ax, ay), ``(dx, dy) = x_field - x_centre``,
    with the complex G*(omega) of ``material`` (omega rad/s; None: hysteretic only).
    The kernel is proportional to 1/G*.

    Returns
    -------
    ndarray, shape broadcast + (3, 3), complex, m/N: ``[..., a, b]`` = u_a from unit force in b.
    """
    G = material.complex_shear_modulus(omega)
    nu = material.poisson
    # integrate g(p) over p in the rectangle, p = offset from force point to field point
    I = rectangle_integrals(dx, dy, ax, ay) / (4.0 * np.asarray(ax) * np.asarray(ay))
    one_r, xx, yy, xy, x_r2, y_r2 = I
    c = 1.0 / (2 * math.pi * G)
    b0 = (1 - 2 * nu) / (4 * math.pi * G)
    out = np.empty(one_r.shape + (3, 3), dtype=complex)
    out[..., 0, 0] = c * (one_r - nu * yy)
    out[..., 1, 1] = c * (one_r - nu * xx)
    out[..., 0, 1] = out[..., 1, 0] = c * nu * xy
    out[..., 2, 2] = c * (1 - nu) * one_r
    out[..., 0, 2] = b0 * x_r2
    out[..., 1, 2] = b0 * y_r2
    out[..., 2, 0] = -b0 * x_r2
    out[..., 2, 1] = -b0 * y_r2
    return out


def radial_to_cartesian(A, B, C, D, dx, dy):
    """Point kernel (3, 3) blocks from the radial functions at offsets (dx, dy).

    At r = 0 the angular terms take their angular mean: g_xx = g_yy = (C + D)/2, no coupling.

    Returns
    -------
    ndarray, shape dx.shape + (3, 3), complex
    """
    dx, dy = np.asarray(dx, float), np.asarray(dy, float)
    r = np.hypot(dx, dy)
    safe = np.where(r > 0, r, 1.0)
    c = np.where(r > 0, dx / safe, 0.0)
    s = np.where(r > 0, dy / safe, 0.0)
    c2 = np.where(r > 0, c * c, 0.5)
    s2 = np.where(r > 0, s * s, 0.5)
    out = np.empty(r.shape + (3, 3), dtype=complex)
    out[..., 0, 0] = C * c2 + D * s2
    out[..., 1, 1] = C * s2 + D * c2
    out[..., 0, 1] = out[..., 1, 0] = (C - D) * s * c
    out[..., 2, 2] = A
    out[..., 0, 2] = B * c
    out[..., 1, 2] = B * s
    out[..., 2, 0] = -B * c
    out[..., 2, 1] = -B * s
    return out


def polygon_integrals(poly):
    """Integrals of the six basis kernels over polygons, the field point at the origin.

    Parameters
    ----------
    poly : array_like, shape (..., k, 2), m
        vertices of each polygon counter-clockwise, in coordinates p = x_field - y relative to
        the field point (a zero-length edge, a repeated vertex, is allowed: triangles as k = 4)

    Returns
    -------
    ndarray, shape (6,) + poly.shape[:-2], m (the kernels are of degree -1): the integrals of
    1/r, x²/r³, y²/r³, xy/r³, x/r², y/r² over each polygon, as ``rectangle_integrals``.

    Method: every kernel f is homogeneous of degree -1, so div(p f) = (2 - 1) f and, by the
    divergence theorem, ∫_P f dA = Σ_edges h_e ∫_e f ds, h_e = p·n_e the signed distance from
    the origin to edge e's line (n_e outward). The edge integrals are closed forms in the
    abscissa t along the edge (r² = h² + t²); h_e ∫_e f ds is continuous in h and vanishes at
    h = 0, so the field point may lie inside, on an edge or vertex, or outside (the origin is
    an integrable singularity: p f is bounded, a small circle around it contributes nothing).
    """
    a = np.asarray(poly, dtype=float)
    b = np.roll(a, -1, axis=-2)
    e = b - a
    length = np.hypot(e[..., 0], e[..., 1])
    live = length > 0
    safe_len = np.where(live, length, 1.0)
    tx, ty = e[..., 0] / safe_len, e[..., 1] / safe_len
    nx, ny = ty, -tx                                    # outward normal of a counter-clockwise edge
    h = a[..., 0] * nx + a[..., 1] * ny
    t1 = a[..., 0] * tx + a[..., 1] * ty
    t2 = b[..., 0] * tx + b[..., 1] * ty
    r1 = np.hypot(a[..., 0], a[..., 1])
    r2 = np.hypot(b[..., 0], b[..., 1])
    on = live & (h != 0)                               # h = 0: p·n = 0 on the edge, no contribution
    hs = np.where(on, h, 1.0)
    ah = np.abs(hs)
    r1s, r2s = np.where(on, r1, 1.0), np.where(on, r2, 1.0)
    ash = np.arcsinh(t2 / ah) - np.arcsinh(t1 / ah)     # ∫ dt/r
    tr = t2 / r2s - t1 / r1s                            # h² ∫ dt/r³
    ir = 1.0 / r2s - 1.0 / r1s                          # -∫ t dt/r³
    at = np.arctan(t2 / hs) - np.arctan(t1 / hs)        # h ∫ dt/r²
    lg = np.log(r2s / r1s)                              # ∫ t dt/r²
    quad = ash - tr                                     # ∫ t² dt/r³
    out = np.stack([
        hs * ash,                                                        # 1/r
        hs * (nx * nx * tr + tx * tx * quad) - 2 * hs * hs * nx * tx * ir,  # x²/r³
        hs * (ny * ny * tr + ty * ty * quad) - 2 * hs * hs * ny * ty * ir,  # y²/r³
        hs * (nx * ny * tr + tx * ty * quad) - hs * hs * (nx * ty + ny * tx) * ir,  # xy/r³
        hs * (nx * at + tx * lg),                                        # x/r²
        hs * (ny * at + ty * lg),                                        # y/r²
    ])
    return np.where(on, out, 0.0).sum(axis=-1)
