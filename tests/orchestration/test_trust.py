"""Trust round four: no orphans after kill -9, a full disk is a clean error, Ctrl-C at any
instant, absurd magnitudes refused (issue 35, items 2-5).

- Orphans: a writer killed (SIGKILL) inside ``atomic_output`` or ``atomic_folder`` leaves its
  temporary, named with its host and pid; the next write to the same place removes it (its
  process is gone), keeps the temporaries of live processes and of other machines, and the
  output path holds the old file or the new one, whole. Through the command line: ``uplift run``
  killed while it writes its results, then run again.
- Full disk: the file system refuses the data (ENOSPC stubbed at the write, the flush or the
  close in process; a real EFBIG from a file size limit, RLIMIT_FSIZE, in a child process):
  exit 3 (EXIT_WRITE), one line naming the path, no traceback, nothing partial, the old output
  as it was; the cache only warns.
- Ctrl-C: SIGINT delivered by a hook in a child process while the results are written, at the
  rename, after it, inside a ``__del__`` (where Python swallows the KeyboardInterrupt), and at
  the ensemble's final write: exit 130, one line saying whether the output was committed, no
  "Exception ignored" message, never exit 0 nor death by the signal.
- Magnitudes: each physical input beyond its plausible range (uplift_common.ranges) is refused
  before any computation, naming the key, the value and the range, with nothing else on stderr
  (numpy warnings are errors here).
"""
import errno
import os
import re
import signal
import subprocess
import sys
import time
import warnings

import h5py
import numpy as np
import pytest

import uplift_common.files as files
from orchestrator.cli import main
from orchestrator.exit_codes import EXIT_INPUT, EXIT_INTERRUPTED, EXIT_OK, EXIT_WRITE
from orchestrator.scene import SceneError, scene_from_dict
from soil_impedance.cache import CacheWarning, write_entry
from uplift_common.files import OutputWriteError, atomic_folder, atomic_output, stamp_checksum, sweep_orphans
from uplift_common.ranges import MAX_LAYERS, MAX_STRUCTURE_NODES, PLAUSIBLE, plausible_range
from helpers import ROOT, changed, tower, write_scene
from helpers.native import seed_native
from helpers.scenes import export_tower

POSIX = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and resource limits")
#: the small tower on explicit Winkler moduli (no BEM): a run takes about a second
WINKLER = tower(soil={"halfspace": None})
OLD = b"a previous output, to be left as it was\n"


def _env(tmp_path):
    cache = os.environ.get("UPLIFT_CACHE") or str(seed_native(tmp_path / "cache"))   # the C runtime compiled once
    return {**os.environ, "PYTHONPATH": str(ROOT), "UPLIFT_CACHE": cache, "OPENBLAS_NUM_THREADS": "1",
            "PYTHONDONTWRITEBYTECODE": "1"}


