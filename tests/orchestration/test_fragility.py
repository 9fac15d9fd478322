"""Fragility curves (orchestrator.fragility, `uplift fragility`): the maximum-likelihood fit
against its sampling error on data drawn from a known lognormal, against a direct grid search
and a hand-computed likelihood; the cases it cannot fit; the bootstrap; a real ensemble (a
small tower on Winkler springs, 8 seeds x 6 PGAs, 1 worker) where the command agrees with an
independent fit of the file's cells, failed cells left out and counted; the report; bad input."""
import contextlib
import io
import json
import math

import numpy as np
import pytest
import xarray as xr
from scipy import optimize, stats

from orchestrator import fragility as frag
from orchestrator.cli import main
from orchestrator.ensemble import read_ensemble, write_ensemble
from orchestrator.report import fragility_parts
from helpers import tower, write_scene
from helpers.native import seed_native

# ---- the fit on arrays --------------------------------------------------------------------------


def _fisher(median, beta, pga, n):
    """Expected Fisher information of (ln median, beta) for binomial stripes (independent of the
    module: p = Phi(u), I = sum n phi(u)^2 / (p (1 - p)) du du^T)."""
    u = (np.log(pga) - np.log(median)) / beta
    p = stats.norm.cdf(u)
    w = n * stats.norm.pdf(u) ** 2 / (p * (1 - p))
    d = np.stack([-np.ones_like(u) / beta, -u / beta])
    return (w * d) @ d.T


def test_recovers_a_known_lognormal_within_its_sampling_error():
    """300 data sets of 10 stripes x 60 cells from median 0.3 g, beta 0.4: the z-scores of ln
    median and beta against the asymptotic standard error (inverse Fisher information) have
    mean 0 within 4 standard errors of a mean (4 / sqrt(300)) and standard deviation 1 within
    15 %; none beyond 4.5."""
    median, beta = 0.3, 0.4
    pga = np.geomspace(0.1, 0.9, 10)
    n = np.full(pga.size, 60)
    se = np.sqrt(np.diag(np.linalg.inv(_fisher(median, beta, pga, n))))
    p = stats.norm.cdf(np.log(pga / median) / beta)
    scores = []
    for seed in range(300):
        z = np.random.default_rng(seed).binomial(n, p)
        fit = frag.fit_fragility(pga, n, z)
        assert fit.identified, fit.reason
        scores.append([(np.log(fit.median_g) - np.log(median)) / se[0], (fit.beta - beta) / se[1]])
    scores = np.array(scores)
    assert np.all(np.abs(scores) < 4.5)
    assert np.all(np.abs(scores.mean(axis=0)) < 4 / np.sqrt(len(scores))), scores.mean(axis=0)
    assert np.all(np.abs(scores.std(axis=0) - 1) < 0.15), scores.std(axis=0)


def _phi(u):
    return 0.5 * (1 + math.erf(u / math.sqrt(2)))


