"""The FMI cross-check folders of the exported FMUs (orchestrator/crosscheck.py).

Claims: fmpy's cross-check validator (fmpy.cross_check.validate_vendor_repo, what the
fmi-cross-check repository runs on a submission) finds no problem in the folders written for the
shared small export, and finds the problems we plant (a CSV column that is no variable, a run
past what fmpy's runner can step); a replay of each ``<Model>_in.csv`` through its FMU alone,
by fmpy's simulate_fmu exactly as fmpy's cross-check runner calls it, reproduces ``_ref.csv`` to
1e-8 relative and passes fmpy's epsilon-band comparison; the structure reference (pair under
Jacobi) equals coupled.fmu's and the project's Gauss-Seidel master's (cosimulate, motion through
the inputs ag_x, ag_y, ag_z) to round-off; ``uplift export --cross-check`` writes the folders and refuses a file
as XDIR (and a scene without a layered soil) before computing.
"""
import shutil

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.cross_check import validate_result
from fmpy.cross_check.validate_vendor_repo import validate_repo
from fmpy.util import read_csv, read_ref_opt_file

from helpers import EXPORT_MOTION, changed, export_tower, write_scene
from orchestrator.cli import main
from orchestrator.crosscheck import FMPY_MAX_INTERVALS, check_cross_check, model_folder, write_cross_check
from orchestrator.master import cosimulate

MODELS = ("structure", "soil", "coupled")
#: fmpy's validate_result imports scipy.ndimage.filters, deprecated in scipy 1.12
pytestmark = pytest.mark.filterwarnings("ignore:Please import:DeprecationWarning")


@pytest.fixture(scope="module")
def xc(exported, tmp_path_factory):
    return write_cross_check(exported, tmp_path_factory.mktemp("xc"), "small")


def files(xc, model, suffix):
    return xc.models[model] / f"{model}{suffix}"


def test_layout_and_fmpy_validator_finds_no_problem(xc, exported):
    assert xc.problems == ()
    fmu_count, result_count, problems = validate_repo(str(xc.root))
    assert (fmu_count, result_count, problems) == (3, 0, [])
    for model in MODELS:
        folder = xc.models[model]
        assert folder == model_folder(xc.root, model)
        assert folder.relative_to(xc.root).parts[:5] == ("fmus", "2.0", "cs", folder.parts[-4], "uplift")
        assert sorted(p.name for p in folder.iterdir()) == sorted(
            [f"{model}.fmu", f"{model}_in.csv", f"{model}_ref.csv", f"{model}_ref.opt", "README.md"])
        assert files(xc, model, ".fmu").read_bytes() == getattr(exported, model).read_bytes()
        opt = read_ref_opt_file(str(files(xc, model, "_ref.opt")))
        assert (opt["StartTime"], opt["StopTime"], opt["StepSize"]) == (0.0, exported.stop_time, exported.dt)
        header = files(xc, model, "_ref.csv").read_text().splitlines()[0]
        assert header.startswith('"time",') and all(n.startswith('"') for n in header.split(","))
    ref = read_csv(str(files(xc, "soil", "_ref.csv")))
    assert len(ref.dtype.names) == 8 and "dissipated_energy" in ref.dtype.names
    assert min(np.abs(ref[n]).max() for n in ref.dtype.names[1:]) > 1e3     # no round-off-level column


def test_validator_reports_planted_problems(xc, tmp_path):
    bad = tmp_path / "xc"
    shutil.copytree(xc.root, bad)
    folder = model_folder(bad, "structure")
    ref = folder / "structure_ref.csv"
    ref.write_text(ref.read_text().replace('"max_uplift"', '"max_uplift_m"', 1))
    opt = folder / "structure_ref.opt"
    dt = read_ref_opt_file(str(opt))["StepSize"]
    opt.write_text(opt.read_text().replace("StopTime, ", f"StopTime, {(FMPY_MAX_INTERVALS + 1) * dt!r}\n#", 1))
    problems = check_cross_check(bad)
    assert len(problems) == 2
    assert "max_uplift_m" in problems[0] and "does not exist" in problems[0]
    assert f"more than {FMPY_MAX_INTERVALS} intervals" in problems[1]


