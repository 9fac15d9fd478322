"""What a run pays besides its stepping: the fit found without reading the impedance table, keyed
honestly by the table's inputs."""
import h5py
import numpy as np
import pytest

import orchestrator.impedance as impedance
import soil_impedance.sweep as sweep
from orchestrator.impedance import cached_scene_fit, scene_impedance
from orchestrator.run import run_scene
from orchestrator.scene import scene_from_dict
from soil_impedance.sweep import table_key
from helpers import small_reactor

#: the reactor's sticks on a coarse raft (17 nodes), 1.5 s at 5 ms: a fit in about a second
SCENE = small_reactor(analysis={"routes": ["monolithic", "linear"]}, motion={"duration_s": 0.5})


def _key(scene):
    return table_key(scene.profile, scene.mesh, scene.frequencies_hz, scene.contact_kind, "gap")


def test_the_fit_is_found_by_the_tables_inputs_without_reading_it(tmp_path, monkeypatch):
    """A second run of a fit-only route reads neither the table nor the BEM (the sweep is refused
    here) and gives the same answer to the bit; a route that reads the table still gets it, swept
    once for the run."""
    scene = scene_from_dict(SCENE, name="small")
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
    monkeypatch.setattr(impedance, "impedance_sweep", counted)
    both, _ = run_scene(scene, cache_dir=tmp_path)
    assert calls == [("gap",)]                       # the linear route's read, once
    assert np.array_equal(both["linear"].gap, first["linear"].gap)
    assert np.array_equal(both["monolithic"].gap, first["monolithic"].gap)


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


def test_a_damaged_fit_entry_is_refitted_from_the_table(tmp_path):
    """The fit found by the table's inputs is still verified on read: a changed value discards it
    (CacheWarning) and the run fits again from the table."""
    from soil_impedance.cache import CacheWarning
    scene = scene_from_dict(SCENE, name="small")
    first, _ = run_scene(scene, routes=["monolithic"], cache_dir=tmp_path)
    (entry,) = tmp_path.glob("fit-*.h5")
    with h5py.File(entry, "r+") as f:                  # one value changed, the checksum left as it was
        f["D"][0, 0] += 1.0
    with pytest.warns(CacheWarning, match="damaged cache entry"):
        again, _ = run_scene(scene, routes=["monolithic"], cache_dir=tmp_path)
    assert np.array_equal(again["monolithic"].gap, first["monolithic"].gap)