def test_hand_computed_likelihood_and_grid_search():
    """Three stripes of 5 cells, 1, 2 and 4 exceedances: ln L at (0.2 g, 0.5) written out with
    math.erf and math.comb; the optimum is at least the best point of a 1201 x 1201 grid, within
    one grid step of it, and its gradient is zero."""
    pga, n, z = np.array([0.1, 0.2, 0.4]), np.array([5, 5, 5]), np.array([1, 2, 4])
    by_hand = 0.0
    for x, nn, zz in zip(pga, n, z):
        p = _phi(math.log(x / 0.2) / 0.5)
        by_hand += math.log(math.comb(nn, zz)) + zz * math.log(p) + (nn - zz) * math.log(1 - p)
    assert frag.log_likelihood(0.2, 0.5, pga, n, z) == pytest.approx(by_hand, rel=1e-13)
    fit = frag.fit_fragility(pga, n, z)
    assert fit.identified
    mu = np.linspace(np.log(0.05), np.log(1.0), 1201)
    beta = np.linspace(0.1, 2.0, 1201)
    grid = frag.log_likelihood(np.exp(mu)[:, None], beta[None, :], pga, n, z)
    i, j = np.unravel_index(np.argmax(grid), grid.shape)
    assert 0 < i < mu.size - 1 and 0 < j < beta.size - 1            # an interior maximum
    assert fit.log_likelihood >= grid[i, j] - 1e-12
    assert abs(np.log(fit.median_g) - mu[i]) <= mu[1] - mu[0]
    assert abs(fit.beta - beta[j]) <= beta[1] - beta[0]
    assert fit.log_likelihood == pytest.approx(frag.log_likelihood(fit.median_g, fit.beta, pga, n, z), rel=1e-14)
    h = 1e-6
    for dm, db in ((h, 0), (0, h)):
        up = frag.log_likelihood(fit.median_g * np.exp(dm), fit.beta + db, pga, n, z)
        down = frag.log_likelihood(fit.median_g * np.exp(-dm), fit.beta - db, pga, n, z)
        assert abs(up - down) / (2 * h) < 1e-5


@pytest.mark.parametrize("n, z, reason", [
    ([8, 8, 8], [0, 0, 0], "no exceedance: no cell exceeds the limit at any PGA up to 0.4 g"),
    ([8, 8, 8], [8, 8, 8], "all exceed: every cell exceeds the limit at every PGA from 0.1 g"),
    ([0, 8, 0], [0, 3, 0], "one PGA level only (0.2 g)"),
    ([8, 8, 8], [0, 3, 8], "exceedances separated by PGA: no cell exceeds below and every cell exceeds above "
                           "the median, which lies at 0.2 g; the likelihood grows without bound as beta -> 0: "
                           "add records or PGA levels around 0.2 g"),
    ([8, 8, 8], [0, 0, 8], "which lies between 0.2 and 0.4 g"),
    ([0, 0, 0], [0, 0, 0], "no usable cell"),
    ([8, 8, 8], [6, 4, 2], "beta runs to its bound 2 (the fractions barely rise with PGA)"),
])
def test_cases_that_cannot_be_fitted_say_why(n, z, reason):
    fit = frag.fit_fragility([0.1, 0.2, 0.4], n, z)
    assert not fit.identified and reason in fit.reason
    assert (fit.median_g, fit.beta, fit.log_likelihood) == (None, None, None)


def _capacities(n_records, median, beta, pga, seed):
    """Per-record exceedance (record, pga): a record exceeds at PGA x when x > its capacity,
    capacities lognormal(median, beta)."""
    c = median * np.exp(beta * np.random.default_rng(seed).standard_normal(n_records))
    return pga[None, :] > c[:, None]


def test_bootstrap_over_records_matches_the_spread_of_the_estimate():
    """Records with lognormal capacities (median 0.3 g, beta 0.4; 80 records x 7 PGAs): the 90 %
    bootstrap band of the median (150 resamples), averaged over 4 ensembles, has the width of
    the 5-95 % spread of the median over 200 independent ensembles within 20 % (one ensemble's
    band scatters by about 10 %), and holds the estimate; seeded."""
    pga = np.geomspace(0.1, 0.9, 7)
    estimates = []
    for seed in range(200):
        hits = _capacities(80, 0.3, 0.4, pga, seed)
        estimates.append(frag.fit_fragility(pga, np.full(pga.size, 80), hits.sum(axis=0)).median_g)
    spread = np.diff(np.quantile(np.log(estimates), [0.05, 0.95]))[0]
    widths = []
    for seed in range(1000, 1004):
        hits = _capacities(80, 0.3, 0.4, pga, seed)
        usable = np.ones_like(hits)
        bs = frag.bootstrap(pga, hits, usable, 150, seed=7, confidence=0.9)
        assert bs["identified"] == 150
        widths.append(np.log(bs["median_g"][1] / bs["median_g"][0]))
        point = frag.fit_fragility(pga, usable.sum(axis=0), hits.sum(axis=0)).median_g
        assert bs["median_g"][0] < point < bs["median_g"][1]
    assert 0.8 < np.mean(widths) / spread < 1.2, (widths, spread)
    assert frag.bootstrap(pga, hits, usable, 50, seed=7, confidence=0.9) == \
        frag.bootstrap(pga, hits, usable, 50, seed=7, confidence=0.9)
    assert frag.bootstrap(pga, hits, usable, 50, seed=8, confidence=0.9) != \
        frag.bootstrap(pga, hits, usable, 50, seed=7, confidence=0.9)


