"""Layered soil at the impedance level: the soft layer on stiff rock (radiation cutoff) and
passivity across the layer's resonances."""
import numpy as np
import pytest

from soil_impedance import Layer, Material, SoilProfile, circle_mesh, impedance_sweep

H, VS = 10.0, 200.0
FC = VS / (4 * H)              # horizontal (shear) cutoff of the layer, 5 Hz


def _profile(damping):
    return SoilProfile((Layer(vs=VS, rho=1800.0, nu=0.3, damping=damping, thickness=H, name="layer"),),
                       Material(vs=2000.0, rho=2400.0, nu=0.25, damping=0.0, name="rock"))


MESH = circle_mesh(5.0, 1.25)


def _ratio(K, j):
    """Damping ratio Im K_jj(f) / (2 K_jj(0))."""
    return K[:, j, j].imag / (2 * K[0, j, j].real)


def test_no_radiation_below_horizontal_cutoff():
    f = np.array([0.0, 0.25, 0.5, 0.7, 1.5, 2.0]) * FC
    elastic = impedance_sweep(_profile(0.0), MESH, f, outputs=("rigid",))["rigid"].matrices
    damped = impedance_sweep(_profile(0.05), MESH, f, outputs=("rigid",))["rigid"].matrices
    # elastic layer: below the cutoff only the leak into the 10x stiffer rock (< 0.5 %)
    assert np.all(np.abs(_ratio(elastic, 0)[1:4]) < 0.005)
    # above it, radiation damping appears (tens of percent)
    assert _ratio(elastic, 0)[4] > 0.1
    # damped layer: below the cutoff the ratio is the material damping, 5 % (to 0.5 %)
    assert _ratio(damped, 0)[1:4] == pytest.approx(0.05, abs=0.005)


@pytest.mark.parametrize("damping", [0.0, 0.05])
def test_passive_across_layer_resonances(damping):
    """Hermitian part of Im K(ω) >= 0 for ω > 0 on a dense grid through the layer's shear and
    dilatational resonances (Vs/4H = 5 Hz, Vp/4H = 9.4 Hz)."""
    f = np.linspace(0.5, 15.0, 30)
    K = impedance_sweep(_profile(damping), MESH, f, outputs=("rigid",))["rigid"].matrices
    scale = np.abs(np.diagonal(K, axis1=1, axis2=2)).max(axis=1)
    for k in range(f.size):
        # DOF-scaled so translations and rotations weigh alike
        d = 1 / np.sqrt(np.abs(np.diag(K[k])))
        im = d[:, None] * (K[k].imag + K[k].imag.T) / 2 * d[None, :]
        assert np.linalg.eigvalsh(im).min() > -1e-6, (f[k], np.linalg.eigvalsh(im).min())
    assert np.all(scale > 0)