def _temporaries(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# ---- orphans --------------------------------------------------------------------------------------

KILLED_WRITER = """
import os, signal, sys
from uplift_common.files import atomic_folder, atomic_output
kind, path = sys.argv[1], sys.argv[2]
with (atomic_output(path) if kind == "file" else atomic_folder(path)) as tmp:
    target = tmp if kind == "file" else tmp / "structure.fmu"
    target.write_bytes(b"half of a new file" * 50000)
    os.kill(os.getpid(), signal.SIGKILL)
"""


@POSIX
@pytest.mark.parametrize("kind", ["file", "folder"])
def test_temporaries_of_a_killed_writer_are_swept_by_the_next_write(kind, tmp_path):
    out = tmp_path / ("out.h5" if kind == "file" else "export")
    old = out if kind == "file" else out / "structure.fmu"
    old.parent.mkdir(exist_ok=True)
    old.write_bytes(OLD)
    where = out.parent if kind == "file" else out
    p = subprocess.run([sys.executable, "-c", KILLED_WRITER, kind, str(out)], env=_env(tmp_path))
    assert p.returncode == -signal.SIGKILL
    left = _temporaries(where)
    assert len(left) == 1 and old.read_bytes() == OLD                  # the old file whole, the temporary left
    # temporaries of a live process, of another machine: kept; of a dead one, for another file: swept too
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        name = "out.h5" if kind == "file" else "stage"
        kept = [f".{name}.{files.HOST}-{live.pid}.abcdef.tmp", f".{name}.00000000-{_dead_pid()}.abcdef.tmp"]
        for k in kept + [f".other.h5.{files.HOST}-{_dead_pid()}.abcdef.tmp"]:
            (where / k).write_bytes(b"x")
        kept.append(f".gone.h5.{_dead_pid()}.abcdef.tmp")  # the older form, no host: kept while gone.h5 is absent
        (where / kept[-1]).write_bytes(b"x")
        files._SWEPT.clear()                       # this test process has swept the folder before
        if kind == "file":
            with atomic_output(out) as tmp:
                tmp.write_bytes(b"new")
        else:
            with atomic_folder(out) as stage:
                (stage / "structure.fmu").write_bytes(b"new")
        assert _temporaries(where) == sorted(kept) and old.read_bytes() == b"new"
    finally:
        live.kill()
        live.wait()
    # the live process gone, a sweep removes its temporary; never the other machine's
    assert [p.name for p in sweep_orphans(where)] == [kept[0]]
    (where / "gone.h5").write_bytes(b"")           # the older form goes once its file is there
    assert [p.name for p in sweep_orphans(where)] == [kept[2]]
    assert _temporaries(where) == [kept[1]]


@POSIX
def test_run_killed_while_writing_leaves_the_old_file_and_the_next_run_sweeps(tmp_path):
    """`uplift run -o out.h5` killed (SIGKILL) with the new results complete in their temporary,
    at the rename: the old out.h5 is intact, the temporary left; the next run writes out.h5 and
    removes it."""
    scene = write_scene(tmp_path / "s.toml", WINKLER)
    out = tmp_path / "out.h5"
    out.write_bytes(OLD)
    # killed at the rename of the output (cache entries, e.g. the synthetic motion, go in before)
    hook = ("import os, signal\nreplace = os.replace\nos.replace = lambda a, b: os.kill(os.getpid(), signal.SIGKILL) "
            "if str(b).endswith('out.h5') else replace(a, b)\n")
    p = _cli(hook, ["run", scene, "-o", str(out)], tmp_path)
    assert p.returncode == -signal.SIGKILL, p.stderr
    assert out.read_bytes() == OLD and len(_temporaries(tmp_path)) == 1
    p = _cli("", ["run", scene, "-o", str(out)], tmp_path)
    assert p.returncode == EXIT_OK, p.stderr
    assert _temporaries(tmp_path) == []
    with h5py.File(out, "r") as f:
        files.require_checksum(f, out)


def _cli(hook: str, argv, tmp_path, preexec=None):
    """``uplift argv`` in a child process after ``hook`` (Python source run first: patches), SIGINT
    at its default (a child started from a shell's background job inherits it ignored) and then
    ``preexec``."""
    def setup():
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        if preexec is not None:
            preexec()
    code = f"{hook}\nimport sys\nfrom orchestrator.cli import main\nsys.argv = ['uplift', *sys.argv[1:]]\nsys.exit(main())"
    return subprocess.run([sys.executable, "-c", code, *argv], cwd=tmp_path, env=_env(tmp_path), text=True,
                          capture_output=True, preexec_fn=setup, timeout=300)


# ---- a full disk --------------------------------------------------------------------------------

def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.mark.parametrize("point", ["write", "flush", "close"])
def test_atomic_output_on_a_full_disk(point, tmp_path, monkeypatch):
    """ENOSPC at the write of the data, the flush of the HDF5 file, the fsync of the temporary:
    OutputWriteError naming the path and the space left; the old file intact, no temporary."""
    out = tmp_path / "out.h5"
    out.write_bytes(OLD)
    if point == "flush":
        monkeypatch.setattr(h5py.File, "flush", _enospc)
    if point == "close":
        monkeypatch.setattr(os, "fsync", _enospc)
    with pytest.raises(OutputWriteError) as err, atomic_output(out) as tmp, h5py.File(tmp, "w") as f:
        f["a"] = np.arange(10.0)
        if point == "write":
            _enospc()
        stamp_checksum(f)
    assert re.search(rf"cannot write '{re.escape(str(out))}': no space left on device \(errno ENOSPC\); "
                     r"[0-9.]+ \w+ free on its file system; .* a previous out.h5 is left as it was", str(err.value))
    assert out.read_bytes() == OLD and _temporaries(tmp_path) == []


def test_an_append_on_a_full_disk_leaves_the_file_as_it_was(tmp_path, monkeypatch):
    """atomic_update (`uplift fragility` storing its fits in the ensemble file): the append is
    made in memory; the disk refuses the new image: OutputWriteError, the file byte for byte."""
    from uplift_common.files import atomic_update, hdf5_output, require_checksum
    path = tmp_path / "e.h5"
    with hdf5_output(path) as f:
        f["a"] = np.arange(5.0)
        stamp_checksum(f)
    before = path.read_bytes()
    monkeypatch.setattr(os, "fsync", _enospc)
    with pytest.raises(OutputWriteError, match="cannot write .*e.h5': no space left on device"), \
            atomic_update(path) as copy, h5py.File(copy, "r+") as f:
        f["b"] = np.arange(1e5)
    assert path.read_bytes() == before and _temporaries(tmp_path) == []
    monkeypatch.undo()
    with atomic_update(path) as copy, h5py.File(copy, "r+") as f:
        f["b"] = np.arange(3.0)
    with h5py.File(path, "r") as f:
        require_checksum(f, path)
        assert list(f) == ["a", "b"]


def test_atomic_folder_on_a_full_disk_leaves_no_folder_it_made(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "fsync", _enospc)
    with pytest.raises(OutputWriteError, match="nothing was written"), \
            atomic_folder(tmp_path / "new" / "report") as stage:
        (stage / "report.html").write_text("<html>")
    assert list(tmp_path.iterdir()) == []


def test_cache_on_a_full_disk_warns_and_goes_on(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "fsync", _enospc)

    def writer(path):
        with atomic_output(path) as tmp, h5py.File(tmp, "w") as f:
            f["a"] = 1.0
            stamp_checksum(f)
    with pytest.warns(CacheWarning, match="no space left on device"):
        write_entry(tmp_path / "cache" / "entry.h5", writer)
    assert list((tmp_path / "cache").iterdir()) == []


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A results file of the Winkler tower (for report)."""
    folder = tmp_path_factory.mktemp("results")
    scene = write_scene(folder / "s.toml", WINKLER)
    assert main(["run", scene, "-o", str(folder / "r.h5")]) == EXIT_OK
    return folder / "r.h5"


def _old_outputs(tmp_path):
    """The outputs of every writing command, each holding OLD (a report folder with its page)."""
    (tmp_path / "rep").mkdir()
    (tmp_path / "exp").mkdir()
    for name in ("out.h5", "s2.toml", "p.h5", "imp.h5", "rep/report.html", "exp/structure.fmu"):
        (tmp_path / name).write_bytes(OLD)


FULL_DISK = {                      # command -> (argv in tmp_path, the file it would have replaced)
    "run": (lambda d, r: ["run", "s.toml", "-o", "out.h5"], "out.h5"),
    "scene": (lambda d, r: ["scene", "reactor", "-o", "s2.toml"], "s2.toml"),
    "pushover": (lambda d, r: ["pushover", "s.toml", "--soil", "winkler", "--steps", "4", "-o", "p.h5"], "p.h5"),
    "report": (lambda d, r: ["report", str(r), "-o", "rep"], "rep/report.html"),
    "impedance": (lambda d, r: ["impedance", "x.toml", "-o", "imp.h5"], "imp.h5"),
    "export": (lambda d, r: ["export", "x.toml", "--kind", "python", "-o", "exp"], "exp/structure.fmu"),
}


@pytest.mark.parametrize("command", sorted(FULL_DISK))
def test_full_disk_is_a_clean_error_of_every_writing_command(command, results, tmp_path, monkeypatch, capsys):
    """The disk fills as the command commits its output (fsync fails with ENOSPC): exit 3, one
    line naming the path, the old output as it was, no temporary or staging folder left."""
    monkeypatch.chdir(tmp_path)
    write_scene(tmp_path / "s.toml", WINKLER)
    write_scene(tmp_path / "x.toml", export_tower())          # a small BEM scene: impedance, export
    _old_outputs(tmp_path)
    argv, target = FULL_DISK[command]
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    monkeypatch.setattr(os, "fsync", _enospc)
    capsys.readouterr()
    assert main(argv(tmp_path, results)) == EXIT_WRITE
    err = capsys.readouterr().err.strip().splitlines()
    progress = ("wrote", "run ", "pushover ", "fit ", "impedance ", "  ")
    assert len(err) - sum(ln.startswith(progress) for ln in err) == 1, err
    assert err[-1].startswith("uplift: error: cannot write") and "no space left on device" in err[-1], err
    named = "exp'" if command == "export" else "rep'" if command == "report" else f"{target}'"   # the output, not a stage
    assert f"cannot write '{named}" in err[-1] or f"/{named}" in err[-1], err
    assert ".tmp" not in err[-1] and "Traceback" not in "\n".join(err)
    assert (tmp_path / target).read_bytes() == OLD
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before          # nothing partial


@pytest.mark.slow                        # a run on the session's scheduler (its start: seconds)
def test_full_disk_at_the_ensemble_write(tmp_path, monkeypatch, capsys, scheduler):
    """The ensemble file cannot be written: exit 3, the old file as it was, the finished cells
    kept in <output>.cells for a rerun (the cells on the session's scheduler)."""
    import orchestrator.ensemble.dataset as dataset
    monkeypatch.chdir(tmp_path)
    write_scene(tmp_path / "s.toml", WINKLER)
    (tmp_path / "e.h5").write_bytes(OLD)
    write_image = dataset.write_image

    def full(path, data):                  # the disk fills as the ensemble file is written
        with monkeypatch.context() as m:
            m.setattr(os, "fsync", _enospc)
            return write_image(path, data)
    monkeypatch.setattr(dataset, "write_image", full)
    argv = ["ensemble", "s.toml", "--seeds", "1", "--pga", "0.3", "--scheduler", scheduler, "-o", "e.h5"]
    assert main(argv) == EXIT_WRITE
    err = capsys.readouterr().err
    assert "uplift: error: cannot write 'e.h5': no space left on device" in err and "Traceback" not in err
    assert (tmp_path / "e.h5").read_bytes() == OLD and _temporaries(tmp_path) == []
    assert len(list((tmp_path / "e.h5.cells").iterdir())) == 1


def _file_size_limit(limit):
    def preexec():
        import resource
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)        # write() then fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    return preexec


@POSIX
@pytest.mark.slow                        # two commands in child processes: about 8 s
def test_a_real_file_size_limit_in_a_child_process(results, tmp_path):
    """The kernel refuses the data (RLIMIT_FSIZE: writes past 64 KiB fail with EFBIG, as a full
    disk fails with ENOSPC): `uplift run -o` and `uplift report -o` exit 3 with one line, the
    old files as they were, nothing partial left."""
    write_scene(tmp_path / "s.toml", WINKLER)
    _old_outputs(tmp_path)
    # the outputs' folder as it was (the cache, when it is here, may gain entries: the motion's)
    listing = lambda: sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if "cache" not in p.relative_to(tmp_path).parts[:1])
    before = listing()
    for argv, target in ((["run", "s.toml", "-o", "out.h5"], "out.h5"),
                         (["report", str(results), "-o", "rep"], "rep/report.html")):
        p = _cli("", argv, tmp_path, preexec=_file_size_limit(64 * 1024))
        err = p.stderr.strip().splitlines()
        assert p.returncode == EXIT_WRITE, p.stderr
        assert err[-1].startswith("uplift: error: cannot write") and "file too large" in err[-1], p.stderr
        assert "Traceback" not in p.stderr and (tmp_path / target).read_bytes() == OLD
    assert listing() == before


