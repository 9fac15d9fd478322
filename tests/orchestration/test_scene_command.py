"""`uplift scene NAME [-o FILE]`: a built-in scene written as a commented TOML that runs as it
is; `uplift run --pga/--dt/--duration`: overrides checked, applied and recorded."""
import json
import re
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

import numpy as np
import pytest

from helpers import tower, write_scene
from helpers.native import seed_native
from orchestrator import scene_file
from orchestrator.cli import main
from orchestrator.motion import G
from orchestrator.results_file import read_motion, read_results, read_scene_record
from orchestrator.scene import builtin_scenes, load_scene
from soil_impedance.sweep import table_key

BUILTINS = Path(scene_file.__file__).parent / "scenes"


def _same_results(a, b):
    """Every history of every route of two results files equal bit for bit."""
    ra, rb = read_results(a), read_results(b)
    assert list(ra) == list(rb)
    for route in ra:
        x, y = ra[route], rb[route]
        assert x.status == y.status and x.message == y.message
        for key in ("time", "raft", "gap", "contact_force", "soil_w", "newton_iters", "xy"):
            assert np.array_equal(getattr(x, key), getattr(y, key)), (route, key)
        for group in ("acc", "disp", "energy"):
            gx, gy = getattr(x, group), getattr(y, group)
            assert list(gx) == list(gy)
            assert all(np.array_equal(gx[k], gy[k]) for k in gx), (route, group)


@pytest.mark.parametrize("name", builtin_scenes())
def test_every_key_of_a_builtin_is_explained(name):
    """Each key line of a built-in scene carries a comment, on its line or in the comment block
    just above it (what `uplift scene` writes)."""
    lines = (BUILTINS / f"{name}.toml").read_text(encoding="utf-8").splitlines()
    for i, line in enumerate(lines):
        if re.match(r"\s*[A-Za-z_]+\s*=", line):
            above = lines[i - 1].strip() if i else ""
            assert "#" in line or above.startswith("#"), f"{name}.toml line {i + 1} has no comment: {line}"


