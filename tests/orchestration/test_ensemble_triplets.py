"""`uplift ensemble` over records of three components: a folder is one record (its components
told by PEER's file names or by a components.toml), scaled so that its stronger horizontal
reaches the PGA; every cell equals `uplift run` of the scene with those files and that scale;
--seeds of a synthetic motion of three components; the components a folder cannot be told
from are refused with the folder and the fix. The small scene of test_ensemble (reactor stick
on a 21-node raft, 1.5 s records), on the session's scheduler of one worker (conftest)."""
import contextlib
import io
import json

import numpy as np
import pytest
import xarray as xr
from helpers import changed, small_reactor, toml_text, write_scene
from helpers.native import seed_native

from orchestrator import ensemble as ens
from orchestrator.cli import main
from orchestrator.motion import G, make_motion
from orchestrator.results_file import read_results
from orchestrator.scene import load_scene
from orchestrator.spectra import response_spectrum

SCENE = small_reactor()
PGAS = (0.4, 0.8)
T = 0.01 * np.arange(151)


def _pulse(f_hz, t0, seed, peak):
    """A pulse of f_hz around t0 s with some noise, peaking at ``peak`` (g)."""
    a = np.sin(2 * np.pi * f_hz * T) * np.exp(-((T - t0) / 0.3) ** 2)
    a += 0.2 * np.random.default_rng(seed).standard_normal(T.size) * np.exp(-((T - t0 - 0.1) / 0.4) ** 2)
    return peak * a / np.abs(a).max()


#: two records, their components' values in g: A (y the stronger horizontal) as PEER AT2 files
#: named by azimuth, B (a vertical stronger than both horizontals) as two-column files told by
#: a components.toml
RECORDS = {"A": {"x": _pulse(2.0, 0.6, 1, 0.3), "y": _pulse(3.0, 0.7, 2, 0.5), "z": _pulse(6.0, 0.6, 3, 0.25)},
           "B": {"x": _pulse(2.5, 0.5, 4, 0.4), "y": _pulse(1.5, 0.8, 5, 0.2), "z": _pulse(8.0, 0.5, 6, 0.6)}}
#: record A's PEER names: x = 090 (east), y = 000 (north), z = -UP
PEER_NAMES = {"x": "RSN99_TEST_STA090.AT2", "y": "RSN99_TEST_STA000.AT2", "z": "RSN99_TEST_STA-UP.AT2"}


def _at2(path, values):
    lines = ["PEER NGA STRONG MOTION DATABASE RECORD", "test record", "ACCELERATION TIME SERIES IN UNITS OF G",
             f"NPTS=  {values.size}, DT=   .0100 SEC"]
    lines += ["  ".join(f"{v:.10E}" for v in values[k:k + 5]) for k in range(0, values.size, 5)]
    path.write_text("\n".join(lines) + "\n")
    return np.array([float(v) for ln in lines[4:] for v in ln.split()])


def _write_triplets(root):
    """Folder A (PEER names, with PEER's velocity file and search table beside), folder B
    (components.toml, and a stray record file it leaves out); returns {label: {axis: (path,
    values as written, g)}}."""
    a, b = root / "A", root / "B"
    a.mkdir()
    b.mkdir()
    out = {"A": {}, "B": {}}
    for axis, name in PEER_NAMES.items():
        out["A"][axis] = (a / name, _at2(a / name, RECORDS["A"][axis]))
    (a / "RSN99_TEST_STA090.VT2").write_text("not a record\n")
    (a / "_SearchResults.csv").write_text("not a record\n")
    for axis, name in zip("xyz", ("east.txt", "north.txt", "vertical.txt")):
        np.savetxt(b / name, np.column_stack([T, RECORDS["B"][axis]]))
        out["B"][axis] = (b / name, np.loadtxt(b / name)[:, 1])
    np.savetxt(b / "other.txt", np.column_stack([T, T]))
    (b / "components.toml").write_text('# the components of this record\nx = "east.txt"\ny = "north.txt"\n'
                                       'z = "vertical.txt"\n')
    return out


