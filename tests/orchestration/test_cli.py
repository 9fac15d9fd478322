"""The command line: exit codes, --json contract, files written."""
import json
import math

import h5py
import numpy as np
import pytest

from orchestrator.cli import main

SCENE = """
[soil]
halfspace = {{ vs = 500.0, nu = 0.3333333333333333, rho = 2000.0, damping = 0.0 }}
[foundation]
shape = "circle"
radius = 10.0
element_size = 2.5
[impedance]
frequencies_hz = {freqs}
"""


@pytest.fixture
def scene(tmp_path, monkeypatch):
    monkeypatch.setenv("UPLIFT_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "disk.toml"
    path.write_text(SCENE.format(freqs="[0.0]"))
    return path


def test_impedance_json_contract(scene, tmp_path, capsys):
    out = tmp_path / "table.h5"
    assert main(["impedance", str(scene), "--json", "-o", str(out)]) == 0
    data = json.loads(capsys.readouterr().out)          # exactly one JSON object on stdout
    assert set(data) == {"frequencies_hz", "dofs", "rigid", "wall_s", "discretisation_error"}
    assert data["dofs"] == ["ux", "uy", "uz", "rx", "ry", "rz"]
    K = np.array(data["rigid"])                          # (F, 6, 6, 2)
    assert K.shape == (1, 6, 6, 2)
    # a coarse static disk: Kv within 8 % of Mossakovskii's welded value (O(h) error at h = R/4)
    G, R, nu = 2000 * 500.0 ** 2, 10.0, 1 / 3
    kv = 4 * G * R * math.log(3 - 4 * nu) / (1 - 2 * nu)
    assert K[0, 2, 2, 0] == pytest.approx(kv, rel=0.08)
    # the coarse grid (R/h = 4) is too flexible (-3.5 %): the estimate (vs h/2, Richardson) says so
    err = data["discretisation_error"]["errors"]
    assert set(err) == set(data["dofs"]) and -0.08 < err["uz"] < -0.01
    assert abs(K[0, 2, 2, 0] / (1 + err["uz"]) - kv) < 0.5 * abs(K[0, 2, 2, 0] - kv)
    with h5py.File(out) as f:                             # the file is readable with plain h5py
        assert f["matrices_real"].shape == (1, 6, 6)
        assert json.loads(f.attrs["notes"])["discretisation_error"] == data["discretisation_error"]


def test_cache_reuses_sweep(scene, capsys, monkeypatch):
    assert main(["impedance", str(scene), "--json"]) == 0
    first = json.loads(capsys.readouterr().out)

    def no_bem(*args, **kwargs):
        raise AssertionError("the second sweep must come from the cache")
    monkeypatch.setattr("soil_impedance.sweep._compute", no_bem)
    assert main(["impedance", str(scene), "--json"]) == 0
    second = json.loads(capsys.readouterr().out)
    assert first["rigid"] == second["rigid"]


def test_bad_input_exit_code(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENE.format(freqs="[0.0]").replace("nu = 0.3333333333333333", "nu = 0.5"))
    assert main(["impedance", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "soil.halfspace" in err and "Poisson" in err
    assert main(["impedance", str(tmp_path / "absent.toml")]) == 2
    assert main(["--help"]) == 0
    for tol in ("-1", "0", "1.5", "nan", "x"):        # a bad option is refused before any computation
        assert main(["fit", str(bad), "--tol", tol]) == 2
        assert "argument --tol" in capsys.readouterr().err


def test_fit_json_contract(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("UPLIFT_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "disk.toml"
    path.write_text(SCENE.format(freqs="[0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0]"))
    model = tmp_path / "model.h5"
    assert main(["fit", str(path), "--table", "rigid", "--tol", "0.01", "--json", "-o", str(model)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"order", "max_rel_error", "passive", "passivity_margin", "wall_s"}
    assert out["max_rel_error"] <= 0.01 and out["passive"] and out["order"] <= 24
    from soil_impedance.fit import load_fit
    assert load_fit(model).report.max_rel_error == pytest.approx(out["max_rel_error"])


def _shell(*args, cwd=None, env=None):
    """``uplift ARGS`` as a user's shell runs it: a child process, stdout and stderr apart."""
    import os
    import subprocess
    import sys
    from helpers import ROOT
    env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    return subprocess.run([sys.executable, "-m", "orchestrator.cli", *args], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=600)


def test_no_command_lists_the_commands_and_version_prints_the_distributions():
    import importlib.metadata
    from orchestrator.cli import _parser, command_list
    proc = _shell()
    assert proc.returncode == 2 and proc.stdout == ""          # a missing command is bad input, as before
    listed = [line.split()[0] for line in proc.stderr.split("commands:\n")[1].split("\n\n")[0].splitlines()]
    assert listed == ["run", "scene", "cache", "impedance", "fit", "export", "compare", "report", "ensemble", "envelope", "fragility", "pushover", "bench"]
    assert all(len(line.split(maxsplit=1)) == 2 for line in command_list(_parser()).splitlines())  # one line each
    assert "give a COMMAND" in proc.stderr.splitlines()[-1]
    proc = _shell("--version")
    assert proc.returncode == 0
    assert proc.stdout.strip() == f"uplift (uplift-ssi) {importlib.metadata.version('uplift-ssi')}"


def test_version_without_installed_metadata_reads_the_checkouts_pyproject(monkeypatch):
    import importlib.metadata
    from helpers import ROOT
    from orchestrator import cli
    from orchestrator.scene import tomllib

    def absent(name):
        raise importlib.metadata.PackageNotFoundError(name)
    monkeypatch.setattr(importlib.metadata, "version", absent)
    expected = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert cli.version().startswith(f"{expected} (not installed")


def strict_loads(text):
    """json.loads refusing NaN and Infinity (what a strict JSON reader does)."""
    return json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(f"not strict JSON: {c}")))


def test_run_summary_on_stdout_progress_on_stderr_json_strict(tmp_path):
    from helpers import tower, write_scene
    from helpers.native import seed_native
    scene = write_scene(tmp_path / "tower.toml", tower())
    env = {"UPLIFT_CACHE": str(seed_native(tmp_path / "cache"))}    # the C runtime compiled once for the tests
    proc = _shell("run", scene, "-o", str(tmp_path / "r.h5"), cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout.splitlines()          # what `uplift run SCENE > out.txt` keeps: the summary
    assert out[0].startswith("motion: ") and out[1].startswith("winkler [x]: max uplift ")
    assert "wrote" not in proc.stdout and "max uplift" not in proc.stderr
    assert f"wrote {tmp_path / 'r.h5'}" in proc.stderr and "run tower [winkler]" in proc.stderr   # progress
    proc = _shell("run", scene, "-o", str(tmp_path / "r.h5"), "--json", cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr
    summ = strict_loads(proc.stdout)        # exactly one object, strict
    assert summ["routes"]["winkler"]["max_uplift_m"] > 0 and "winkler" in proc.stderr


def test_run_json_with_a_non_finite_value_says_null_and_why(tmp_path, capsys, monkeypatch):
    """A route whose numbers are not finite (a diverged run) is written null with the reason."""
    from helpers import tower, write_scene
    import orchestrator.results_file as results_file          # the command imports it when it runs
    from orchestrator.results_file import summary
    from helpers.native import seed_native
    monkeypatch.setenv("UPLIFT_CACHE", str(seed_native(tmp_path / "cache")))    # the C runtime compiled once
    monkeypatch.setattr(results_file, "summary", lambda res: dict(summary(res), max_uplift_m=float("nan"),
                                                         peak_acc_g={"top": float("inf")}))
    scene = write_scene(tmp_path / "tower.toml", tower())
    assert main(["run", scene, "-o", str(tmp_path / "r.h5"), "--json"]) == 0
    s = strict_loads(capsys.readouterr().out)["routes"]["winkler"]
    assert s["max_uplift_m"] is None and "not a finite number (nan)" in s["missing"]["max_uplift_m"]
    assert s["peak_acc_g"] == {"top": None, "missing": {"top": s["peak_acc_g"]["missing"]["top"]}}


@pytest.mark.slow
def test_native_export_says_what_it_compiles_and_reports_each_platform(tmp_path, capsys, monkeypatch):
    from fmus.native_build import PLATFORMS
    from helpers import export_tower, write_scene
    monkeypatch.setenv("UPLIFT_CACHE", str(tmp_path / "cache"))
    scene = write_scene(tmp_path / "tower.toml", export_tower())
    assert main(["export", scene, "-o", str(tmp_path / "fmus")]) == 0
    captured = capsys.readouterr()
    err = captured.err.splitlines()
    notice = next(i for i, line in enumerate(err) if line.startswith("compiling the FMUs' C runtime"))
    assert "with zig for 3 platforms (linux64, win64, darwin64)" in err[notice]
    assert "65-95 s" in err[notice] and "once zig has cached them" in err[notice]   # the one-time cost, said first
    done = [line.split()[1:3] for line in err[notice + 1:] if line.startswith("  compiled ")]
    assert done == [[p, f"({k}/3)"] for k, p in enumerate(PLATFORMS, 1)]          # each platform as it finishes
    assert err.index(next(line for line in err if line.startswith("wrote "))) > notice + 3
    assert (tmp_path / "fmus" / "coupled.fmu").is_file() and captured.out == ""


@pytest.mark.parametrize("args, message", [
    (["--n-seeds", "3", "--seeds", "1"], "argument --seeds: not allowed with argument --n-seeds"),
    (["--n-seeds", "0"], "argument --n-seeds: '0' must be an integer >= 1"),
    (["--n-seeds", "2", "--records", "rec.txt"], "--n-seeds varies the scene's synthetic motion; --records gives"),
])
def test_n_seeds_bad_input_exits_2_with_one_line(tmp_path, capsys, args, message):
    from helpers import tower, write_scene
    scene = write_scene(tmp_path / "tower.toml", tower())
    assert main(["ensemble", scene, "--pga", "0.1", "-o", str(tmp_path / "e.h5"), *args]) == 2
    assert message in capsys.readouterr().err and not (tmp_path / "e.h5").exists()


def test_a_single_seed_says_it_is_one_motion(tmp_path, capsys, monkeypatch):
    """`--seeds 3` runs seed 3 alone, and says so (the seeds run are what run_ensemble gets)."""
    from orchestrator import ensemble
    from helpers import tower, write_scene
    seen = {}

    def stop(scene, pgas, **kw):
        seen.update(kw)
        raise KeyboardInterrupt
    monkeypatch.setattr(ensemble, "run_ensemble", stop)
    scene = write_scene(tmp_path / "tower.toml", tower())
    assert main(["ensemble", scene, "--pga", "0.1", "--seeds", "3"]) == 130
    assert seen["seeds"] == [3] and "--seeds 3: one motion, seed 3 (for 3 motions, seeds 0 to 2: --n-seeds 3)" \
        in capsys.readouterr().err
    assert main(["ensemble", scene, "--pga", "0.1", "--n-seeds", "3"]) == 130
    assert seen["seeds"] == [0, 1, 2] and "one motion" not in capsys.readouterr().err


def test_impedance_refused_when_the_sweep_would_not_fit(scene, capsys, monkeypatch):
    # the sweep's memory estimate against the machine's available memory (here 1 MiB): exit 2,
    # one line naming the estimate, the memory and the fix, and no BEM computed
    monkeypatch.setattr("soil_impedance.sweep.available_memory", lambda: 2 ** 20)
    monkeypatch.setattr("soil_impedance.sweep._compute", lambda *a, **k: pytest.fail("computed before refusing"))
    assert main(["impedance", str(scene), "--no-cache"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs about" in err[0] and "0.00 GiB available" in err[0] and "coarser mesh" in err[0]
