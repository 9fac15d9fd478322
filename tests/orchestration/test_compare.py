"""compare(): route differences against a reference, JSON-able, and its printed table."""
import json

import numpy as np

from structure.results import RouteResult

from orchestrator.compare import compare, format_table


def _result(route, scale_gap=1.0, scale_rot=1.0, scale_acc=1.0, wall=1.0):
    nt, N = 400, 4
    t = 0.01 * np.arange(nt)
    raft = np.zeros((nt, 6))
    raft[:, 3] = 1e-4 * scale_rot * np.sin(2 * np.pi * t)
    raft[:, 4] = 2e-4 * scale_rot * np.cos(2 * np.pi * t)
    gap = np.zeros((nt, N))
    gap[100, 2] = 1e-3 * scale_gap
    acc = {"top": np.column_stack([scale_acc * np.sin(2 * np.pi * 3 * t), 0 * t, 0.5 * scale_acc * np.sin(2 * np.pi * 7 * t)])}
    return RouteResult(route=route, time=t, raft=raft, gap=gap, contact_force=np.ones((nt, N)), acc=acc,
                       wall_s=wall, xy=np.zeros((N, 2)))


def test_relative_differences_exact_for_scaled_routes():
    res = {"timefreq": _result("timefreq", wall=4.0),
           "winkler": _result("winkler", 1.1, 0.8, 1.25, wall=1.0)}
    c = compare(res)
    d = c["differences"]["winkler"]
    assert c["reference"] == "timefreq"
    assert abs(d["max_uplift"] - 0.1) < 1e-12
    assert abs(d["max_rotation"] + 0.2) < 1e-12           # sqrt(rx^2 + ry^2) scales too
    assert abs(d["spectrum_peaks"]["top"]["x"] - 0.25) < 1e-9   # spectra are linear in the input
    assert "y" not in d["spectrum_peaks"]["top"]              # zero direction skipped
    assert abs(d["max_spectrum_peak"] - 0.25) < 1e-9
    assert abs(d["wall_ratio"] - 0.25) < 1e-12
    json.dumps(c)
    table = format_table(c)
    assert "winkler" in table and "+10.00%" in table and "-20.00%" in table
