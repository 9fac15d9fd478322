"""What a run pays besides its stepping: the fit found without reading the impedance table, keyed
honestly by the table's inputs."""
import h5py
import numpy as np
import pytest

import orchestrator.impedance as impedance
import soil_impedance.sweep as sweep
from orchestrator.impedance import cached_scene_fit, scene_impedance
from orchestrator.motion import make_motion
from orchestrator.run import prepare_run, proxy_springs, run_scene, step_doubling, step_doubling_warning
from orchestrator.scene import scene_from_dict
from soil_impedance.cache import CacheWarning
from soil_impedance.sweep import table_key
from helpers import small_reactor
from helpers.native import seed_native

#: the reactor's sticks on a coarse raft (17 nodes), 1.5 s at 5 ms: a fit in about a second
SCENE = small_reactor(analysis={"routes": ["monolithic", "linear"]}, motion={"duration_s": 0.5})


def _key(scene):
    return table_key(scene.profile, scene.mesh, scene.frequencies_hz, scene.contact_kind, "gap")


@pytest.mark.slow
def test_the_fit_is_found_by_the_tables_inputs_without_reading_it(tmp_path, monkeypatch):
    """A second run of a fit-only route reads neither the table nor the BEM (the sweep is refused
    here) and gives the same answer to the bit; a route that reads the table still gets it, swept
    once for the run. The fit entry is still verified: a damaged one is fitted again."""
    scene = scene_from_dict(SCENE, name="small")
    seed_native(tmp_path)                               # the C runtime compiled once for the tests
    first, _ = run_scene(scene, cache_dir=tmp_path)
    calls = []
    real = impedance.impedance_sweep

    def counted(*args, **kwargs):
        calls.append(kwargs.get("outputs"))
        return real(*args, **kwargs)

    def refused(*args, **kwargs):
        raise AssertionError("the impedance table was read")

    monkeypatch.setattr(impedance, "impedance_sweep", refused)
    again, _ = run_scene(scene, routes=["monolithic"], cache_dir=tmp_path)
    assert np.array_equal(again["monolithic"].gap, first["monolithic"].gap)
    assert any("impedance table not read" in s for s in again["monolithic"].notes.skipped)
    assert any("rational fit read from cache" in s for s in again["monolithic"].notes.skipped)
    shared = prepare_run(scene, routes=["monolithic"], cache_dir=tmp_path)     # an ensemble's set-up: the same
    assert shared.tables == {} and shared.fit.report.cached
    cell, _ = run_scene(scene, routes=["monolithic"], cache_dir=tmp_path, shared=shared)
    assert np.array_equal(cell["monolithic"].gap, first["monolithic"].gap)
    monkeypatch.setattr(impedance, "impedance_sweep", counted)
    both, _ = run_scene(scene, cache_dir=tmp_path)
    assert calls == [("gap",)]                       # the linear route's read, once
    assert np.array_equal(both["linear"].gap, first["linear"].gap)
    assert np.array_equal(both["monolithic"].gap, first["monolithic"].gap)
    (entry,) = tmp_path.glob("fit-*.h5")                # still verified on read: a changed value
    with h5py.File(entry, "r+") as f:                  # (the checksum left as it was) is refitted
        f["D"][0, 0] += 1.0
    with pytest.warns(CacheWarning, match="damaged cache entry"):
        refit, _ = run_scene(scene, routes=["monolithic"], cache_dir=tmp_path)
    assert np.array_equal(refit["monolithic"].gap, first["monolithic"].gap)


def test_the_table_key_is_the_tables_hash_and_moves_with_every_input(tmp_path, monkeypatch):
    """table_key is the swept table's hash (the fit's key), and a change of the soil, the mesh,
    the frequencies, the interface contact or the BEM code changes it: the fit cached for the old
    inputs is not found (a miss, never a stale fit)."""
    scene = scene_from_dict(SCENE, name="small")
    table = scene_impedance(scene, ("gap",), cache_dir=tmp_path)["gap"]
    assert _key(scene) == table.hash
    assert cached_scene_fit(scene, tmp_path) is None     # nothing fitted yet
    impedance.scene_fit(scene, cache_dir=tmp_path, table=table)
    assert cached_scene_fit(scene, tmp_path) is not None
    rock = SCENE["soil"]["halfspace"]
    changes = [dict(soil={"halfspace": dict(rock, vs=1700.0)}), dict(soil={"halfspace": dict(rock, damping=0.02)}),
               dict(foundation={"element_size": 7.0}), dict(impedance={"range_hz": [0.0, 25.0, 27]}),
               dict(foundation={"contact": "relaxed"})]
    keys = {_key(scene)}
    for change in changes:
        other = scene_from_dict(small_reactor(**change), name="small")
        keys.add(_key(other))
        assert cached_scene_fit(other, tmp_path) is None, change
    assert len(keys) == 1 + len(changes)
    monkeypatch.setattr(sweep, "code_version", lambda: "changed BEM code")
    assert _key(scene) != table.hash and cached_scene_fit(scene, tmp_path) is None
    monkeypatch.undo()
    assert cached_scene_fit(scene, tmp_path, impedance._fit_options(scene, {"tol": 0.5})) is None


