"""Wavenumber quadrature rule for the layered Green's functions (``greens.regular_green``).

The Hankel integrals run over k in [0, K_max] along a path in the complex k plane:

* ω > 0: a polygon 0 -> t_r + ib -> k_c - b + ib -> k_c **above** the real axis (with
  e^{+iωt} and damping the Rayleigh/Love poles lie below the axis; undamped they lie on
  [ω/Vs_halfspace, ω/(0.874 Vs_min)], the polygon passes above them at height b), then the
  real axis [k_c, K_max] with panels graded geometrically from width b up to the nominal
  width (the dynamic kernel varies on the scale ks just above k_c);
* ω = 0: the real axis [0, K_max] only.

All panels are Gauss-Legendre with ``nodes`` points. Every number below is a named field of
``GreenRule``; ``GreenRule.discretize`` returns the concrete nodes and weights.

    k_c      = kc_factor * ω / min(Vs)                      (> all poles: c_R >= 0.874 Vs)
    b        = min(height * k_c, bessel_growth / r_max)     (|J(kr)| grows like e^{b r};
                                                             low: first-quadrant poles exist)
    t_r      = min(b, 0.5 ω / Vs_halfspace)                 (first ramp stays below all poles)
    a        = max(asym_scale * |ks_top|, tail_clearance * b)   (tail 1/k - 1/sqrt(k²+a²) has
                                                             branch points at ±ia: keep ia
                                                             well above the contour)
    K_max    = max(kmax_ks * a, kmax_ks * |ks_top|, kmax_depth / h_1, 2 k_c)
    width    = 2π / r_max / refine                          (real-axis panel width)
    first    = min(b, first_depth / H, width)               (first real-axis panel; widths
                                                             then double up to ``width``;
                                                             H: deepest interface depth)
    contour panel width <= contour_width * b / refine
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class KGrid:
    """Concrete quadrature: ∫ f(k) dk ≈ Σ weights * f(nodes).

    nodes, weights : ndarrays shape (n,), complex; ``n_contour`` first nodes are off-axis.
    """

    nodes: np.ndarray
    weights: np.ndarray
    n_contour: int
    k_c: float
    height: float
    k_max: float
    panel_width: float
    tail_a: float = 0.0


@dataclass(frozen=True)
class GreenRule:
    """Documented discretization of the wavenumber integrals (see module docstring).

    kc_factor : contour end k_c in units of ω/min(Vs); > 1/0.874 so it passes every pole
    height : contour height b as a fraction of k_c. Keep it small: layered media also have
        poles in the first quadrant on the proper sheet (thickness resonances near k = 0,
        e.g. k ≈ 0.01 + 0.1i /m for 10 m of Vs 200 m/s on rock at 10 Hz; complex modes) and a
        contour above them silently drops their residues
    bessel_growth : cap on b * r_max (Bessel functions of complex argument grow like e^{b r})
    contour_width : contour panel width in units of b (poles sit >= ~b/2 from the path)
    kmax_ks : K_max >= kmax_ks |ks_top| (the dynamic remainder decays like k^-5 after the
        analytic k^-3 subtraction)
    kmax_depth : K_max >= kmax_depth / h_1 (layering effects decay like e^{-2 k h_1})
    refine : divides every panel width (convergence studies: 2 = twice as many nodes)
    nodes : Gauss-Legendre points per panel
    r_floor : m, smallest r_max used to size panels (r_max = max(r.max(), r_floor))
    asym_probe : the k^-3 coefficient is read at k = asym_probe |ks_top|
    asym_scale : a >= asym_scale |ks_top| in the subtracted tail 1/k - 1/sqrt(k² + a²)
    tail_clearance : a >= tail_clearance * b (the tail's branch point ia stays off the path)
    first_depth : first real-axis panel <= first_depth / H (resolves the deep layering near
        k -> 0, where it matters for r ~ H)
    """

    kc_factor: float = 2.0
    height: float = 0.02
    bessel_growth: float = 2.0
    contour_width: float = 2.0
    kmax_ks: float = 20.0
    kmax_depth: float = 25.0
    refine: float = 1.0
    nodes: int = 8
    r_floor: float = 1.0
    asym_probe: float = 1.0e3
    asym_scale: float = 1.0
    tail_clearance: float = 3.0
    first_depth: float = 0.5

    def refined(self, factor: float = 2.0) -> GreenRule:
        """A rule with panels ``factor`` times narrower and a longer, higher-K tail."""
        return replace(self, refine=self.refine * factor, kmax_ks=self.kmax_ks * factor,
                       kmax_depth=self.kmax_depth * factor)

    def discretize(self, profile, omega: float, r_max: float) -> KGrid:
        """Nodes and weights for ``profile`` at ``omega`` (rad/s) and radii up to ``r_max`` (m)."""
        r_max = max(float(r_max), self.r_floor)
        mats = list(profile.layers) + [profile.halfspace]
        vs_min = min(m.vs for m in mats)
        top = profile.top
        ks_top = omega * math.sqrt(top.rho / abs(top.complex_shear_modulus(omega)))
        depths = np.cumsum([l.thickness for l in profile.layers])
        layered = not profile.is_homogeneous and len(depths) > 0
        h1 = float(depths[0]) if layered else math.inf
        depth = float(depths[-1]) if layered else math.inf
        k_c = self.kc_factor * omega / vs_min
        b = min(self.height * k_c, self.bessel_growth / r_max) if k_c > 0 else 0.0
        tail_a = max(self.asym_scale * ks_top, self.tail_clearance * b)
        k_max = max(self.kmax_ks * tail_a, self.kmax_depth / h1, 2.0 * k_c)
        width = 2.0 * math.pi / r_max / self.refine
        first = min(b if b > 0 else width, self.first_depth / depth if layered else math.inf, width)
        x, w = np.polynomial.legendre.leggauss(self.nodes)
        nodes, weights = [], []

        def segment(z0, z1, n):
            edges = np.linspace(0.0, 1.0, n + 1)
            for a, c in zip(edges[:-1], edges[1:]):
                s = 0.5 * (a + c) + 0.5 * (c - a) * x
                nodes.append(z0 + (z1 - z0) * s)
                weights.append((z1 - z0) * 0.5 * (c - a) * w)

        if k_c > 0:
            t_r = min(b, 0.5 * omega / profile.halfspace.vs)
            pw = self.contour_width * b / self.refine
            poly = [0.0, t_r + 1j * b, k_c - b + 1j * b, k_c]
            for z0, z1 in zip(poly[:-1], poly[1:]):
                segment(z0, z1, max(1, math.ceil(abs(z1 - z0) / pw)))
        n_contour = sum(len(n) for n in nodes)
        # real axis: geometric grading from width ~b (or the nominal width at ω = 0)
        k0, step = k_c, first
        if not (width > 0 and first > 0):
            raise ValueError(f"GreenRule: panel widths {width!r}, {first!r} must be > 0 (check refine, r_floor)")
        while k0 < k_max:
            step = min(step, width)
            k1 = min(k0 + step, k_max)
            segment(k0, k1, 1)
            k0, step = k1, 2.0 * step
        return KGrid(np.concatenate(nodes).astype(complex), np.concatenate(weights).astype(complex),
                     n_contour, k_c, b, k_max, width, tail_a)