# ---- Ctrl-C at any instant ------------------------------------------------------------------------

SIGINT_SELF = "import os, signal\nsigint = lambda *a: os.kill(os.getpid(), signal.SIGINT)\n"
#: where the hook sends SIGINT -> (hook source, committed?)
INTERRUPTS = {
    "writing": ("import orchestrator.results_file as r\nstamp = r.stamp_checksum\n"
                "r.stamp_checksum = lambda f: (sigint(), stamp(f))[1]\n", False),
    "rename": ("replace = os.replace\n"
               "def at_rename(a, b):\n    if str(b).endswith('out.h5'):\n        sigint()\n    return replace(a, b)\n"
               "os.replace = at_rename\n", True),
    "after": ("import orchestrator.cli as cli\nsay = cli._say\n"
              "def after(*lines):\n    if any(ln.startswith('wrote') for ln in lines):\n        sigint()\n"
              "    say(*lines)\ncli._say = after\n", True),
    "in-del": ("import orchestrator.results_file as r\nstamp = r.stamp_checksum\n"
               "class Swallowed:\n    def __del__(self):\n        sigint()\n        sum(range(10000))\n"
               "def swallow(f):\n    Swallowed()\n    return stamp(f)\nr.stamp_checksum = swallow\n", True),
}


@POSIX
@pytest.mark.parametrize("point", sorted(INTERRUPTS))
def test_ctrl_c_at_the_final_write_of_run(point, tmp_path):
    write_scene(tmp_path / "s.toml", WINKLER)
    out = tmp_path / "out.h5"
    out.write_bytes(OLD)
    hook, committed = INTERRUPTS[point]
    p = _cli(SIGINT_SELF + hook, ["run", "s.toml", "-o", "out.h5"], tmp_path)
    err = p.stderr.strip().splitlines()
    assert p.returncode == EXIT_INTERRUPTED, p.stderr
    assert err[-1].startswith("uplift: interrupted") and sum("interrupted" in ln for ln in err) == 1, p.stderr
    assert "Traceback" not in p.stderr and "Exception ignored" not in p.stderr, p.stderr
    if committed:
        assert err[-1].startswith("uplift: interrupted after writing out.h5 (whole"), p.stderr
        with h5py.File(out, "r") as f:
            files.require_checksum(f, out)
    else:
        assert "nothing was written" in err[-1] and out.read_bytes() == OLD
    assert _temporaries(tmp_path) == []