def _stiff_tower(dt, **sections):
    """The stiff tower of test_run's step-doubling test (10 ms does not resolve its contact, 5 ms
    does), the winkler route."""
    from helpers import changed, tower
    beam = dict(tower()["structure"]["beams"][0], E=3e12, G=1.25e12)
    data = changed(tower(), soil={"winkler": {"kv": 5.0e9, "kh": 4.0e9}}, structure={"beams": [beam]},
                   motion={"pga_g": 0.6}, analysis={"dt": dt})
    return scene_from_dict(changed(data, **sections), name="stiff")


@pytest.mark.slow
def test_the_step_doubling_check_is_stepped_once_then_read(tmp_path, monkeypatch):
    """The check warns where dt is too large and not where it is not; a second run reads its two
    answers from the cache (the native stepper is not called) and carries the same check; any
    change of what the stepper reads (motion, contact penalty, step) is a miss; a damaged entry is
    stepped again with a CacheWarning."""
    import fmus.native_stepper as native_stepper
    calls = []
    real = native_stepper.native_max_uplift

    def counted(*args, **kwargs):
        calls.append("dt-check")
        return real(*args, **kwargs)

    monkeypatch.setattr(native_stepper, "native_max_uplift", counted)
    cells = tmp_path / "cells"
    seed_native(tmp_path), seed_native(cells)          # the C runtime compiled once for the tests

    def check(scene):
        motion = make_motion(scene.motion, scene.analysis.dt)
        out = step_doubling(scene, scene.model(), proxy_springs(scene, False), motion, tmp_path)
        return out, step_doubling_warning(out) is not None

    for dt, warned in ((0.01, True), (0.005, False)):
        calls.clear()
        first, warns = check(_stiff_tower(dt))
        assert warns == warned and (first["relative_change"] > first["tolerance"]) == warned
        assert calls == ["dt-check"] * 2
        again, warns_again = check(_stiff_tower(dt))
        assert again == first and warns_again == warned and len(calls) == 2
        for change in (dict(motion={"pga_g": 0.55}), dict(contact={"enabled": True, "penalty": 2.0}),
                       dict(analysis={"dt": dt * 0.8})):
            calls.clear()
            check(_stiff_tower(dt, **change))
            assert len(calls) == 2, change
        for entry in tmp_path.glob("dtcheck-*.h5"):
            with h5py.File(entry, "r+") as f:
                f.attrs["max_uplift_m"] = 1.0                  # changed, the checksum left as it was
        calls.clear()
        with pytest.warns(CacheWarning, match="damaged cache entry"):
            damaged, _ = check(_stiff_tower(dt))
        assert damaged == first and len(calls) == 2
    scene = _stiff_tower(0.005)              # keep=False (an ensemble cell's motion): stepped, not kept
    calls.clear()
    out = step_doubling(scene, scene.model(), proxy_springs(scene, False), make_motion(scene.motion, 0.005),
                        cells, keep=False)
    assert out == first and len(calls) == 2 and not list(cells.glob("dtcheck-*"))


@pytest.mark.parametrize("nt", [2, 256, 257, 700])
def test_response_spectra_are_the_step_by_step_recurrence_to_the_bit(nt):
    """The spectra (the synthetic motion's matching runs them on every run) keep the numbers of
    the plain recurrence, one step at a time, whatever the chunking of the steps."""
    from orchestrator.spectra import _coefficients, response_spectra
    acc = np.random.default_rng(nt).standard_normal((nt, 2))
    periods, dt, zeta = 1.0 / np.geomspace(0.2, 33.0, 60), 0.005, 0.05
    omega = 2 * np.pi / periods
    a11, a12, a21, a22, b0u, b1u, b0v, b1v = _coefficients(omega, zeta, dt)
    u, v, umax, amax = (np.zeros((2, omega.size)) for _ in range(4))
    p = -acc[:, :, None]
    for n in range(nt - 1):
        u, v = (a11 * u + a12 * v + b0u * p[n] + b1u * p[n + 1], a21 * u + a22 * v + b0v * p[n] + b1v * p[n + 1])
        umax, amax = np.maximum(umax, np.abs(u)), np.maximum(amax, np.abs(2 * zeta * omega * v + omega ** 2 * u))
    for j, spec in enumerate(response_spectra(acc, dt, periods, zeta)):
        assert np.array_equal(spec.sd, umax[j]) and np.array_equal(spec.sa, amax[j])