def test_which_cells_count():
    """Converged cells with a number count; failed, stopped, refused and NaN ones are left out
    and counted by reason; <= and < differ at the threshold."""
    values = np.array([[0.75, 0.5, np.nan], [1.0, 0.75, 0.25]])
    status = np.array([["converged", "stopped", "converged"], ["converged", "failed", "refused"]])
    usable, hit, left = frag.exceedances(values, status, "<=", 0.75)
    np.testing.assert_array_equal(usable, [[True, False, False], [True, False, False]])
    np.testing.assert_array_equal(hit, [[True, False, False], [False, False, False]])
    assert dict(zip(frag.LEFT_OUT, left)) == {"failed": 1, "stopped": 1, "refused": 1, "undefined": 1}
    assert not frag.exceedances(values, status, "<", 0.75)[1].any()


@pytest.mark.parametrize("text, norm", [
    ("max_uplift>5mm", "max_uplift > 5 mm"),
    ("  min_contact_ratio <= 0.75 ", "min_contact_ratio <= 0.75"),
    ("floor_spectrum[node=top,direction=x, frequency=5] > 1.2e-1 g",
     "floor_spectrum[node=top, direction=x, frequency=5] > 1.2e-1 g"),
])
def test_limit_syntax(text, norm):
    assert frag.parse_limit(text).text == norm


# ---- a real ensemble ----------------------------------------------------------------------------

TOWER = tower(soil={"halfspace": None}, motion={"pga_g": 0.2, "duration_s": 2.0, "seed": 1})
PGAS = ("0.05", "0.1", "0.15", "0.2", "0.3", "0.4")
LIMITS = ("max_uplift > 2 mm", "min_contact_ratio < 75 %", "floor_spectrum[node=top, direction=x, frequency=5.0] > 0.2 g")


@pytest.fixture(scope="module")
def ensemble(tmp_path_factory, scheduler):
    """`uplift ensemble` of the tower: 8 seeds x 6 PGAs on the winkler route, on the session's
    scheduler (one worker), on a cache folder of its own holding the C runtime compiled once for
    the tests (its worker and its time-step check load it instead of compiling it twice)."""
    tmp = tmp_path_factory.mktemp("fragility")
    write_scene(tmp / "tower.toml", TOWER)
    out = tmp / "ens.h5"
    with pytest.MonkeyPatch.context() as env, contextlib.redirect_stdout(io.StringIO()):
        env.setenv("UPLIFT_CACHE", str(seed_native(tmp / "cache")))
        code = main(["ensemble", str(tmp / "tower.toml"), "--seeds", *map(str, range(1, 9)), "--pga", *PGAS,
                     "--scheduler", scheduler, "-o", str(out), "--json"])
    assert code == 0
    return out


def _fragility(path, *args):
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(["fragility", str(path), *args])
    return code, (json.loads(stdout.getvalue()) if code == 0 and "--json" in args else None)


def _cell_numbers(ds, limit):
    """(values (record, pga), threshold) of the winkler cells, read straight from the file: the
    spectral ordinate interpolated linearly in ln f by numpy."""
    if limit.startswith("max_uplift"):
        return ds["max_uplift"].sel(route="winkler").values, 2e-3
    if limit.startswith("min_contact_ratio"):
        return ds["min_contact_ratio"].sel(route="winkler").values, 0.75
    s = ds["floor_spectrum"].sel(route="winkler", node="top", direction="x").values
    lnf = np.log(ds["frequency"].values)
    return np.apply_along_axis(lambda row: np.interp(np.log(5.0), lnf, row), -1, s), 0.2 * 9.81