def test_a_failed_write_leaves_each_model_folder_whole(xc, exported, tmp_path, monkeypatch):
    """A write that fails (or is interrupted) inside a model's folder leaves that folder as it was:
    its files are staged and moved into place together (uplift_common.files.atomic_folder)."""
    import orchestrator.crosscheck as crosscheck
    root = tmp_path / "xc"
    shutil.copytree(xc.root, root)
    for p in root.rglob("*"):
        if p.is_file():
            p.write_bytes(b"a file of an earlier export")
    before = {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}

    def fails(*args):
        raise KeyboardInterrupt
    monkeypatch.setattr(crosscheck, "readme", fails)          # the last file of the first folder
    with pytest.raises(KeyboardInterrupt):
        write_cross_check(exported, root, "small")
    assert {p: p.read_bytes() for p in root.rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("model", MODELS)
def test_replay_of_in_csv_reproduces_ref_csv(xc, model):
    """Run as fmpy's cross-check runner does (python -m fmpy.cross_check --simulate)."""
    opt = read_ref_opt_file(str(files(xc, model, "_ref.opt")))
    ref = read_csv(str(files(xc, model, "_ref.csv")))
    result = simulate_fmu(str(files(xc, model, ".fmu")), validate=False, step_size=opt["StepSize"],
                          stop_time=opt["StopTime"], input=read_csv(str(files(xc, model, "_in.csv"))),
                          output=list(ref.dtype.names[1:]))
    np.testing.assert_allclose(result["time"], ref["time"], rtol=0, atol=1e-12)
    for name in ref.dtype.names[1:]:
        scale = np.abs(ref[name]).max()
        assert scale > 0, name
        np.testing.assert_allclose(result[name], ref[name], rtol=0, atol=1e-8 * scale, err_msg=name)
    assert validate_result(result, ref, opt["StartTime"], opt["StopTime"]) is None


def test_structure_reference_equals_coupled_and_the_project_master(xc, exported):
    structure = read_csv(str(files(xc, "structure", "_ref.csv")))
    coupled = read_csv(str(files(xc, "coupled", "_ref.csv")))
    gs = cosimulate(exported.structure, exported.soil, EXPORT_MOTION.acc, exported.dt)
    assert gs.info["fmu_max_uplift"] > 1e-4                   # the motion lifts the raft
    for name, key in (("max_uplift", "fmu_max_uplift"), ("max_raft_rotation", "fmu_max_raft_rotation")):
        np.testing.assert_allclose(coupled[name], structure[name], rtol=1e-10)
        assert structure[name][-1] == pytest.approx(gs.info[key], rel=1e-10)


CLI_SCENE = export_tower()


def test_cli_export_cross_check(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("UPLIFT_CACHE", str(tmp_path / "cache"))
    scene = tmp_path / "toy.toml"
    write_scene(scene, CLI_SCENE)
    xdir = tmp_path / "xc"
    assert main(["export", str(scene), "-o", str(tmp_path / "fmus"), "--cross-check", str(xdir)]) == 0
    err = capsys.readouterr().err
    assert "WARNING" not in err
    for model in MODELS:
        assert f"{model_folder(xdir, model)}/" in err
        assert (model_folder(xdir, model) / f"{model}_ref.csv").is_file()
    assert validate_repo(str(xdir))[2] == []
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    assert main(["export", str(scene), "-o", str(tmp_path / "fmus2"), "--cross-check", str(a_file)]) == 2
    assert "--cross-check" in capsys.readouterr().err and not (tmp_path / "fmus2").exists()
    winkler_only = tmp_path / "winkler.toml"                  # no BEM soil to put in the soil FMU
    write_scene(winkler_only, changed(CLI_SCENE, soil={"halfspace": None, "winkler": {"kv": 5.0e7, "kh": 4.0e7}}))
    assert main(["export", str(winkler_only), "-o", str(tmp_path / "fmus3")]) == 2
    assert "no layered soil" in capsys.readouterr().err