@pytest.fixture(scope="module")
def case(tmp_path_factory, scheduler):
    """`uplift ensemble SCENE --records A B --pga 0.4 0.8 --json` on the session's scheduler (one
    worker), a cache shared by the module."""
    tmp = tmp_path_factory.mktemp("triplets")
    env = pytest.MonkeyPatch()
    env.setenv("UPLIFT_CACHE", str(seed_native(tmp / "cache")))     # the C runtime compiled once for the tests
    scene = tmp / "small.toml"
    write_scene(scene, SCENE)
    triplets = _write_triplets(tmp)
    out = tmp / "ens.h5"
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(["ensemble", str(scene), "--records", str(tmp / "A"), str(tmp / "B"), "--pga", *map(str, PGAS),
                     "--scheduler", scheduler, "-o", str(out), "--json"])
    yield {"tmp": tmp, "scene": scene, "triplets": triplets, "out": out, "code": code, "log": stderr.getvalue(),
           "summary": json.loads(stdout.getvalue()), "ds": xr.open_dataset(out, engine="h5netcdf").load()}
    env.undo()


def _with_motion(motion: str) -> str:
    """The scene with ``motion`` as its [motion] table (its lines up to the next table)."""
    return toml_text(changed(SCENE, motion=None)) + motion


def _run(scene_text: str, tmp):
    """`uplift run --json` of the scene ``scene_text``: (summary, RouteResult)."""
    path = tmp / "cell.toml"
    path.write_text(scene_text)
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(["run", str(path), "-o", str(tmp / "cell.h5"), "--json"]) == 0
    return json.loads(stdout.getvalue())["routes"]["monolithic"], read_results(tmp / "cell.h5")["monolithic"]


def _same_cell(cell, s, res, frequencies):
    """An ensemble cell against its single run: the summary's numbers and the floor spectra to 1e-10."""
    rel = lambda a, b: abs(a - b) / abs(b)
    assert str(cell["status"].values) == "converged"
    assert rel(float(cell["max_uplift"]), s["max_uplift_m"]) < 1e-10
    assert rel(float(cell["max_raft_rotation"]), s["max_raft_rotation_rad"]) < 1e-10
    assert float(cell["min_contact_ratio"]) == pytest.approx((res.gap <= 0).mean(axis=1).min(), rel=1e-10, abs=1e-12)
    for node in ("top_outer", "internals_37m"):
        acc = res.acc[node]
        spectra = np.array([response_spectrum(acc[:, j], 0.005, 1 / frequencies, 0.05).psa for j in range(3)])
        got = cell["floor_spectrum"].sel(node=node).values
        np.testing.assert_allclose(got, spectra, rtol=1e-10, atol=1e-10 * spectra.max())


def test_triplets_equal_uplift_run_of_their_three_files(case, tmp_path, monkeypatch):
    """Each (triplet, PGA): `uplift run` of [motion] components = {x, y, z} = the triplet's files,
    scale = PGA / the stronger horizontal's peak (computed here from the values written)."""
    monkeypatch.setenv("UPLIFT_CACHE", str(case["tmp"] / "cache"))
    ds, summ = case["ds"], case["summary"]
    assert case["code"] == 0
    assert list(ds["record"].values) == ["A", "B"] and ds.attrs["components"] == "x y z"
    assert summ["components"] == ["x", "y", "z"] and (summ["runs"], summ["converged"], summ["workers"]) == (4, 4, 1)
    assert "A: x = RSN99_TEST_STA090.AT2, y = RSN99_TEST_STA000.AT2, z = RSN99_TEST_STA-UP.AT2" in case["log"]
    uplifts = {}
    for label, comps in case["triplets"].items():
        peaks = {a: np.abs(v).max() for a, (_, v) in comps.items()}
        for a, (path, _) in comps.items():
            assert str(ds["record_file"].sel(record=label, direction=a).values) == str(path.resolve())
            assert float(ds["record_peak"].sel(record=label, direction=a)) == pytest.approx(peaks[a], rel=1e-12)
        fmt = "peer-at2" if label == "A" else "two-column"
        files = ", ".join(f'{a} = "{p.resolve()}"' for a, (p, _) in comps.items())
        for pga in PGAS:
            scale = float(pga / max(peaks["x"], peaks["y"]))      # the vertical of B is stronger: not the reference
            assert float(ds["record_scale"].sel(record=label, pga=pga)) == pytest.approx(scale, rel=1e-12)
            s, res = _run(_with_motion(f'[motion]\nkind = "record"\nformat = "{fmt}"\nunits = "g"\n'
                                       f"components = {{ {files} }}\nscale = {scale!r}\n"), tmp_path)
            assert s["components"] == ["x", "y", "z"]
            _same_cell(ds.sel(record=label, pga=pga, route="monolithic"), s, res, ds["frequency"].values)
            uplifts[label, pga] = s["max_uplift_m"]
    assert min(uplifts.values()) > 1e-4           # every cell lifts the raft: the comparison bites
    for pga in PGAS:                               # the median of two records: their mean
        assert float(ds["max_uplift_fractile"].sel(quantile=0.5, pga=pga, route="monolithic")) == \
            pytest.approx((uplifts["A", pga] + uplifts["B", pga]) / 2, rel=1e-12)