def _independent_fit(pga, n, z):
    """Maximum likelihood with scipy.stats.binom and Nelder-Mead on (ln median, ln beta)."""
    keep = n > 0
    pga, n, z = pga[keep], n[keep], z[keep]
    nll = lambda p: -stats.binom.logpmf(z, n, stats.norm.cdf(np.log(pga / np.exp(p[0])) / np.exp(p[1]))).sum()
    res = optimize.minimize(nll, [np.log(np.median(pga)), np.log(0.5)], method="Nelder-Mead",
                            options={"xatol": 1e-10, "fatol": 1e-13, "maxiter": 5000})
    return np.exp(res.x[0]), np.exp(res.x[1]), -res.fun


def _check_against_file(entries, path, status_ok):
    ds = xr.open_dataset(path, engine="h5netcdf").load()
    pga = ds["pga"].values
    usable = status_ok(ds)
    for e, limit in zip(entries, LIMITS):
        values, threshold = _cell_numbers(ds, limit)
        exceed = (values < threshold if "<" in limit else values > threshold) & usable
        n, z = usable.sum(axis=0), exceed.sum(axis=0)
        assert (e["limit"], e["route"], e["pga_g"]) == (limit, "winkler", list(pga))
        assert (e["cells"], e["exceedances"]) == (list(n), list(z))
        assert 0 < z.sum() < n.sum() and e["identifiable"] and e["reason"] is None
        median, beta, ll = _independent_fit(pga, n, z)
        assert e["median_g"] == pytest.approx(median, rel=1e-6)
        assert e["beta"] == pytest.approx(beta, rel=1e-6)
        assert e["log_likelihood"] == pytest.approx(ll, abs=1e-9)
        assert e["log_likelihood"] >= ll - 1e-12                      # the module's optimum is not worse


