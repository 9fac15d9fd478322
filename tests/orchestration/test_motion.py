"""Motions: deterministic synthetic records with the requested PGA, record readers, errors."""
import numpy as np
import pytest

from orchestrator.motion import MotionError, make_motion, read_record, rg160_psa, synthetic_motion
from orchestrator.spectra import response_spectrum


def test_synthetic_is_deterministic_and_scaled():
    a = synthetic_motion(0.25, 10.0, 0.005, seed=3)
    b = synthetic_motion(0.25, 10.0, 0.005, seed=3)
    assert np.array_equal(a.acc, b.acc)
    assert a.acc.shape == (2001, 3) and np.all(a.acc[:, 1:] == 0)
    assert a.pga[0] == pytest.approx(0.25 * 9.81, rel=1e-12)
    # baseline corrected: the final ground velocity is small against its peak
    vel = np.concatenate([[0], np.cumsum(0.5 * (a.acc[1:, 0] + a.acc[:-1, 0])) * a.dt])
    disp = np.cumsum(vel) * a.dt
    assert abs(vel[-1]) < 1e-10 * np.abs(vel).max()
    assert abs(disp[-1]) < 1e-2 * np.abs(disp).max()
    assert abs(a.acc[0, 0]) < 1e-3 * a.pga[0]            # quiet start kept


def test_synthetic_spectrum_shape_follows_rg160():
    m = synthetic_motion(0.25, 10.0, 0.005, seed=1)
    f = np.geomspace(0.5, 25, 25)
    ratio = response_spectrum(m.acc[:, 0], m.dt, 1 / f, 0.05).psa / rg160_psa(f, 0.25 * 9.81)
    # the shape is matched (ratio flat within ±25 %); its level is set by the PGA scaling
    assert ratio.max() / ratio.min() < 1.7


def test_rg160_control_points():
    assert rg160_psa([2.5, 9.0, 33.0, 50.0], 1.0) == pytest.approx([3.13, 2.61, 1.0, 1.0])


def test_readers(tmp_path):
    two = tmp_path / "rec.txt"
    two.write_text("0 0\n0.01 0.1\n0.02 -0.2\n0.03 0.05\n")
    m = read_record(two, "two-column", units="g", scale=2.0, direction="y")
    assert m.dt == pytest.approx(0.01) and m.acc[2, 1] == pytest.approx(-0.4 * 9.81)
    at2 = tmp_path / "rec.AT2"
    at2.write_text("PEER\nEQ\nACCELERATION TIME SERIES IN UNITS OF G\nNPTS=   5, DT=   .0050 SEC\n"
                   "  .1  .2  .3\n  .4  .5\n")
    m = read_record(at2, "peer-at2", units="g")
    assert m.dt == 0.005 and m.acc[:, 0] == pytest.approx(9.81 * np.array([.1, .2, .3, .4, .5]))


@pytest.mark.parametrize("kwargs, msg", [
    ({"path": "absent.txt"}, "no such file"),
    ({"fmt": "csv"}, "motion.format = 'csv'"),
    ({"units": "gal"}, "motion.units = 'gal'"),
    ({"direction": "w"}, "motion.direction = 'w'"),
])
def test_reader_errors(tmp_path, kwargs, msg):
    rec = tmp_path / "rec.txt"
    rec.write_text("0 0\n0.01 0.1\n")
    path = kwargs.pop("path", rec)
    with pytest.raises(MotionError, match=msg.replace("(", r"\(").replace(")", r"\)")):
        read_record(tmp_path / path if isinstance(path, str) else path, **kwargs)


def test_synthetic_record_does_not_depend_on_the_analysis_step():
    """One scene, one motion: a time-step study must compare the same record (resampled)."""
    fine = synthetic_motion(0.25, 10.0, 0.005, seed=2)
    coarse = synthetic_motion(0.25, 10.0, 0.02, seed=2)
    finer = synthetic_motion(0.25, 10.0, 0.0025, seed=2)
    assert coarse.dt == 0.02 and coarse.acc.shape == (501, 3)
    np.testing.assert_allclose(coarse.acc, fine.acc[::4], rtol=0, atol=1e-12 * fine.pga.max())
    np.testing.assert_allclose(finer.acc[::2], fine.acc, rtol=0, atol=1e-12 * fine.pga.max())
    np.testing.assert_allclose(finer.acc[1::2], 0.5 * (fine.acc[:-1] + fine.acc[1:]), rtol=0,
                               atol=1e-12 * fine.pga.max())


