"""Work done beside a route's stepping: the step-doubling check of a run starts in a thread at the
route's first progress report and gives the notes it gives in order."""
import threading

import pytest

import orchestrator.run as run_module
from orchestrator.run import _Beside, run_scene
from orchestrator.scene import scene_from_dict
from helpers.native import seed_native


def test_beside_starts_at_the_first_report_once_and_gives_its_value_or_its_error():
    ran, seen = [], []
    started = threading.Event()

    def call():
        ran.append(threading.current_thread())
        started.set()
        return {"n": len(ran)}

    beside = _Beside(call)
    tick = beside.starting(lambda *a: seen.append(a))
    assert not ran                                   # nothing before the first report
    tick(1, 10)
    tick(2, 10)
    assert started.wait(10) and seen == [(1, 10), (2, 10)]
    assert beside.value() == {"n": 1} and beside.value() == {"n": 1}
    assert ran[0] is not threading.main_thread() and len(ran) == 1

    quiet = _Beside(call)                            # a route that reports no progress: computed in place
    quiet.starting(None)
    assert quiet.value() == {"n": 2} and ran[1] is threading.main_thread()

    same = _Beside(call, threaded=False)
    bar = object()
    assert same.starting(bar) is bar and same.value() == {"n": 3} and ran[2] is threading.main_thread()

    def fails():
        raise ValueError("the check's own error")

    failing = _Beside(fails)
    failing.starting(None)(1, 2)
    with pytest.raises(ValueError, match="the check's own error"):
        failing.value()


def _stiff_tower(dt):
    """test_fixed_costs's stiff tower (10 ms does not resolve its contact: the check warns), the
    winkler route only."""
    from helpers import changed, tower
    beam = dict(tower()["structure"]["beams"][0], E=3e12, G=1.25e12)
    data = changed(tower(), soil={"winkler": {"kv": 5.0e9, "kh": 4.0e9}}, structure={"beams": [beam]},
                   motion={"pga_g": 0.6}, analysis={"dt": dt, "routes": ["winkler"]})
    return scene_from_dict(data, name="stiff")


def test_the_step_check_beside_the_route_gives_the_notes_of_the_check_in_order(tmp_path, monkeypatch):
    """The check runs in another thread, whether the caller follows the progress or not (the
    route's reports start it); it gives the check, the warning and the histories of the check
    computed in order (``step_doubling`` called in the caller's thread, then the route)."""
    seed_native(tmp_path)
    threads = []
    real = run_module.step_doubling

    def spied(*args, **kwargs):
        threads.append(threading.current_thread())
        return real(*args, **kwargs)

    monkeypatch.setattr(run_module, "step_doubling", spied)
    scene = _stiff_tower(0.01)
    reports = []
    beside, _ = run_scene(scene, cache_dir=tmp_path, progress=lambda done, total, label="": reports.append(done))
    quiet, _ = run_scene(scene, cache_dir=tmp_path)
    assert reports and threads[0] is not threading.main_thread() and threads[1] is not threading.main_thread()
    monkeypatch.setattr(run_module, "_Beside", lambda call, threaded=True: _Beside(call, threaded=False))
    in_order, _ = run_scene(scene, cache_dir=tmp_path)
    assert threads[2] is threading.main_thread()
    a, b = beside["winkler"], in_order["winkler"]
    assert quiet["winkler"].info["dt_check"] == b.info["dt_check"]
    assert quiet["winkler"].notes.warnings == b.notes.warnings
    assert a.info["dt_check"] == b.info["dt_check"] and a.info["dt_check"]["relative_change"] > 0.05
    assert a.notes.warnings == b.notes.warnings and any("does not resolve" in w for w in a.notes.warnings)
    assert (a.gap == b.gap).all() and a.max_uplift() == b.max_uplift()