def test_the_cells_run_the_scaled_triplet(case):
    """The motion of each cell (what its route steps): the stronger horizontal peaks at the PGA,
    the other components by the same factor (B's vertical above the PGA)."""
    plan = ens.plan_ensemble(load_scene(case["scene"]), PGAS, records=[case["tmp"] / "A", case["tmp"] / "B"])
    for cell in plan.cells:
        label, pga = plan.records[cell.index[0]].label, plan.pgas[cell.index[1]]
        motion = make_motion(cell.scene.motion, 0.01)
        raw = {a: np.abs(v).max() for a, (_, v) in case["triplets"][label].items()}
        factor = pga / max(raw["x"], raw["y"])
        np.testing.assert_allclose(motion.pga / G, [raw[a] * factor for a in "xyz"], rtol=1e-12)
        assert max(motion.pga[:2]) / G == pytest.approx(pga, rel=1e-12)
    assert plan.components == ("x", "y", "z")


def test_scaled_vertical_over_the_intensity_limit_is_refused(case, capsys):
    """B's vertical is 1.5 times its stronger horizontal: at 0.8 g it peaks at 1.2 g > 1 g."""
    assert main(["ensemble", str(case["scene"]), "--records", str(case["tmp"] / "B"), "--pga", "0.8",
                 "--max-pga", "1.0", "-o", str(case["tmp"] / "refused.h5")]) == 2
    err = capsys.readouterr().err
    assert "--records 'B' at --pga 0.8" in err and "component z (vertical.txt) peaks at 1.2 g" in err
    assert "analysis.max_pga_g = 1 g" in err and not (case["tmp"] / "refused.h5").exists()


@pytest.mark.slow
def test_seeds_give_independent_synthetic_triplets(case, tmp_path, monkeypatch, scheduler):
    """A synthetic scene of three components: each seed a triplet; the cells equal `uplift run`."""
    monkeypatch.setenv("UPLIFT_CACHE", str(case["tmp"] / "cache"))
    scene_text = toml_text(changed(SCENE, motion={"components": ["x", "y", "z"], "vertical_ratio": 0.5}))
    scene = tmp_path / "syn.toml"
    scene.write_text(scene_text)
    ds = ens.run_ensemble(scene, [0.5], seeds=[1, 2], scheduler=scheduler, cache_dir=case["tmp"] / "cache")
    assert ds.attrs["components"] == "x y z" and ds.attrs["vertical_ratio"] == 0.5
    assert list(ds["seed"].values) == [1, 2]
    uplifts = []
    for seed in (1, 2):
        s, res = _run(scene_text.replace("pga_g = 0.3", "pga_g = 0.5").replace("seed = 3", f"seed = {seed}"), tmp_path)
        assert s["components"] == ["x", "y", "z"]
        _same_cell(ds.sel(record=f"seed {seed}", pga=0.5, route="monolithic"), s, res, ds["frequency"].values)
        uplifts.append(s["max_uplift_m"])
    assert uplifts[0] != uplifts[1]


# ---- telling the components of a folder --------------------------------------------------------

@pytest.mark.parametrize("name, component", [
    ("RSN6_IMPVALL.I_I-ELC180.AT2", 180.0), ("RSN6_IMPVALL.I_I-ELC270.AT2", 270.0),
    ("RSN6_IMPVALL.I_I-ELC-UP.AT2", "z"), ("RSN1_HELENA.A_A-HMCDWN.AT2", "z"),
    ("RSN766_LOMAP_G02000.AT2", 0.0), ("RSN766_LOMAP_G02090.AT2", 90.0), ("RSN9_BORREGO_B-ELC360.AT2", 0.0),
    ("RSN1485_CHICHI_TCU045-E.AT2", "x"), ("RSN1485_CHICHI_TCU045-N.AT2", "y"), ("RSN1485_CHICHI_TCU045-V.AT2", "z"),
    ("RSN143_TABAS_TAB-L1.AT2", "x"), ("RSN143_TABAS_TAB-T1.AT2", "y"),
    ("RSN9999_EVENT_STA_H1.AT2", "x"), ("rsn9999_event_sta_h2.at2", "y"), ("RSN9999_EVENT_STA_UP.txt", "z"),
    ("NIGH11EW.AT2", "x"), ("NIGH11NS.AT2", "y"), ("NIGH11UD.AT2", "z"),
    ("STAN10W.AT2", 350.0), ("STAS80W.AT2", 260.0), ("STAS10E.AT2", 170.0),
    ("rec0.txt", None), ("record.AT2", None), ("STA-X.AT2", None), ("STA999.AT2", None),
])
def test_peer_names(name, component):
    assert ens.peer_component(name) == component


