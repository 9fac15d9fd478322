"""Pieces of a warm run made cheaper keep their answers: a cache key's byte stream (``feed``) is the
documented one, written out here by hand (the keys of entries already in a cache still match);
the code digests read each file once and give the digest of the files as they are on disk; a run
checks its memory once."""
import dataclasses
import hashlib

import numpy as np

import orchestrator.run as run_module
from helpers.native import seed_native
from helpers.scenes import tower
from orchestrator.run import run_scene
from orchestrator.scene import scene_from_dict
from soil_impedance.cache import feed
from uplift_common.code import _package_root, code_digest, source_files


@dataclasses.dataclass(frozen=True)
class Point:
    x: float
    n: int
    label: str
    tags: tuple
    extra: object = None


def test_a_keys_byte_stream_is_the_documented_one():
    value = Point(1.5, 2, "a", (True, 3j, np.float64(0.25), np.arange(2, dtype=np.int32)), {"k": [None]})
    h = hashlib.sha256()
    feed(h, value)
    a = np.arange(2, dtype=np.int32)
    expected = (f"<{__name__}.Point x=(float 1.5) n=(int 2) label=(str 'a') tags=[4,(bool True),(complex 3j),"
                f"(float64 {np.float64(0.25)!r}),(array <i4 (2,))").encode() + a.tobytes() + b"] extra={1(str 'k'):[1,(NoneType None)]}>"
    assert h.hexdigest() == hashlib.sha256(expected).hexdigest()


def test_code_digests_are_those_of_the_files_on_disk():
    names = ("structure", "orchestrator.run", "structure.model")       # overlapping: each file once
    h = hashlib.sha256()
    base = _package_root("structure").parent
    seen = []
    for name in names:
        for path in source_files(name):
            if path not in seen:
                seen.append(path)
                h.update(path.relative_to(base).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    assert code_digest(*names) == h.hexdigest()
    assert code_digest("structure") != code_digest(*names)


SCENE = tower(motion={"duration_s": 1.0})   # the small tower, a 1 s record


def test_a_run_checks_its_memory_once_and_a_prepared_run_on_its_own(tmp_path, monkeypatch):
    checks = []
    real = run_module.check_run_memory
    monkeypatch.setattr(run_module, "check_run_memory", lambda *a, **k: checks.append(1) or real(*a, **k))
    scene = scene_from_dict(SCENE, name="small")
    cache = seed_native(tmp_path / "cache")
    results, _ = run_scene(scene, cache_dir=cache)
    assert results["winkler"].converged and len(checks) == 1
    run_module.prepare_run(scene, cache_dir=cache)
    assert len(checks) == 2


def test_the_program_freezes_its_objects_for_the_exit_and_still_runs_the_exit(tmp_path):
    """``uplift`` run as the program moves its objects to the collector's permanent generation as
    its last step (``orchestrator.cli._freeze_for_exit``: the interpreter's exit then skips its
    collections over them); the exit itself is unchanged: atexit handlers run after it, the
    output is whole and the exit codes are the command's (0; 2 with its one-line error). A
    command called in process (``main(argv)``, a test's) freezes nothing."""
    import gc
    import os
    import subprocess
    import sys

    from helpers import ROOT
    from orchestrator.cli import main

    def program(*args):
        code = ("import atexit, gc, runpy, sys\n"
                "atexit.register(lambda: print('frozen', gc.get_freeze_count() > 0, flush=True))\n"
                f"sys.argv = ['uplift', *{list(args)!r}]\n"
                "runpy.run_module('orchestrator.cli', run_name='__main__')\n")
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                              env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=tmp_path)
    done = program("scene", "reactor")
    assert done.returncode == 0 and "[structure]" in done.stdout, done.stderr[-2000:]
    assert done.stdout.rstrip().endswith("frozen True")
    bad = program("run", "no-such-scene")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "no-such-scene" in bad.stderr, bad.stderr
    assert bad.stdout.strip() == "frozen True"
    before = gc.get_freeze_count()
    assert main(["scene", "reactor", "-o", str(tmp_path / "reactor.toml")]) == 0
    assert gc.get_freeze_count() == before


def test_the_fit_key_s_settings_are_the_options_with_the_node_coordinates_hashed():
    """``FitOptions.settings`` (the fit cache key's and the report's) takes the fields as they are:
    the dict ``dataclasses.asdict`` gives, node_xy replaced by the first 16 hex digits of the
    SHA-256 of its little-endian doubles, for options with and without nodes."""
    import json

    from soil_impedance.fit import FitOptions
    xy = np.random.default_rng(1).standard_normal((241, 2))
    for options in (FitOptions.make(node_xy=xy, tol=0.04), FitOptions(), FitOptions(patience=None, f_causal_hz=2.5,
                                                                                      rigid_correction=True)):
        expected = dataclasses.asdict(options)
        nodes = expected.pop("node_xy")
        expected["node_xy_sha"] = None if nodes is None else hashlib.sha256(
            np.ascontiguousarray(nodes, "<f8").tobytes()).hexdigest()[:16]
        assert json.dumps(options.settings(), sort_keys=True) == json.dumps(expected, sort_keys=True)


def test_notes_added_to_a_result_share_its_histories_and_give_the_replaced_result():
    """``RouteResult.with_notes`` (five per warm run) and ``with_checked`` share the result's
    read-only histories instead of copying them all again (``replace`` runs ``__post_init__``):
    the result equals the one ``dataclasses.replace`` makes, field by field, and its arrays are the
    same objects, still read-only."""
    from types import MappingProxyType

    from helpers.results import route_result
    res = route_result("monolithic")
    noted = res.with_notes(skipped=["a"], warnings=["w"], precheck="p", timings={"x": 1}, info={"k": [1, 2]})
    n = res.notes
    replaced = dataclasses.replace(res, info={**res.info, "k": [1, 2]}, notes=type(n)(
        skipped=n.skipped + ("a",), warnings=n.warnings + ("w",), precheck="p", timings={**n.timings, "x": 1}))
    for f in dataclasses.fields(res):
        a, b = getattr(noted, f.name), getattr(replaced, f.name)
        if isinstance(a, np.ndarray):
            assert a is getattr(res, f.name) and not a.flags.writeable and a.tobytes() == b.tobytes(), f.name
        elif isinstance(a, MappingProxyType):
            assert dict(a).keys() == dict(b).keys(), f.name
            for k in a:
                assert np.array_equal(a[k], b[k]), (f.name, k)
        else:
            assert a == b, f.name
    timed = noted.with_checked(wall_s=2.5)
    assert timed.wall_s == 2.5 and noted.wall_s == res.wall_s and timed.gap is res.gap