@pytest.mark.slow
def test_cli_agrees_with_a_fit_of_the_files_cells(ensemble, tmp_path):
    path = tmp_path / "ens.h5"
    path.write_bytes(ensemble.read_bytes())
    root = read_ensemble(path)
    code, out = _fragility(path, *(a for lim in LIMITS for a in ("--limit", lim)), "--json", "--plot",
                           str(tmp_path / "f.png"))
    assert code == 0 and (tmp_path / "f.png").stat().st_size > 0
    entries = out["fragility"]
    assert len(entries) == 3
    _check_against_file(entries, path, lambda ds: ds["status"].sel(route="winkler").values == "converged")
    assert all(e["left_out"] == dict.fromkeys(frag.LEFT_OUT, 0) and e["bootstrap"] is None for e in entries)
    # stored in the file: the group opens with xarray and holds the same numbers; the cells are untouched
    stored = xr.open_dataset(path, group="fragility", engine="h5netcdf").load()
    assert list(stored["limit"].values) == list(LIMITS)
    np.testing.assert_array_equal(stored["median_g"].values[:, 0], [e["median_g"] for e in entries])
    np.testing.assert_array_equal(stored["exceedances"].values[:, 0], [e["exceedances"] for e in entries])
    xr.testing.assert_identical(read_ensemble(path), root)
    # the report draws it: the table and one panel per limit
    assert main(["report", str(path), "-o", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "report.html").read_text()
    assert f"<td>{entries[0]['median_g']:.4g}</td>" in page and (tmp_path / "rep" / "fragility.png").is_file()
    fig = frag.fragility_figure(frag.read_fragility(path))
    assert [ax.get_title() for ax in fig.axes] == list(LIMITS)
    # a second fit replaces the first
    code, out = _fragility(path, "--limit", "max_uplift > -1", "--json")
    e = out["fragility"][0]
    assert not e["identifiable"] and e["median_g"] is None and e["reason"].startswith("all exceed")
    assert list(frag.read_fragility(path)["limit"].values) == ["max_uplift > -1"]


def test_spectral_ordinate_on_and_between_grid_frequencies(ensemble):
    """On a grid frequency the file's value; between two, linear in ln f; thresholds in g."""
    ds = read_ensemble(ensemble)
    f = ds["frequency"].values
    s = ds["floor_spectrum"].sel(node="top", direction="x").transpose("record", "pga", "route", "frequency").values
    on, g = frag.limit_values(ds, frag.parse_limit(f"floor_spectrum[node=top, direction=x, frequency={float(f[40])!r}] > 1 g"))
    np.testing.assert_array_equal(on, s[..., 40])
    assert g == 9.81
    mid = np.sqrt(f[40] * f[41])                                   # halfway in ln f
    between, _ = frag.limit_values(ds, frag.parse_limit(f"floor_spectrum[node=top, direction=x, frequency={float(mid)!r}] > 1"))
    np.testing.assert_allclose(between, 0.5 * (s[..., 40] + s[..., 41]), rtol=1e-12)


def test_failed_cells_left_out_and_counted(ensemble, tmp_path):
    ds = read_ensemble(ensemble)
    status, uplift = ds["status"].values.copy(), ds["max_uplift"].values.copy()
    for i, j, why in ((0, 3, "failed"), (2, 3, "failed"), (5, 4, "stopped")):
        status[i, j, 0] = why
        if why == "failed":
            uplift[i, j, 0] = np.nan
    ds["status"].values, ds["max_uplift"].values = status, uplift
    path = write_ensemble(ds, tmp_path / "partial.h5")
    code, out = _fragility(path, *(a for lim in LIMITS for a in ("--limit", lim)), "--json", "--no-store")
    assert code == 0 and frag.read_fragility(path) is None
    for e in out["fragility"]:
        assert e["left_out"] == {"failed": 2, "stopped": 1, "refused": 0, "undefined": 0}
        assert e["cells"] == [8, 8, 8, 6, 7, 8]
    _check_against_file(out["fragility"], path, lambda ds: ds["status"].sel(route="winkler").values == "converged")


def test_bootstrap_from_the_command_is_seeded(ensemble, tmp_path):
    path = tmp_path / "ens.h5"
    path.write_bytes(ensemble.read_bytes())
    args = ("--limit", LIMITS[0], "--bootstrap", "40", "--seed", "3", "--json", "--no-store")
    (_, a), (_, b) = _fragility(path, *args), _fragility(path, *args)
    assert a == b
    bs, median = a["fragility"][0]["bootstrap"], a["fragility"][0]["median_g"]
    assert (bs["samples"], bs["seed"], bs["confidence"]) == (40, 3, 0.9) and 0 < bs["identified"] <= 40
    assert bs["median_g"][0] < median < bs["median_g"][1]
    # no resample fitted: no band (JSON null, the report's "-"), the fit itself stays
    fits = frag.fragility(read_ensemble(path), [LIMITS[0]], samples=5)
    fits["median_g_band"][:], fits["beta_band"][:], fits["bootstrap_identified"][:] = np.nan, np.nan, 0
    e = frag.fragility_json(fits)["fragility"][0]
    assert e["median_g"] == median and e["bootstrap"]["identified"] == 0
    assert e["bootstrap"]["median_g"] is None and e["bootstrap"]["beta"] is None
    frag.store_fragility(path, fits)
    assert "<td>-</td>" in "".join(fragility_parts(path, tmp_path))


@pytest.mark.parametrize("args, message", [
    (["--limit", "max_uplift >> 2"], "--limit 'max_uplift >> 2': write VARIABLE > VALUE"),
    (["--limit", "uplift > 2 mm"], "no per-cell variable 'uplift' in the ensemble file (its variables: max_uplift"),
    (["--limit", "max_uplift > 2 mm", "--route", "monolithic"],
     "--route 'monolithic' is not in the ensemble file (its routes: winkler)"),
    (["--limit", "max_uplift > 2 g"], "unit 'g' is not one of max_uplift's (m, cm, mm; no unit: m)"),
    (["--limit", "max_uplift[node=top] > 2 mm"], "max_uplift is one number per cell: drop the [...]"),
    (["--limit", "floor_spectrum > 1 g"], "floor_spectrum needs [node=..., direction=..., frequency=...]"),
    (["--limit", "floor_spectrum[node=top, direction=x, frequency=80] > 1 g"],
     "frequency '80' must be a number of Hz within the file's spectra, 0.5 to 40 Hz"),
    (["--limit", "floor_spectrum[node=roof, direction=x, frequency=5] > 1 g"], "node 'roof' is not in the file"),
    (["--limit", "max_uplift > 2 mm", "--limit", "max_uplift>2mm"], "the same limit state is given twice"),
    (["--limit", "max_uplift > 2 mm", "--bootstrap", "-1"], "--bootstrap -1: a number of resamples >= 0"),
    (["--limit", "max_uplift > 2 mm", "--bootstrap", "5", "--seed", "-2"], "--seed -2: the bootstrap's seed"),
    (["--limit", "max_uplift > 2 mm", "--confidence", "1.5"], "argument --confidence: '1.5' must lie in (0, 1)"),
])
def test_bad_input_exits_2_and_leaves_the_file(ensemble, tmp_path, capsys, args, message):
    path = tmp_path / "ens.h5"
    path.write_bytes(ensemble.read_bytes())
    assert _fragility(path, *args)[0] == 2
    assert message in capsys.readouterr().err
    assert path.read_bytes() == ensemble.read_bytes()


def test_not_an_ensemble_file_exits_2(tmp_path, capsys):
    assert _fragility(tmp_path / "nowhere.h5", "--limit", "max_uplift > 2 mm")[0] == 2
    assert "is not an ensemble file of `uplift ensemble`" in capsys.readouterr().err


@pytest.mark.slow
def test_the_readmes_recipe_in_small_gives_an_identifiable_curve(tmp_path, capsys, monkeypatch):
    """README's recipe (`uplift ensemble reactor --pga 0.1 0.2 0.3 0.4 --n-seeds 8`, then `uplift
    fragility --limit "max_uplift > X mm"`) on the tower: 6 seeds (0 to 5) x 4 PGAs, 2 s records,
    winkler, 1 worker (a cache folder, so that the worker loads the native stepper the time-step
    check compiled); the limit lies inside the spread of the cells, so the counts straddle the
    PGAs and the fit is identified (measured: 0/6, 4/6, 5/6, 5/6; median 0.201 g, beta 0.480)."""
    monkeypatch.setenv("UPLIFT_CACHE", str(seed_native(tmp_path / "cache")))
    scene = write_scene(tmp_path / "tower.toml", TOWER)
    out = tmp_path / "ens.h5"
    assert main(["ensemble", scene, "--n-seeds", "6", "--pga", "0.1", "0.2", "0.3", "0.4", "--workers", "1",
                 "-o", str(out), "--json"]) == 0
    summ = json.loads(capsys.readouterr().out)
    assert summ["runs"] == 24
    ds = xr.open_dataset(out, engine="h5netcdf").load()
    assert ds.sizes["record"] == 6 and [str(r) for r in ds["record"].values] == [f"seed {s}" for s in range(6)]
    code, fits = _fragility(out, "--limit", "max_uplift > 2 mm", "--json", "--no-store")
    (e,) = fits["fragility"]
    assert code == 0 and e["identifiable"], e
    assert 0 < sum(e["exceedances"]) < sum(e["cells"]) and 0.1 < e["median_g"] < 0.4 and 0 < e["beta"] < 2
    assert main(["fragility", str(out), "--limit", "max_uplift > 100 mm", "--no-store"]) == 0
    assert "NOT IDENTIFIABLE: no exceedance" in capsys.readouterr().out
