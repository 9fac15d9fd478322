"""The figures as a report reader sees them: no empty panel, a unit on every axis, routes told
apart by more than colour (the figure objects, no image comparison)."""
import re
from types import SimpleNamespace

import numpy as np
import pytest
import xarray as xr

from orchestrator import fragility as frag
from orchestrator.motion import Motion
from orchestrator.plots import impedance_figure, pyplot, run_figures
from orchestrator.report import ensemble_figures
from helpers import route_result

UNIT = re.compile(r"\((?:g|s|Hz|mm|mrad|%|-)\)")        # "(unit)" as the axis labels write it
T = 0.01 * np.arange(300)


@pytest.fixture
def close():
    """Close the figures a test made."""
    figures = []
    yield figures.append
    plt = pyplot()
    for fig in figures:
        plt.close(fig)


def _figures(results, motion, close):
    out = dict(run_figures(results, motion, "tiny"))
    for fig in out.values():
        close(fig)
    return out


def _labelled(fig):
    """Every axis label of ``fig`` that is set carries a unit; every panel has data."""
    for ax in fig.axes:
        for label in (ax.get_xlabel(), ax.get_ylabel()):
            assert not label or UNIT.search(label), label
        assert ax.lines or ax.collections, f"empty panel {ax.get_title()!r}"


def test_floor_spectra_have_one_panel_per_excited_direction(close):
    """route_result's top node shakes in x and z only: under an x motion the y panel is left
    out, and the title says so; the spectra are those of the results file."""
    motion = Motion(0.01, np.column_stack([np.sin(T), 0 * T, 0 * T]), "x motion")
    figs = _figures({"winkler": route_result("winkler")}, motion, close)
    fig = figs["winkler_floor_spectra"]
    assert [ax.get_title() for ax in fig.axes] == ["x (horizontal)", "z (vertical)"]
    assert "not drawn: y (no response above round-off)" in fig._suptitle.get_text()
    assert fig.axes[0].get_ylabel() == "pseudo-acceleration, 5 % (g)"
    assert all(ax.get_xlabel() == "frequency (Hz)" for ax in fig.axes)
    _labelled(fig)
    _labelled(figs["winkler_raft"])
    assert figs["winkler_raft"].axes[-1].get_xlabel() == "time (s)"


def test_a_ground_component_alone_makes_its_panel_and_no_response_no_figure(close):
    still = route_result("winkler").replace(acc={"top": np.zeros((300, 3))})
    motion = Motion(0.01, np.column_stack([0 * T, np.sin(T), 0 * T]), "y motion")
    fig = _figures({"winkler": still}, motion, close)["winkler_floor_spectra"]
    assert [ax.get_title() for ax in fig.axes] == ["y (horizontal)"]           # the ground's spectrum
    assert [line.get_label() for line in fig.axes[0].lines] == ["ground"]
    assert "winkler_floor_spectra" not in _figures({"winkler": still}, None, close)


def test_impedance_titles_give_K0_with_its_units(close):
    f = np.linspace(0.0, 10.0, 6)
    K = np.zeros((6, 6, 6), complex)
    for j, k0 in enumerate([1e9, 1e9, 1.5e9, 5e10, 5e10, 6e10]):
        K[:, j, j] = k0 * (1 - 0.02 * f + 0.05j * f)
    table = SimpleNamespace(frequencies_hz=f, matrices=K, dofs=["ux", "uy", "uz", "rx", "ry", "rz"])
    scene = SimpleNamespace(name="toy", profile=SimpleNamespace(top=SimpleNamespace(vs=300.0)),
                            mesh=SimpleNamespace(radius=5.0, n=60), contact_kind="welded")
    fig = impedance_figure(table, scene)
    close(fig)
    titles = [ax.get_title() for ax in fig.axes[:4]]
    assert titles[0].endswith("K0 = 1.000e+09 N/m") and titles[1].endswith("K0 = 1.500e+09 N/m")
    assert titles[2].endswith("N·m/rad") and titles[3].endswith("K0 = 6.000e+10 N·m/rad")
    _labelled(fig)