@POSIX
def test_ctrl_c_while_exiting_does_not_kill_by_the_signal(tmp_path):
    """A SIGINT after the command's outcome is known (an exit handler sends it) is ignored: the
    command had finished; the process is not killed by the signal."""
    write_scene(tmp_path / "s.toml", WINKLER)
    p = _cli(SIGINT_SELF + "import atexit\natexit.register(sigint)\n", ["run", "s.toml", "-o", "out.h5"], tmp_path)
    assert p.returncode == EXIT_OK and "Traceback" not in p.stderr, p.stderr


@POSIX
@pytest.mark.slow                        # a child process, two runs on the session's scheduler
def test_ctrl_c_at_the_ensemble_write_keeps_the_old_file_and_the_cells(tmp_path, scheduler):
    """SIGINT as the ensemble file is stamped (its cells run on the session's scheduler, the
    local cluster of an ensemble closed by then in any case)."""
    write_scene(tmp_path / "s.toml", WINKLER)
    (tmp_path / "e.h5").write_bytes(OLD)
    hook = ("import orchestrator.ensemble.dataset as d\nstamp = d.stamp_file\n"
            "d.stamp_file = lambda path: (sigint(), stamp(path))[1]\n")
    p = _cli(SIGINT_SELF + hook, ["ensemble", "s.toml", "--seeds", "1", "2", "--pga", "0.3", "--scheduler",
                                  scheduler, "-o", "e.h5"], tmp_path)
    err = p.stderr.strip().splitlines()
    assert p.returncode == EXIT_INTERRUPTED, p.stderr
    assert err[-1].startswith("uplift: interrupted before the output was committed"), p.stderr
    assert "Traceback" not in p.stderr and "Exception ignored" not in p.stderr, p.stderr
    assert (tmp_path / "e.h5").read_bytes() == OLD and _temporaries(tmp_path) == []
    assert len(list((tmp_path / "e.h5.cells").iterdir())) == 2          # finished runs kept for a rerun