def test_a_cached_table_is_read_and_hashed_once(tmp_path, monkeypatch):
    """The verification of a cached table reads each dataset once and hands it to the reader
    (the same digest as the slab-by-slab one), the matrices a few rows at a time straight into
    the table's complex array (each row once); a changed value is still refused."""
    from uplift_common.files import checksum
    from soil_impedance.sweep import _cache_path, _read_cached
    scene = scene_from_dict(SCENE, name="small")
    table = scene_impedance(scene, ("gap",), cache_dir=tmp_path)["gap"]
    path = _cache_path(tmp_path, "gap", table.hash)
    with h5py.File(path) as f:
        kept = {}
        assert checksum(f, kept) == checksum(f) == f.attrs["sha256"]
        assert np.array_equal(kept["/matrices_real"], table.matrices.real)
    reads, rows = [], []
    real, direct = h5py.Dataset.__getitem__, h5py.Dataset.read_direct
    monkeypatch.setattr(h5py.Dataset, "__getitem__", lambda ds, key: reads.append(ds.name) or real(ds, key))

    def read_direct(ds, dest, source_sel=None, dest_sel=None):
        first = source_sel if isinstance(source_sel, slice) else source_sel[0]
        rows.extend((ds.name, r) for r in range(*first.indices(ds.shape[0])))
        return direct(ds, dest, source_sel, dest_sel)
    monkeypatch.setattr(h5py.Dataset, "read_direct", read_direct)
    again = _read_cached(path, table.hash)
    assert np.array_equal(again.matrices, table.matrices) and again.dofs == table.dofs
    assert sorted(reads) == sorted(set(reads)) and "/dofs" in reads              # each dataset read once
    F = table.frequencies_hz.size
    assert sorted(rows) == sorted((f"/matrices_{p}", r) for p in ("imag", "real") for r in range(F))
    assert not {name for name, _ in rows} & set(reads)
    monkeypatch.undo()
    with h5py.File(path, "r+") as f:
        f["matrices_imag"][0, 0, 0] += 1.0
    with pytest.warns(CacheWarning, match="damaged cache entry"):
        assert _read_cached(path, table.hash) is None