def _folder(root, names, toml=None):
    root.mkdir()
    for n in names:
        np.savetxt(root / n, np.column_stack([T, _pulse(2.0, 0.6, 1, 0.3)]))
    if toml is not None:
        (root / "components.toml").write_text(toml)
    return root


def test_folder_components(tmp_path):
    sfx = ens.RECORD_SUFFIXES
    d = _folder(tmp_path / "chichi", ["S-N.txt", "S-V.txt", "S-E.txt", "notes.csv"])
    assert ens.folder_components(d, sfx) == ({"x": d / "S-E.txt", "y": d / "S-N.txt", "z": d / "S-V.txt"},
                                             "PEER names")
    # azimuths: x is 90 degrees clockwise of y (east of north), whatever the order of the names
    for pair, x in ((("a180.txt", "a270.txt"), "a270.txt"), (("b000.txt", "b270.txt"), "b000.txt"),
                    (("c045.txt", "c315.txt"), "c045.txt")):
        d = _folder(tmp_path / pair[0][0], pair)
        assert ens.folder_components(d, sfx)[0]["x"].name == x
    d = _folder(tmp_path / "one", ["s090.txt", "s-UP.txt"])
    assert ens.folder_components(d, sfx)[0] == {"x": d / "s090.txt", "z": d / "s-UP.txt"}
    # components.toml wins over the names (here swapping them) and may leave files out
    d = _folder(tmp_path / "toml", ["s-E.txt", "s-N.txt", "s-V.txt"], 'y = "s-E.txt"\nx = "s-N.txt"\n')
    assert ens.folder_components(d, sfx) == ({"x": d / "s-N.txt", "y": d / "s-E.txt"}, "components.toml")


@pytest.mark.parametrize("names, toml, message", [
    (["rec0.txt", "rec1.txt"], None, "cannot tell the component of 'rec0.txt' from its name"),
    (["s-UP.txt", "sDWN.txt", "s-E.txt"], None, "'s-UP.txt' and 'sDWN.txt' both name the component z"),
    (["s000.txt", "s045.txt"], None, "'s000.txt' (0 deg) and 's045.txt' (45 deg) are not at right angles"),
    (["s000.txt", "s090.txt", "s180.txt"], None, "3 horizontals by azimuth"),
    (["s000.txt", "s_H1.txt", "s-UP.txt"], None, "horizontals named both by azimuth (s000.txt) and by name (s_H1.txt)"),
    ([], None, "no record files in this folder"),
    (["a.txt"], 'x = "a.txt"\nw = "a.txt"\n', "unknown key 'w'"),
    (["a.txt"], 'x = "b.txt"\n', "x = 'b.txt': no such file in"),
    (["a.txt"], 'x = "a.txt"\ny = "a.txt"\n', "'a.txt' is given for two components"),
    (["a.txt"], "x = a.txt\n", "cannot read it as TOML"),
    (["a.txt"], "", "no component"),
])
def test_folders_that_cannot_be_told_are_refused(case, tmp_path, capsys, names, toml, message):
    d = _folder(tmp_path / "rec", names, toml)
    assert main(["ensemble", str(case["scene"]), "--records", str(d), "--pga", "0.3", "-o", str(tmp_path / "e.h5")]) == 2
    err = capsys.readouterr().err
    assert message in err and str(d) in err
    if toml is None and names:       # the fix: a components.toml, or the files one by one
        assert "Write components.toml in it" in err and "give the files themselves" in err
    assert not (tmp_path / "e.h5").exists()


