"""compare(): route differences against a reference, JSON-able, and its printed table."""
import dataclasses
import json

import numpy as np
import pytest

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


def test_default_reference_is_the_most_exact_route_with_uplift():
    from orchestrator.routes import default_reference
    assert default_reference(["winkler", "linear", "cosim", "timefreq", "monolithic"]) == "timefreq"
    assert default_reference(["winkler", "linear", "cosim", "monolithic"]) == "monolithic"
    assert default_reference(["linear", "winkler", "cosim"]) == "cosim"
    assert default_reference(["linear", "winkler"]) == "winkler"      # never linear while a route lifts
    assert default_reference(["linear"]) == "linear"


def test_zero_reference_gives_an_absolute_difference_and_linear_uplift_is_not_compared():
    from helpers import route_result
    res = {"linear": route_result("linear", gap_scale=0.5), "monolithic": route_result("monolithic", gap_scale=0.0),
           "winkler": route_result("winkler")}
    c = compare(res)
    d = c["differences"]["winkler"]
    assert c["reference"] == "monolithic"                 # not linear, which lets nothing lift
    assert d["max_uplift"] is None and d["absolute"]["max_uplift_m"] == pytest.approx(1e-3)
    assert "the reference is 0" in d["missing"]["max_uplift"]
    assert d["max_rotation"] == 0.0 and "max_rotation" not in d["missing"]
    lin = c["differences"]["linear"]
    assert lin["max_uplift"] is None and lin["absolute"]["max_uplift_m"] is None
    assert "linear lets no uplift happen" in lin["missing"]["max_uplift"]
    json.loads(json.dumps(c, allow_nan=False))
    table = format_table(c)
    assert "inf" not in table and "+1.0000 mm" in table and "the reference is 0" in table
    against_linear = compare(res, reference="linear")["differences"]["winkler"]
    assert against_linear["max_uplift"] is None and "linear lets no uplift" in against_linear["missing"]["max_uplift"]
    assert against_linear["max_rotation"] == 0.0


def test_compare_json_is_strict_with_a_zero_reference_and_a_diverged_route(tmp_path, capsys):
    from helpers import route_result
    from orchestrator.cli import main
    from orchestrator.results_file import write_results
    bad = route_result("cosim", converged=False)
    gap = np.array(bad.gap)
    gap[50:, :] = np.nan                                  # a run that blew up before it stopped
    bad = dataclasses.replace(bad, gap=gap)
    path = write_results(tmp_path / "r.h5", {"winkler": route_result("winkler", gap_scale=0.0),
                                             "monolithic": route_result("monolithic"), "cosim": bad,
                                             "linear": route_result("linear")}, scene_name="toy")
    assert main(["compare", str(path), "--json"]) == 0
    text = capsys.readouterr().out
    strict = json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    assert strict["reference"] == "monolithic"            # monolithic before winkler and cosim
    assert strict["differences"]["winkler"]["max_uplift"] == -1.0
    cosim = strict["differences"]["cosim"]
    assert cosim["max_uplift"] is None and "not a finite number" in cosim["missing"]["max_uplift"]
    assert strict["routes"]["cosim"]["max_uplift_m"] is None and strict["routes"]["cosim"]["missing"]["max_uplift_m"]
    assert main(["compare", str(path), "--reference", "winkler"]) == 0
    out = capsys.readouterr().out
    assert "inf" not in out.lower() and "+1.0000 mm" in out