def _fragility_fits():
    """Fits of two routes whose observed fractions coincide at every PGA (the case where one
    route's markers used to hide the other's)."""
    pga = np.array([0.1, 0.2, 0.3, 0.4])
    uplift = np.array([[0.001, 0.004, 0.006, 0.009], [0.002, 0.003, 0.007, 0.008], [0.001, 0.006, 0.004, 0.01],
                       [0.0015, 0.002, 0.0065, 0.0085]])          # (record, pga), 5 mm crossed in between
    ds = xr.Dataset({"max_uplift": (("record", "pga", "route"), np.stack([uplift, uplift], axis=-1), {"units": "m"}),
                     "status": (("record", "pga", "route"), np.full((4, 4, 2), "converged"))},
                    coords={"record": ["a", "b", "c", "d"], "pga": pga, "route": ["winkler", "monolithic"]})
    return frag.fragility(ds, ["max_uplift > 5 mm", "max_uplift > 0.005"])


def test_fragility_routes_are_told_apart(close):
    fig = frag.fragility_figure(_fragility_fits())
    close(fig)
    assert [ax.get_title() for ax in fig.axes] == ["max_uplift > 5 mm", "max_uplift > 0.005 (m)"]
    for ax in fig.axes:
        assert ax.get_xlabel() == "PGA (g)" and ax.get_ylabel() == "P(exceed | PGA) (-)"
        observed = [line for line in ax.lines if line.get_label().endswith("observed z/n")]
        curves = [line for line in ax.lines if "beta" in line.get_label()]
        assert len(observed) == len(curves) == 2
        assert observed[0].get_marker() != observed[1].get_marker()
        assert curves[0].get_linestyle() != curves[1].get_linestyle()
        np.testing.assert_array_equal(observed[0].get_ydata(), observed[1].get_ydata())   # same fractions,
        assert np.all(observed[0].get_xdata() < observed[1].get_xdata())                    # side by side


def test_ensemble_figures_tell_routes_apart_and_leave_out_unexcited_directions(close):
    pga, routes, q = np.array([0.1, 0.2]), ["winkler", "monolithic"], np.array([0.16, 0.5, 0.84])
    f = np.geomspace(0.5, 40.0, 120)
    spectrum = np.ones((3, 2, 2, 1, 3, f.size))                     # (quantile, pga, route, node, direction, f)
    spectrum[..., 1, :] = np.nan                                      # y: round-off in every cell
    cells = (("record", "pga", "route"), np.ones((3, 2, 2)))
    frac = (("quantile", "pga", "route"), np.ones((3, 2, 2)))
    ds = xr.Dataset({"status": (("record", "pga", "route"), np.full((3, 2, 2), "converged")),
                     **dict.fromkeys(("max_uplift", "max_raft_rotation", "min_contact_ratio"), cells),
                     **{f"{name}_fractile": frac for name in ("max_uplift", "max_raft_rotation", "min_contact_ratio")},
                     "floor_spectrum_fractile": (("quantile", "pga", "route", "node", "direction", "frequency"),
                                                 spectrum)},
                    coords={"record": ["a", "b", "c"], "pga": pga, "route": routes, "quantile": q, "node": ["top"],
                            "direction": ["x", "y", "z"], "frequency": f},
                    attrs={"scene": "toy", "components": "x y", "damping": 0.05})
    figs = dict(ensemble_figures(ds))
    for fig in figs.values():
        close(fig)
        _labelled(fig)
    medians = [line for line in figs["ensemble_against_pga"].axes[0].lines if "median" in line.get_label()]
    assert medians[0].get_marker() != medians[1].get_marker()
    assert medians[0].get_linestyle() != medians[1].get_linestyle()
    spectra = figs["ensemble_floor_spectra_0.1g"]
    assert [ax.get_title() for ax in spectra.axes] == ["top, x (horizontal)", "top, z (vertical)"]
    assert "not drawn: y" in spectra._suptitle.get_text()