@POSIX
@pytest.mark.slow                        # a local dask cluster: about 10 s
def test_ctrl_c_while_the_cluster_starts_is_not_lost(tmp_path):
    """SIGINT as the local cluster's workers start (sent from inside LocalCluster's constructor):
    exit 130, one line, no traceback of a half-made cluster at exit, no worker left (it was
    ignored there, and the ensemble ran on to exit 0)."""
    write_scene(tmp_path / "s.toml", WINKLER)
    (tmp_path / "e.h5").write_bytes(OLD)
    hook = ("import distributed\ninit = distributed.LocalCluster.__init__\n"
            "def starting(self, *a, **k):\n    sigint()\n    init(self, *a, **k)\n"
            "distributed.LocalCluster.__init__ = starting\n")
    p = _cli(SIGINT_SELF + hook, ["ensemble", "s.toml", "--seeds", "1", "--pga", "0.3", "--workers", "1", "-o", "e.h5"],
             tmp_path)
    err = p.stderr.strip().splitlines()
    assert p.returncode == EXIT_INTERRUPTED, p.stderr
    assert err[-1].startswith("uplift: interrupted before the output was committed"), p.stderr
    assert "Traceback" not in p.stderr and (tmp_path / "e.h5").read_bytes() == OLD


# ---- absurd magnitudes ----------------------------------------------------------------------------