def test_records_that_do_not_go_together_are_refused(case, tmp_path):
    scene = load_scene(case["scene"])
    a = _folder(tmp_path / "a", ["s-E.txt", "s-N.txt", "s-V.txt"])
    b = _folder(tmp_path / "b", ["s-E.txt", "s-V.txt"])
    with pytest.raises(ens.EnsembleError, match="'a' has the components x, y, z and 'b' x, z: every record"):
        ens.plan_ensemble(scene, [0.3], records=[a, b])
    with pytest.raises(ens.EnsembleError, match="give at least one record folder or file"):
        ens.plan_ensemble(scene, [0.3], records=[])
    with pytest.raises(ens.EnsembleError, match="give folders .* or files .*, not both"):
        ens.plan_ensemble(scene, [0.3], records=[a, b / "s-E.txt"])
    c = _folder(tmp_path / "c", ["s-E.txt"])
    np.savetxt(c / "s-V.txt", np.column_stack([T[:100], T[:100]]))
    with pytest.raises(ens.EnsembleError, match=r"--records 'c': the records differ in their lengths .*s-V.txt"):
        ens.plan_ensemble(scene, [0.3], records=[c])
    d = _folder(tmp_path / "d", ["s-E.txt"])
    _at2(d / "s-UP.AT2", T)
    with pytest.raises(ens.EnsembleError, match="its files are of different formats"):
        ens.plan_ensemble(scene, [0.3], records=[d])
    e = _folder(tmp_path / "e", ["s-E.txt"])
    np.savetxt(e / "s-N.txt", np.column_stack([T, 0 * T]))
    (e / "s-E.txt").write_text((e / "s-N.txt").read_text())
    with pytest.raises(ens.EnsembleError, match="'e': the horizontals are zero everywhere"):
        ens.plan_ensemble(scene, [0.3], records=[e])
    xz = tmp_path / "xz.toml"
    write_scene(xz, changed(SCENE, motion={"components": ["x", "z"]}))
    with pytest.raises(ens.EnsembleError, match="a file is a one-component record on .motion..direction"):
        ens.plan_ensemble(load_scene(xz), [0.3], records=[a / "s-E.txt"])


def test_vertical_alone_is_scaled_on_its_peak_and_keys_follow_the_content(case, tmp_path):
    scene = load_scene(case["scene"])
    z = _folder(tmp_path / "z", ["s-UP.txt"])
    plan = ens.plan_ensemble(scene, [0.3], records=[z])
    assert plan.components == ("z",)
    assert make_motion(plan.cells[0].scene.motion, 0.01).pga[2] / G == pytest.approx(0.3, rel=1e-12)
    # a folder's key: its files' content and components, not its path
    a = _folder(tmp_path / "a", ["s-E.txt", "s-V.txt"])
    moved = _folder(tmp_path / "elsewhere", ["s-E.txt", "s-V.txt"])
    swapped = _folder(tmp_path / "swapped", ["s-E.txt", "s-V.txt"], 'x = "s-V.txt"\nz = "s-E.txt"\n')
    for d in (a, moved, swapped):        # a vertical other than the horizontal
        np.savetxt(d / "s-V.txt", np.column_stack([T, _pulse(7.0, 0.4, 9, 0.2)]))
    key = lambda d: ens.plan_ensemble(scene, [0.3], records=[d]).cells[0].key
    assert key(moved) == key(a) and key(swapped) != key(a)


def test_scene_of_three_record_files_runs_as_one_record(case):
    """Without --records, a scene whose [motion] has record components is one record."""
    tmp = case["tmp"]
    files = ", ".join(f'{a} = "{p}"' for a, (p, _) in case["triplets"]["B"].items())
    path = tmp / "own.toml"
    path.write_text(_with_motion(f'[motion]\nkind = "record"\ncomponents = {{ {files} }}\n'))
    plan = ens.plan_ensemble(load_scene(path), [0.4])
    (rec,) = plan.records
    assert rec.label == "east.txt + north.txt + vertical.txt" and plan.components == ("x", "y", "z")
    peaks = {a: np.abs(v).max() for a, (_, v) in case["triplets"]["B"].items()}
    assert rec.scale(0.4) == pytest.approx(0.4 / peaks["x"], rel=1e-12)
    # the same cell as the folder B's (its key: the files' content, not the paths)
    assert plan.cells[0].key == ens.plan_ensemble(load_scene(case["scene"]), [0.4], records=[tmp / "B"]).cells[0].key


def test_older_files_say_their_direction():
    assert ens.ensemble_components(xr.Dataset(attrs={"motion_direction": "y"})) == ("y",)
    assert ens.ensemble_components(xr.Dataset(attrs={"components": "x z"})) == ("x", "z")
