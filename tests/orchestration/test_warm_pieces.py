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