ABSURD = {                          # name -> (section changes of the tower, key named, quantity)
    "vs": ({"soil": {"halfspace": {"vs": 1e308, "nu": 0.3, "rho": 2000.0}}}, "soil.halfspace.vs", "vs"),
    "rho": ({"soil": {"halfspace": {"vs": 500.0, "nu": 0.3, "rho": 2.0e6}}}, "soil.halfspace.rho", "rho"),
    "vp": ({"soil": {"halfspace": {"vs": 500.0, "vp": 1e7, "rho": 2000.0}}}, "soil.halfspace.vp", "vp"),
    "thickness": ({"soil": {"layers": [{"thickness": 1e308, "vs": 300.0, "nu": 0.3, "rho": 1900.0}]}},
                  "soil.layers[0].thickness", "thickness"),
    "radius": ({"foundation": {"shape": "circle", "radius": 1e6, "lx": None, "ly": None}}, "foundation.radius",
               "radius"),
    "side": ({"foundation": {"lx": 1e9}}, "foundation.lx", "length"),
    "frequency": ({"impedance": {"frequencies_hz": [0.0, 1e12]}}, "impedance.frequencies_hz[1]", "frequency"),
    "E": ({"structure": {"beams": [dict(tower()["structure"]["beams"][0], E=1e30)]}}, "structure.beams[0].E",
          "modulus"),
    "A": ({"structure": {"beams": [dict(tower()["structure"]["beams"][0], A=1e300)]}}, "structure.beams[0].A",
          "area"),
    "mass": ({"structure": {"masses": [{"node": 2, "m": 1e20}]}}, "structure.masses[0].m", "mass"),
    "inertia": ({"structure": {"raft": {"node": 1, "m": 1e6, "inertia": [1e30, 0, 0]}}},
                "structure.raft.inertia[0]", "rotary_inertia"),
    "coordinate": ({"structure": {"nodes": [{"id": 1, "xyz": [0, 0, 0]}, {"id": 2, "xyz": [0, 0, 1e9],
                                                                          "name": "top"}]}},
                   "structure.nodes[1].xyz[2]", "coordinate"),
    "spring": ({"structure": {"springs": [{"node": 2, "k": [1e30, 0, 0, 0, 0, 0]}]}}, "structure.springs[0].k[0]",
               "stiffness"),
    "rayleigh": ({"structure": {"damping": {"rayleigh": [0.1, 1e6]}}}, "structure.damping.rayleigh[1]",
                 "rayleigh_a1"),
    "winkler": ({"soil": {"winkler": {"kv": 1e20, "kh": 1e7}}}, "soil.winkler.kv", "subgrade_modulus"),
    "penalty": ({"contact": {"penalty": 1e30}}, "contact.penalty", "penalty"),
}


@pytest.mark.parametrize("case", sorted(ABSURD))
def test_absurd_magnitude_is_refused_naming_key_value_and_range(case):
    change, key, quantity = ABSURD[case]
    with warnings.catch_warnings():
        warnings.simplefilter("error")                              # no numpy warning on the way
        with pytest.raises(SceneError) as err:
            scene_from_dict(tower(**change), name="t")      # the tower on its half-space and springs
    text = str(err.value)
    assert f"{key} = " in text and f"plausible range {plausible_range(quantity)}" in text, text


def test_too_many_layers_or_nodes_are_refused_before_parsing_them():
    layer = {"thickness": 1.0, "vs": 300.0, "nu": 0.3, "rho": 1900.0}
    t = time.perf_counter()
    with pytest.raises(SceneError, match=f"soil.layers has {MAX_LAYERS + 1} layers; at most {MAX_LAYERS}"):
        scene_from_dict(tower(soil={"layers": [layer] * (MAX_LAYERS + 1)}), name="t")
    nodes = [{"id": 1}] * (MAX_STRUCTURE_NODES + 1)                     # refused before any node is read
    with pytest.raises(SceneError, match=f"structure.nodes has {MAX_STRUCTURE_NODES + 1} nodes"):
        scene_from_dict(changed(WINKLER, structure={"nodes": nodes}), name="t")
    assert time.perf_counter() - t < 1.0
    ok = tower(soil={"layers": [layer] * MAX_LAYERS})
    assert len(scene_from_dict(ok, name="t").profile.layers) == MAX_LAYERS     # the limit itself passes