@pytest.mark.parametrize("name", builtin_scenes())
def test_scene_prints_or_writes_the_builtin(name, tmp_path, capsys):
    assert main(["scene", name]) == 0
    printed = capsys.readouterr().out
    out = tmp_path / "copy.toml"
    assert main(["scene", name, "-o", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().err
    text = out.read_text(encoding="utf-8")
    assert text.startswith(f"# Written by `uplift scene {name}`") and printed.startswith(f"# Written by `uplift scene {name}`")
    builtin = tomllib.loads((BUILTINS / f"{name}.toml").read_text(encoding="utf-8"))
    files = scene_file._paths(builtin)
    if not files:
        assert text == printed and tomllib.loads(text) == builtin
        return
    # a scene that names files (l_raft's mesh): copied beside the written copy and named by their
    # name there, named by absolute path when printed; both load into the built-in scene
    for rel in files:
        assert (out.parent / Path(rel).name).read_bytes() == (BUILTINS / rel).read_bytes()
        assert f'"{Path(rel).name}"' in text and f'"{(BUILTINS / rel).resolve()}"' in printed
    elsewhere = tmp_path / "printed.toml"
    elsewhere.write_text(printed, encoding="utf-8")
    ref = load_scene(name)
    for copy in (load_scene(out), load_scene(elsewhere)):
        assert np.array_equal(copy.mesh.xy, ref.mesh.xy) and np.array_equal(copy.mesh.area, ref.mesh.area)


def test_scene_refuses_what_is_not_a_builtin(tmp_path, capsys):
    assert main(["scene", "nope"]) == 2
    assert "unknown built-in scene 'nope'" in capsys.readouterr().err
    mine = write_scene(tmp_path, tower())
    assert main(["scene", mine]) == 2
    assert "already a scene" in capsys.readouterr().err
    assert main(["scene", "reactor", "-o", str(tmp_path / "absent" / "s.toml")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_written_disk_halfspace_is_the_builtin(tmp_path, capsys):
    """The disk has no [structure]: its copy gives the same impedance sweep (the same cache key:
    every input of the BEM) and the same refusal of `uplift run`."""
    out = tmp_path / "elsewhere" / "disk.toml"
    out.parent.mkdir()
    assert main(["scene", "disk-halfspace", "-o", str(out)]) == 0
    built, copy = load_scene("disk-halfspace"), load_scene(out)
    for table in ("rigid", "gap"):
        keys = [table_key(s.profile, s.mesh, s.frequencies_hz, s.contact_kind, table) for s in (built, copy)]
        assert keys[0] == keys[1]
    capsys.readouterr()
    messages = []
    for scene in ("disk-halfspace", str(out)):
        assert main(["run", scene, "--route", "winkler", "-o", str(tmp_path / "r.h5")]) == 2
        messages.append(capsys.readouterr().err.split(": the routes")[1])
    assert messages[0] == messages[1] and "add [structure]" in messages[0]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One cache folder for the module: the native stepper's library copied in (compiled once for
    the tests), the reactor's BEM sweep made once."""
    return seed_native(tmp_path_factory.mktemp("cache"))


@pytest.mark.slow
def test_written_reactor_runs_as_the_builtin(tmp_path, cache, monkeypatch, capsys):
    """`uplift scene reactor -o s.toml; uplift run s.toml` equals `uplift run reactor` bit for
    bit (the winkler route, 1 s of the motion: one BEM sweep, shared through the cache)."""
    monkeypatch.setenv("UPLIFT_CACHE", str(cache))
    other = tmp_path / "other"
    other.mkdir()
    monkeypatch.chdir(other)
    assert main(["scene", "reactor", "-o", "s.toml"]) == 0
    common = ["--route", "winkler", "--duration", "1"]
    assert main(["run", "s.toml", *common, "-o", str(tmp_path / "copy.h5")]) == 0
    capsys.readouterr()                                     # its summary (stdout) aside
    assert main(["run", "reactor", *common, "-o", str(tmp_path / "builtin.h5"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["overrides"] == [{"option": "--duration", "value": 1.0, "key": "motion.duration_s",
                                     "was": 10.0, "now": 1.0}]
    _same_results(tmp_path / "copy.h5", tmp_path / "builtin.h5")
    assert read_results(tmp_path / "copy.h5")["winkler"].time[-1] == pytest.approx(1.0)


def test_builtin_companion_files_are_copied_or_named_absolutely(tmp_path, monkeypatch, capsys):
    """A built-in that names files (a nodes CSV, a record in a subfolder) runs from its copy in
    another folder: the files are copied beside the copy; printed, they are named by absolute path."""
    package = tmp_path / "package"
    (package / "records").mkdir(parents=True)
    (package / "raft.csv").write_text("x,y,area\n-5,-5,25\n5,-5,25\n5,5,25\n-5,5,25\n")
    t = np.arange(0, 2.0, 0.01)
    np.savetxt(package / "records" / "quake.txt", np.column_stack([t, 0.2 * np.sin(2 * np.pi * 2 * t)]))
    data = tower(foundation={"shape": "nodes", "file": "raft.csv", "lx": None, "ly": None, "element_size": None},
                 motion={"kind": "record", "file": "records/quake.txt", "pga_g": None, "duration_s": None,
                         "seed": None})
    write_scene(package / "fake.toml", data, extra="# records/quake.txt is 2 s of a 2 Hz sine\n")
    monkeypatch.setattr(scene_file, "builtin_scenes", lambda: ["fake"])
    monkeypatch.setattr(scene_file.resources, "files", lambda _: package)
    out = tmp_path / "elsewhere" / "fake.toml"
    out.parent.mkdir()
    assert main(["scene", "fake", "-o", str(out)]) == 0
    assert {p.name for p in out.parent.iterdir()} == {"fake.toml", "raft.csv", "quake.txt"}
    assert 'file = "quake.txt"' in out.read_text() and "# records/quake.txt is 2 s" in out.read_text()  # comments kept
    assert main(["scene", "fake"]) == 0
    printed = tmp_path / "printed.toml"
    printed.write_text(capsys.readouterr().out)
    assert str(package / "records" / "quake.txt") in printed.read_text()
    original = load_scene(package / "fake.toml")
    for copy in (load_scene(out), load_scene(printed)):
        assert np.array_equal(copy.mesh.xy, original.mesh.xy)
        assert np.array_equal(copy.motion.record.acc, original.motion.record.acc)


@pytest.fixture
def small(tmp_path, cache, monkeypatch):
    """The small tower (winkler route on given moduli: no BEM), 3 s at 0.3 g, dt 10 ms."""
    monkeypatch.setenv("UPLIFT_CACHE", str(cache))
    return write_scene(tmp_path, tower())


def test_overrides_change_what_they_say(small, tmp_path, capsys):
    base, over = tmp_path / "base.h5", tmp_path / "over.h5"
    assert main(["run", small, "-o", str(base)]) == 0
    capsys.readouterr()
    assert main(["run", small, "--pga", "0.6", "--dt", "0.005", "--duration", "1.5", "-o", str(over)]) == 0
    text = capsys.readouterr().out                          # the summary, with the overrides: stdout
    assert "override: --pga 0.6: motion.pga_g = 0.6 (the scene's: 0.3)" in text
    assert "override: --dt 0.005: analysis.dt = 0.005 (the scene's: 0.01)" in text
    r0, r1 = read_results(base)["winkler"], read_results(over)["winkler"]
    assert r0.time[-1] == pytest.approx(3.0) and r1.time[-1] == pytest.approx(1.5)       # --duration
    assert np.diff(r0.time)[0] == pytest.approx(0.01) and np.diff(r1.time)[0] == pytest.approx(0.005)  # --dt
    m0, m1 = read_motion(base)[2], read_motion(over)[2]
    assert m0.pga[0] / G == pytest.approx(0.3, rel=0.02)     # --pga (at 10 ms: resampled from 5 ms)
    assert m1.pga[0] / G == pytest.approx(0.6, rel=1e-9)     # at the synthetic motion's own 5 ms: exact
    record = read_scene_record(over)
    assert [(o["option"], o["key"], o["was"], o["now"]) for o in record["overrides"]] == [
        ("--dt", "analysis.dt", 0.01, 0.005), ("--duration", "motion.duration_s", 3.0, 1.5),
        ("--pga", "motion.pga_g", 0.3, 0.6)]
    assert read_scene_record(base)["overrides"] == []
    stored = tmp_path / "stored.toml"                  # the stored scene is the scene that ran
    stored.write_text(record["scene_toml"])
    again = load_scene(stored)
    assert (again.motion.pga_g, again.motion.duration_s, again.analysis.dt) == (0.6, 1.5, 0.005)
    assert "# override: --pga 0.6 sets motion.pga_g = 0.6 (was 0.3)" in record["scene_toml"]


def test_pga_scales_a_record(tmp_path, cache, monkeypatch, capsys):
    monkeypatch.setenv("UPLIFT_CACHE", str(cache))
    t = np.arange(0, 2.0, 0.01)
    np.savetxt(tmp_path / "quake.txt", np.column_stack([t, 0.2 * np.sin(2 * np.pi * 2 * t)]))
    path = write_scene(tmp_path / "rec.toml", tower(motion={"kind": "record", "file": "quake.txt", "scale": 1.5,
                                                             "pga_g": None, "duration_s": None, "seed": None}))
    scene = load_scene(path, pga_g=0.45)
    raw = np.abs(0.2 * np.sin(2 * np.pi * 2 * t)).max()              # the file's peak, g
    assert scene.motion.scale == pytest.approx(0.45 / raw, rel=1e-12)
    assert scene.motion.record.pga[0] / G == pytest.approx(0.45, rel=1e-12)
    assert scene.overrides[0]["key"] == "motion.scale"
    assert main(["run", path, "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert "--duration 1 sets [motion].duration_s of a synthetic motion" in err and "drop --duration" in err


@pytest.mark.parametrize("option", ["--pga", "--dt", "--duration"])
@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "x"])
def test_overrides_refuse_what_is_not_positive(small, option, value, capsys):
    assert main(["run", small, option, value]) == 2
    assert f"argument {option}: {value!r}" in capsys.readouterr().err


@pytest.mark.parametrize("args, says", [
    (["--dt", "0.1"], "--dt 0.1: analysis.dt = 0.1 must be a step in (0, 0.05]"),
    (["--duration", "0.05"], "--duration 0.05: motion.duration_s = 0.05 s is too short"),
    (["--pga", "7"], "--pga 7: motion.pga_g = 7 exceeds the intensity limit"),
    (["--pga", "7", "--max-pga", "6"], "--pga 7: motion.pga_g = 7 exceeds the intensity limit analysis.max_pga_g = 6"),
])
def test_overrides_out_of_range_name_the_option(small, args, says, tmp_path, capsys):
    assert main(["run", small, *args, "-o", str(tmp_path / "r.h5")]) == 2
    assert says in capsys.readouterr().err
    assert not (tmp_path / "r.h5").exists()
