"""Response spectrum of El Centro 1940 N-S against Chopra's published values.

Chopra, Dynamics of Structures (Fig. 6.6.1 and Example 6.x): at 2 % damping the
deformation spectrum of the El Centro N-S record is D = 2.67, 5.97 and 7.47 in at
T_n = 0.5, 1 and 2 s. The record is Chopra's digitisation (tests/data, see its SOURCE file).
"""

import numpy as np
import pytest

from orchestrator.spectra import response_spectrum
from helpers import DATA as DATA_DIR

DATA = DATA_DIR / "elcentro_1940_ns_chopra.csv"
G_IN = 386.09          # in/s^2 (g = 9.80665 m/s^2), Chopra's unit for D


def test_elcentro_deformation_spectrum_matches_chopra():
    t, acc_g = np.loadtxt(DATA, delimiter=",", skiprows=1).T
    dt = 0.02
    assert np.allclose(np.diff(t), dt) and acc_g.size == 1560
    spec = response_spectrum(acc_g * G_IN, dt, [0.5, 1.0, 2.0], damping=0.02)
    assert spec.sd == pytest.approx([2.67, 5.97, 7.47], rel=0.01)
    # and in SI (the project's units): the same spectrum in m
    si = response_spectrum(acc_g * 9.80665, dt, [0.5, 1.0, 2.0], damping=0.02)
    assert si.sd / 0.0254 == pytest.approx(spec.sd, rel=1e-4)