@pytest.mark.parametrize("sample, units, message", [
    ("1e308", "g", "sample 8 of 50 = 1e+308 g lies outside the plausible range |value| <= 50 g"),
    ("-600", "m/s2", "sample 8 of 50 = -600 m/s2 lies outside the plausible range |value| <= 500 m/s2")])
def test_absurd_record_sample_is_one_line_and_no_warning(sample, units, message, tmp_path, capsys):
    rows = [f"{0.01 * i:.2f} {sample if i == 7 else '0.01'}" for i in range(50)]
    (tmp_path / "rec.txt").write_text("\n".join(rows) + "\n")
    scene = changed(WINKLER, motion={"kind": "record", "file": "rec.txt", "units": units, "pga_g": None,
                                     "duration_s": None, "seed": None}, analysis={"dt": 0.005})
    path = write_scene(tmp_path / "s.toml", scene)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["run", path, "-o", str(tmp_path / "o.h5")]) == EXIT_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "motion.file" in err[0] and message in err[0], err


def test_vs_of_1e308_through_the_command_line_is_one_line(tmp_path, capsys):
    path = write_scene(tmp_path / "s.toml", changed(WINKLER, soil={"halfspace": {"vs": 1e308, "nu": 0.3,
                                                                                  "rho": 2000.0}}))
    assert main(["run", path, "-o", str(tmp_path / "o.h5")]) == EXIT_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"uplift: error: scene file {path!r}: soil.halfspace.vs = 1e+308 m/s lies outside the plausible "
                   "range [1, 10000] m/s of a shear-wave speed: check the value and its unit (docs/conventions.md, "
                   "Plausible ranges)"]


def test_the_ranges_are_listed_in_the_docs():
    text = (ROOT / "docs" / "conventions.md").read_text()
    for quantity, r in PLAUSIBLE.items():
        assert f"| {r.what} | {plausible_range(quantity)} |" in text, quantity
    assert f"at most {MAX_LAYERS} layers" in text and f"at most {MAX_STRUCTURE_NODES:,} structure nodes" in text


def test_built_in_and_test_scenes_lie_in_the_ranges():
    from orchestrator.scene import builtin_scenes, load_scene
    for name in builtin_scenes():
        load_scene(name)
    scene_from_dict(tower(), name="tower")


@POSIX
def test_a_held_section_takes_sigint_after_its_end():
    """In process: a SIGINT inside ``held()`` is raised right after it, not inside; with
    ``defer`` it waits for ``raise_owed()``; either way ``received`` counts it."""
    from uplift_common import interrupts
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)   # ignored in a background job's worker
    previous = interrupts.install()
    try:
        done = []
        with pytest.raises(KeyboardInterrupt), interrupts.held():
            os.kill(os.getpid(), signal.SIGINT)
            sum(range(100000))                      # the handler runs here, and only counts
            done.append("section finished")
        assert done == ["section finished"] and interrupts.received() == 1
        with interrupts.held(defer=True):
            os.kill(os.getpid(), signal.SIGINT)
            sum(range(100000))
        done.append("after the deferred section")
        with pytest.raises(KeyboardInterrupt):
            interrupts.raise_owed()
        assert done[-1] == "after the deferred section" and interrupts.received() == 2
        interrupts.raise_owed()                         # nothing owed any more
    finally:
        interrupts.restore(previous)
        signal.signal(signal.SIGINT, inherited)


def test_started_as_reads_the_interpreters_command_line(monkeypatch):
    from uplift_common.interrupts import started_as
    for argv, expected in ((["python", "-m", "orchestrator.cli", "run"], True), (["python", "-m", "pytest"], False),
                           (["python", "/venv/bin/uplift", "run"], True), (["python", "-c", "pass"], False),
                           (["python", "-X", "dev", "/usr/bin/uplift"], True), (["python", "script.py"], False)):
        monkeypatch.setattr(sys, "orig_argv", argv)
        assert started_as("orchestrator.cli", "uplift") == expected, argv
