"""[impedance] frequency_tol: a scene sweeps a thinned subset of its frequencies (soil_impedance.frequencies),
says so in the run notes, and refuses a bad value naming the key."""
import numpy as np
import pytest

from orchestrator.impedance import cached_scene_fit, scene_impedance
from orchestrator.scene import SceneError, scene_from_dict


def _scene(**impedance):
    return scene_from_dict({
        "soil": {"damping_model": "causal", "halfspace": {"vs": 500.0, "nu": 0.3, "rho": 2000.0, "damping": 0.03}},
        "foundation": {"shape": "circle", "radius": 10.0, "element_size": 5.0},
        "impedance": {"range_hz": [0.0, 25.0, 33], **impedance},
        "structure": {"model": "reactor", "damping": {"modal": 0.07}},
        "analysis": {"dt": 0.005},
    }, name="thin")


def test_a_thinned_scene_sweeps_fewer_frequencies_and_says_so(tmp_path):
    """frequency_tol = 1e-3: fewer than the 33 frequencies are solved; the table is on the scene's grid, equal
    to the whole sweep at the swept frequencies and within tol elsewhere; the notes give the count and the
    measured error; without the key the sweep is the plain one (the default: unchanged)."""
    plain = _scene()
    assert plain.frequency_tol is None
    full = scene_impedance(plain, ("rigid",))["rigid"]
    thin = _scene(frequency_tol=1e-3)
    stats = {}
    got = scene_impedance(thin, ("rigid",), cache_dir=tmp_path, stats=stats)["rigid"]
    assert 0 < stats["computed"] < 33
    (line,) = stats["thinning"]
    assert f"{stats['computed']} of 33 frequencies swept" in line and "measured interpolation error" in line
    assert np.array_equal(got.frequencies_hz, full.frequencies_hz)
    err = np.linalg.norm(got.matrices - full.matrices, axis=(1, 2)) / np.linalg.norm(full.matrices, axis=(1, 2))
    assert err.max() <= 1e-3 and np.sum(err == 0) == stats["computed"]
    assert cached_scene_fit(thin, tmp_path) is None          # a fit keyed by the whole grid is not this one's


@pytest.mark.parametrize("value", [0, -1e-3, "1e-3", 0.9])
def test_a_bad_frequency_tol_names_the_key(value):
    with pytest.raises(SceneError, match="impedance.frequency_tol"):
        _scene(frequency_tol=value)
