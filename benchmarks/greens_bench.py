"""Run time against error of ``soil_impedance.greens.regular_green``.

Prints, per frequency, the time for 500 radii in [0, 60] m on a 2-layer profile, the error
against a 2x-refined rule and (homogeneous) against the independent Lamb kernel, then the
time of a 100-frequency sweep (0-25 Hz). Usage: python benchmarks/greens_bench.py
"""
from __future__ import annotations

import math
import time

import numpy as np

from soil_impedance.greens import GreenRule, regular_green, static_radial
from soil_impedance.greens_exact import exact_regular_halfspace
from soil_impedance.profile import Layer, Material, SoilProfile


def rel_err(a, b, material, r):
    scale = np.abs(np.array(static_radial(material, np.maximum(r, 1.0))))
    return float(np.max(np.abs(np.array(a) - np.array(b)) / scale))


def main():
    layered = SoilProfile((Layer(vs=300.0, rho=1900.0, nu=0.35, damping=0.05, thickness=5.0),
                           Layer(vs=600.0, rho=2000.0, nu=0.3, damping=0.03, thickness=15.0)),
                          Material(vs=1500.0, rho=2300.0, nu=0.25, damping=0.01))
    hom = SoilProfile.homogeneous(500.0, 2000.0, nu=0.3)
    r = np.linspace(0.0, 60.0, 500)
    r_ex = np.array([0.0, 1.0, 5.0, 10.0, 20.0, 40.0])
    print(f"{'f Hz':>6} {'t_layered s':>12} {'nodes':>6} {'err vs 2x':>10} {'hom err vs Lamb':>16}")
    for f in (0.0, 0.01, 1.0, 5.0, 10.0, 25.0):
        w = 2 * math.pi * f
        regular_green(layered, w, r)
        t = time.perf_counter()
        a = regular_green(layered, w, r)
        dt = time.perf_counter() - t
        b = regular_green(layered, w, r, GreenRule().refined(2))
        n = GreenRule().discretize(layered, w, r.max()).nodes.size
        ex = "-"
        if f > 0.5:
            e = rel_err(regular_green(hom, w, r_ex), exact_regular_halfspace(hom.top, w, r_ex),
                        hom.top, r_ex)
            ex = f"{e:.1e}"
        print(f"{f:6.2f} {dt:12.4f} {n:6d} {rel_err(a, b, layered.top, r):10.1e} {ex:>16}")
    t = time.perf_counter()
    for f in np.linspace(0.0, 25.0, 100):
        regular_green(layered, 2 * math.pi * f, r)
    print(f"100-frequency sweep, 500 radii, 2 layers: {time.perf_counter() - t:.2f} s")


if __name__ == "__main__":
    main()