def test_make_motion_is_the_generator_or_the_resampled_record(tmp_path):
    """make_motion(config, dt): the synthetic record of the config's keys; a record as read,
    linearly resampled when the analysis step differs from the record's."""
    from orchestrator.scene import MotionConfig
    cfg = MotionConfig(pga_g=0.3, duration_s=4.0, seed=5, direction="y")
    for dt in (0.005, 0.01):
        assert np.array_equal(make_motion(cfg, dt).acc, synthetic_motion(0.3, 4.0, dt, seed=5, direction="y").acc)
    rec = tmp_path / "rec.txt"
    rec.write_text("".join(f"{0.01 * k:.2f} {np.sin(0.3 * k):.6f}\n" for k in range(101)))
    cfg = MotionConfig(kind="record", file=rec, units="m/s2", scale=2.0)
    same = make_motion(cfg, 0.01)
    assert same.dt == pytest.approx(0.01) and np.array_equal(same.acc, read_record(rec, units="m/s2", scale=2.0).acc)
    half = make_motion(cfg, 0.005)
    assert half.dt == 0.005 and half.acc.shape == (201, 3)
    np.testing.assert_allclose(half.acc[1::2, 0], 0.5 * (same.acc[:-1, 0] + same.acc[1:, 0]), rtol=0, atol=1e-12)


AT2_HEAD = "PEER\nEQ\nACCELERATION TIME SERIES IN UNITS OF G\n"


@pytest.mark.parametrize("name, content, msg", [
    ("bad.txt", b"0 0\n0.01 \xff\n", "bad.txt, line 2: byte 0xff is not UTF-8 text"),
    ("bad.txt", b"0 0\n0.01 0.1\n0.02 abc\n", "bad.txt, line 3: '0.02 abc' is not a list of numbers"),
    ("bad.txt", b"0 0\n0.01 0.1 7\n", "bad.txt, line 2: expected two columns"),
    ("bad.txt", b"0 0\n0.01 nan\n", "bad.txt, line 2: '0.01 nan': values must be finite"),
    ("bad.txt", b"0 0\n0.01 0.1\n0.03 0.1\n", "bad.txt, line 3: time step 0.02 s against 0.01 s"),
    ("bad.txt", b"# only a comment\n0 0\n", "expected at least two lines"),
    ("bad.AT2", (AT2_HEAD + "NPTS=   3, DT=   0.0 SEC\n .1 .2 .3\n").encode(), "bad.AT2, line 4: DT = 0 must be"),
    ("bad.AT2", (AT2_HEAD + "NPTS=   3, DT=  -0.01 SEC\n .1 .2 .3\n").encode(), "line 4: DT = -0.01 must be"),
    ("bad.AT2", (AT2_HEAD + "NPTS=   3, DT=   nan SEC\n .1 .2 .3\n").encode(), "line 4: DT = nan must be"),
    ("bad.AT2", (AT2_HEAD + "NPTS=  -3, DT=   .01 SEC\n .1 .2 .3\n").encode(), "line 4: NPTS = -3 must be"),
    ("bad.AT2", (AT2_HEAD + "NPTS=  2.5, DT=   .01 SEC\n .1 .2 .3\n").encode(), "line 4: NPTS = 2.5 must be"),
    ("bad.AT2", (AT2_HEAD + "NPTS=  100, DT=   .01 SEC\n .1 .2 .3\n").encode(), "NPTS = 100 but 3 values follow"),
    ("bad.AT2", (AT2_HEAD + "DT and NPTS unknown\n .1 .2 .3\n").encode(), "line 4: cannot read NPTS and DT"),
    ("bad.AT2", (AT2_HEAD + "NPTS=   3, DT=   .01 SEC\n .1 .2\n x\n").encode(), "bad.AT2, line 6: 'x' is not"),
    ("bad.AT2", (AT2_HEAD + "NPTS=   3, DT=   .01 SEC\n").encode(), "too short for a PEER AT2 file"),
])
def test_malformed_records_name_the_file_and_line(tmp_path, name, content, msg):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(MotionError) as ei:
        read_record(path, "peer-at2" if name.endswith(".AT2") else "two-column")
    assert msg in str(ei.value), str(ei.value)


def test_at2_header_forms(tmp_path):
    """NPTS=/DT= with or without spaces and commas, or the older positional 'NPTS DT' header."""
    for header in ("NPTS=   4, DT=   .0100 SEC", "NPTS=4 DT=.01", "4   0.01   NPTS, DT"):
        path = tmp_path / "r.AT2"
        path.write_text(AT2_HEAD + header + "\n .1 .2\n .3 .4 .5\n")
        m = read_record(path, "peer-at2")
        assert m.dt == 0.01 and m.acc[:, 0] == pytest.approx(9.81 * np.array([.1, .2, .3, .4]))