@pytest.mark.slow
def test_the_fit_is_made_once_on_first_need_and_a_failed_fit_refuses_only_its_routes(tmp_path, monkeypatch, scheduler):
    """One run sequence for a single run and an ensemble's cells: prepare_run sweeps but does not
    fit (a route's first need does, once); a fit that fails is tried once and every route that
    needs it is refused (or stopped) with the reason while the others run, in a single run as in
    an ensemble's cells (the error travels in the pickled SharedRun: no cell fits again, none
    crashes); a fit that succeeds is made once by ``settle`` and read by every copy."""
    import pickle

    import orchestrator.run as run
    from orchestrator.ensemble import run_cell, run_ensemble
    from soil_impedance.rational import FitError
    from uplift_common.errors import ComputationError
    scene = scene_from_dict(small_reactor(analysis={"routes": ["winkler", "monolithic", "cosim"]},
                                          motion={"duration_s": 0.5}), name="small")
    real, calls = run.scene_fit, []

    def failing(*args, **kwargs):
        calls.append("fit")
        raise FitError("no passive model for the test")

    monkeypatch.setattr(run, "scene_fit", failing)
    seed_native(tmp_path)                                                    # the C runtime compiled once
    shared = prepare_run(scene, cache_dir=tmp_path)                          # lazy: swept, not fitted
    assert calls == [] and shared.fit is None and set(shared.tables) == {"rigid", "gap"}
    results, _ = run_scene(scene, cache_dir=tmp_path)
    assert calls == ["fit"]                                                  # once for monolithic and cosim
    assert results["winkler"].converged
    for name in ("monolithic", "cosim"):
        assert results[name].status.value == "refused" and results[name].message == "no passive model for the test"
    settled = prepare_run(scene, cache_dir=tmp_path, fit_progress=lambda *a: None).settle()
    assert calls == ["fit"] * 2 and isinstance(settled.fit_error, FitError)
    cell = pickle.loads(pickle.dumps(settled))                               # as scattered to a worker
    assert cell.fit_progress is None
    values = {r: run_cell(scene, r, cell, (), tmp_path) for r in ("winkler", "monolithic")}
    assert calls == ["fit"] * 2
    assert values["winkler"]["status"] == "converged" and np.isfinite(values["winkler"]["max_uplift"])
    assert values["monolithic"]["status"] == "refused" and values["monolithic"]["message"] == "no passive model for the test"
    ds = run_ensemble(scene, [0.3], seeds=[1], routes=["winkler", "monolithic"], scheduler=scheduler,
                      cache_dir=tmp_path)                                   # the session's scheduler
    assert calls == ["fit"] * 3                                              # made once, on the calling process
    assert list(ds["status"].values.ravel()) == ["converged", "refused"]
    assert "no passive model" in str(ds["message"].sel(route="monolithic").values.ravel()[0])

    def stopping(*args, **kwargs):
        calls.append("fit")
        raise ComputationError("the fit stopped")

    monkeypatch.setattr(run, "scene_fit", stopping)
    results, _ = run_scene(scene, routes=["monolithic", "winkler"], cache_dir=tmp_path)
    assert results["monolithic"].status.value == "stopped" and "the fit stopped" in results["monolithic"].message
    assert results["winkler"].converged and calls == ["fit"] * 4

    def counted(*args, **kwargs):
        calls.append("fit")
        return real(*args, **kwargs)

    monkeypatch.setattr(run, "scene_fit", counted)
    calls.clear()
    settled = prepare_run(scene, routes=["monolithic"], cache_dir=tmp_path).settle()
    assert calls == ["fit"] and settled.fit is not None and settled.fit_error is None
    copy = pickle.loads(pickle.dumps(settled))
    first = run_cell(scene, "monolithic", copy, (), tmp_path)
    again = run_cell(scene, "monolithic", copy, (), tmp_path)
    assert calls == ["fit"] and first["status"] == again["status"] == "converged"
    assert first["max_uplift"] == again["max_uplift"]


def test_a_synthetic_motion_is_matched_once_then_read_to_the_bit(tmp_path, monkeypatch):
    """scene_motion keeps a synthetic motion under the key of its inputs: a second call reads the
    bits make_motion gives (it is not called again), a change of a [motion] key or of the step is
    a miss, a damaged entry is made again with a CacheWarning, and nothing is kept without a
    cache folder."""
    import dataclasses

    import orchestrator.run as run
    scene = scene_from_dict(SCENE, name="small")
    real, calls = run.make_motion, []

    def counted(config, dt):
        calls.append(dt)
        return real(config, dt)

    monkeypatch.setattr(run, "make_motion", counted)
    first = run.scene_motion(scene.motion, 0.005, tmp_path)
    again = run.scene_motion(scene.motion, 0.005, tmp_path)
    direct = real(scene.motion, 0.005)
    assert calls == [0.005]
    assert again.acc.tobytes() == first.acc.tobytes() == direct.acc.tobytes()
    assert (again.dt, again.label, again.components) == (direct.dt, direct.label, direct.components)
    for change in (dict(pga_g=0.35), dict(seed=4), dict(duration_s=0.6)):
        calls.clear()
        other = dataclasses.replace(scene.motion, **change)
        moved = run.scene_motion(other, 0.005, tmp_path)
        assert calls == [0.005] and moved.acc.tobytes() == real(other, 0.005).acc.tobytes(), change
    calls.clear()
    assert run.scene_motion(scene.motion, 0.004, tmp_path).acc.shape != first.acc.shape and calls == [0.004]
    entry = tmp_path / f"motion-{run._motion_key(scene.motion, 0.005)[:24]}.h5"
    with h5py.File(entry, "r+") as f:                  # a changed value, the checksum left as it was
        f["acc"][0, 0] += 1.0
    calls.clear()
    with pytest.warns(CacheWarning, match="damaged cache entry"):
        damaged = run.scene_motion(scene.motion, 0.005, tmp_path)
    assert damaged.acc.tobytes() == direct.acc.tobytes() and calls == [0.005]
    kept = sorted(tmp_path.glob("motion-*.h5"))
    calls.clear()
    assert run.scene_motion(scene.motion, 0.005, None).acc.tobytes() == direct.acc.tobytes() and calls == [0.005]
    assert sorted(tmp_path.glob("motion-*.h5")) == kept
