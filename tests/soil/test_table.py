"""ImpedanceTable: HDF5 round trip, interpolation, errors; sweep cache."""
import h5py
import numpy as np
import pytest

import soil_impedance.sweep as sweep_mod
from soil_impedance import (ImpedanceTable, SoilProfile, TableError, circle_mesh, impedance_sweep,
                            static_impedance)


def _table(f, fun, n=3):
    rng = np.random.default_rng(0)
    M = rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))
    M = M + M.T
    return ImpedanceTable(f, np.array([fun(x) * M for x in f]), [f"d{i}" for i in range(n)],
                          {"what": "test", "n": n}), M


def test_hdf5_round_trip_is_exact(tmp_path):
    t, _ = _table(np.linspace(0, 10, 7), lambda f: 1 + 1j * f ** 1.5)
    # signed zeros must survive the round trip bit for bit
    M = t.matrices.copy()
    M[:, 0, 1] = complex(-0.0, 0.0)
    M[:, 1, 0] = complex(0.0, -0.0)
    t = ImpedanceTable(t.frequencies_hz, M, t.dofs, t.provenance)
    t.save(tmp_path / "k.h5")
    u = ImpedanceTable.load(tmp_path / "k.h5")
    assert np.array_equal(u.frequencies_hz, t.frequencies_hz)
    assert u.matrices.tobytes() == t.matrices.tobytes()
    assert u.dofs == t.dofs and u.provenance == t.provenance and u.hash == t.hash
    with h5py.File(tmp_path / "k.h5") as h:   # readable without this code
        assert h["matrices_real"].shape == (7, 3, 3) and h.attrs["format"] == "uplift.ImpedanceTable"


def test_interpolation_exact_at_nodes_and_accurate_between():
    f = np.linspace(0, 20, 41)                       # Δf = 0.5 Hz
    fun = lambda x: np.exp(-x / 15) * (1 + 0.5j * np.sin(x / 3))
    t, M = _table(f, fun)
    assert np.array_equal(t.at(f[7]), t.matrices[7])
    q = np.linspace(0, 20, 333)
    err = np.abs(t.at(q) - np.array([fun(x) * M for x in q])).max() / np.abs(M).max()
    assert err < 1e-5                                 # cubic spline: O(Δf⁴) ~ 1e-6 here
    # a cubic polynomial in f is reproduced exactly (not-a-knot spline)
    t3, M3 = _table(f, lambda x: 1 + x - 0.1j * x ** 3)
    assert np.allclose(t3.at(3.21), (1 + 3.21 - 0.1j * 3.21 ** 3) * M3, rtol=1e-12, atol=1e-9)
    assert np.allclose(t.at(-2.5), np.conj(t.at(2.5)))   # K(-f) = conj K(f)


def test_errors_are_clear(tmp_path):
    t, _ = _table(np.linspace(1, 10, 5), lambda f: f)
    with pytest.raises(TableError, match="outside the table range"):
        t.at(12.0)
    with pytest.raises(TableError, match="outside the table range"):
        t.at(0.5)
    with pytest.raises(TableError, match="strictly increasing"):
        ImpedanceTable([1, 1, 2], np.zeros((3, 2, 2)), ["a", "b"])
    with pytest.raises(TableError, match="shape"):
        ImpedanceTable([1, 2], np.zeros((3, 2, 2)), ["a", "b"])
    with pytest.raises(TableError, match="labels"):
        ImpedanceTable([1, 2], np.zeros((2, 2, 2)), ["a"])
    with pytest.raises(TableError, match="no DOF"):
        t.index("uz")
    (tmp_path / "junk.h5").write_text("not hdf5")
    with pytest.raises(TableError, match="cannot open"):
        ImpedanceTable.load(tmp_path / "junk.h5")
    with pytest.raises(TableError, match="cannot open"):
        ImpedanceTable.load(tmp_path / "missing.h5")
    with h5py.File(tmp_path / "other.h5", "w") as h:
        h["x"] = 1
    with pytest.raises(TableError, match="not an uplift.ImpedanceTable"):
        ImpedanceTable.load(tmp_path / "other.h5")
    t.save(tmp_path / "k.h5")
    with h5py.File(tmp_path / "k.h5", "r+") as h:
        h["matrices_real"][0, 0, 0] += 1.0
    with pytest.raises(TableError, match="changed since it was written"):
        ImpedanceTable.load(tmp_path / "k.h5")


def test_sweep_cache_hit_returns_identical_arrays_without_recomputation(tmp_path, monkeypatch):
    prof = SoilProfile.homogeneous(vs=200.0, rho=2000.0, nu=0.3, damping=0.05)
    mesh = circle_mesh(4.0, 1.0)
    calls = []
    real = sweep_mod._compute
    monkeypatch.setattr(sweep_mod, "_compute", lambda *a: calls.append(1) or real(*a))
    seen = []
    a = impedance_sweep(prof, mesh, [0.0], outputs=("rigid", "gap"), cache_dir=tmp_path,
                        progress=lambda *p: seen.append(p))
    assert calls == [1] and seen == [(1, 1, "0 Hz")] and len(list(tmp_path.glob("*.h5"))) == 2
    b = impedance_sweep(prof, mesh, [0.0], outputs=("rigid", "gap"), cache_dir=tmp_path)
    assert calls == [1]                                   # read back, not recomputed
    for o in a:
        assert np.array_equal(a[o].matrices, b[o].matrices) and a[o].hash == b[o].hash
    # any changed input is a different key
    impedance_sweep(prof, mesh, [0.0], contact="relaxed", outputs=("rigid",), cache_dir=tmp_path)
    impedance_sweep(SoilProfile.homogeneous(vs=201.0, rho=2000.0, nu=0.3, damping=0.05), mesh, [0.0],
                    outputs=("rigid",), cache_dir=tmp_path)
    assert calls == [1, 1, 1]
    K0 = static_impedance(prof, mesh, output="rigid", cache_dir=tmp_path)
    assert calls == [1, 1, 1] and np.array_equal(K0, a["rigid"].matrices[0])
    assert a["gap"].dofs[6] == "w0" and a["rigid"].dofs == ["ux", "uy", "uz", "rx", "ry", "rz"]
