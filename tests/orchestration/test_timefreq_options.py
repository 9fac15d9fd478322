"""The time-frequency package's interface: options checked on construction, the worker pool's
lifetime and thread-independence, the solver status in the result, and the route glue."""
import subprocess
import sys
import threading
import warnings

import numpy as np
import pytest

from structure import ContactSettings
from structure.results import Status

from orchestrator.motion import Motion
from orchestrator.routes.linear import run_linear
from orchestrator.routes.timefreq import run_timefreq
from orchestrator.timefreq import (GridOptions, NewtonKrylovOptions, PaperOptions, SolveOptions, WorkerPool, linear_fd,
                                   solve)
from helpers import COARSE_RAFT, hysteretic_table, rel, winkler_rational
from helpers import broadband as motion

MODEL, soil = COARSE_RAFT.model, COARSE_RAFT.soil

UPLIFT = ContactSettings(enabled=True)


@pytest.mark.parametrize("make, field", [
    (lambda: GridOptions(pad_s=-1.0), "GridOptions.pad_s"),
    (lambda: GridOptions(wrap_tol=1.5), "GridOptions.wrap_tol"),
    (lambda: GridOptions(wrap_tol=0.0), "GridOptions.wrap_tol"),
    (lambda: GridOptions(nfft=0), "GridOptions.nfft"),
    (lambda: GridOptions(bilinear="yes"), "GridOptions.bilinear"),
    (lambda: SolveOptions(method="newton"), "SolveOptions.method"),
    (lambda: SolveOptions(tol=0.0), "SolveOptions.tol"),
    (lambda: SolveOptions(max_iter=2.5), "SolveOptions.max_iter"),
    (lambda: SolveOptions(max_seconds=float("nan")), "SolveOptions.max_seconds"),
    (lambda: SolveOptions(threads=0), "SolveOptions.threads"),
    (lambda: SolveOptions(paper=dict(rho=1.0)), "SolveOptions.paper"),
    (lambda: PaperOptions(rho=0.0), "PaperOptions.rho"),
    (lambda: PaperOptions(windows=0), "PaperOptions.windows"),
    (lambda: NewtonKrylovOptions(guess="zero"), "NewtonKrylovOptions.guess"),
])
def test_bad_options_name_the_field(make, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        make()


def test_bad_inputs_are_value_errors():
    ag = motion(0.3, duration=1.0)
    with pytest.raises(ValueError, match="bilinear grid"):
        solve(MODEL, soil(), ag, 0.005, options=SolveOptions(method="march"), grid=GridOptions(bilinear=False))
    with pytest.raises(ValueError, match="must be named"):    # no experimental default on the continuous grid
        solve(MODEL, soil(), ag, 0.005, contact=UPLIFT, grid=GridOptions(bilinear=False))
    with pytest.raises(ValueError, match="linear route"):
        solve(MODEL, soil(), ag, 0.005, contact=ContactSettings(enabled=False))
    with pytest.raises(ValueError, match="run_timefreq: unknown option 'padding'"):
        run_timefreq(Motion(0.005, ag), MODEL, hysteretic_table(), contact=UPLIFT, output_nodes=None, padding=1.0)
    with pytest.raises(ValueError, match="run_linear: unknown option 'tol'"):
        run_linear(Motion(0.005, ag), MODEL, hysteretic_table(), contact=UPLIFT, output_nodes=None, tol=1e-6)


def _pool_threads():
    return {t for t in threading.enumerate() if t.name.startswith("ThreadPoolExecutor")}


def test_worker_pool_lives_for_one_solve_and_does_not_change_the_answer():
    """Two threads or one: the same histories (each frequency is computed alone whatever the
    split; measured identical), and no worker thread left once the solve returns. The table
    (a dense band below 25 Hz, springs and dashpots above) runs its bands side by side; a
    rational soil (one dense band) splits its band between the threads."""
    before = _pool_threads()
    ag = motion(0.6, duration=2.0)
    for s in (hysteretic_table(), winkler_rational(soil())):
        one = solve(MODEL, s, ag, 0.005, contact=UPLIFT, options=SolveOptions(threads=1))
        two = solve(MODEL, s, ag, 0.005, contact=UPLIFT, options=SolveOptions(threads=2))
        assert one.converged and two.converged and one.max_uplift() > 1e-4
        assert (one.info["threads"], two.info["threads"]) == (1, 2)
        assert one.info["iterations"] == two.info["iterations"]
        assert rel(two.gap, one.gap) < 1e-12 and rel(two.raft, one.raft) < 1e-12
    lin1 = linear_fd(MODEL, hysteretic_table(), ag, 0.005, contact=UPLIFT, threads=1)
    lin2 = linear_fd(MODEL, hysteretic_table(), ag, 0.005, contact=UPLIFT, threads=2)
    assert rel(lin2.raft, lin1.raft) < 1e-12
    assert _pool_threads() <= before
    pool = WorkerPool(2)
    assert pool.run([lambda: 1, lambda: 2, lambda: 3]) == [1, 2, 3]
    assert pool.chunks(20) == [slice(0, 10), slice(10, 20)] and pool.chunks(10) == [slice(0, 10)]
    pool.close()
    with pytest.raises(RuntimeError, match="closed"):
        pool.run([lambda: 1, lambda: 2])


def test_status_and_history_in_the_result():
    """The solver's status and per-sweep records reach the RouteResult as JSON-able values."""
    ag = motion(0.3, duration=2.0)
    ok = solve(MODEL, hysteretic_table(), ag, 0.005, contact=UPLIFT)
    assert ok.status is Status.CONVERGED and ok.info["status"] == "converged" and ok.message == ""
    hist = ok.info["history"]
    assert len(hist) == ok.info["iterations"] and hist[-1]["residual"] <= 1e-10 < hist[0]["residual"]
    assert {"sweep", "residual", "wall_s", "kernel", "diverged", "newton"} <= set(hist[0])
    cut = solve(MODEL, hysteretic_table(), ag, 0.005, contact=UPLIFT, options=SolveOptions(max_seconds=0.0))
    assert cut.status is Status.STOPPED and cut.info["status"] == "stopped" and "time budget" in cut.message
    few = solve(MODEL, hysteretic_table(), ag, 0.005, contact=UPLIFT, options=SolveOptions(max_iter=1))
    assert few.info["status"] == "not converged" and "did not converge" in few.message
    assert few.info["iterations"] == 1 and few.info["residual"] > 1e-10


def test_route_glue_is_solve_with_the_route_defaults():
    """run_timefreq = solve at tolerance 1e-6 (one sweep fewer than 1e-10, the same answer to
    1e-6), its progress bar fed with the share of residual decades done; run_linear =
    linear_fd; overrides reach the options."""
    ag = motion(0.3, duration=2.0)
    mo, tab, nodes = Motion(0.005, ag), hysteretic_table(), ["top_outer"]
    bar = []
    route = run_timefreq(mo, MODEL, tab, contact=UPLIFT, output_nodes=nodes, progress=lambda k, n: bar.append((k, n)))
    direct = solve(MODEL, tab, ag, 0.005, contact=UPLIFT, output_nodes=nodes, options=SolveOptions(tol=1e-6))
    assert route.converged and route.info["residual"] <= 1e-6 and list(route.acc) == nodes
    assert np.array_equal(route.gap, direct.gap) and np.array_equal(route.acc["top_outer"], direct.acc["top_outer"])
    assert len(bar) == route.info["iterations"] and all(n == 100 and 0 <= k <= 99 for k, n in bar)
    assert [k for k, _ in bar] == sorted(k for k, _ in bar) and bar[0][0] == 0 and bar[-1][0] == 99
    padded = run_timefreq(mo, MODEL, tab, contact=UPLIFT, output_nodes=nodes, pad_s=5.0, route="tf-padded")
    assert padded.route == "tf-padded" and padded.info["pad_s"] >= 5.0 > route.info["pad_s"]
    lin = run_linear(mo, MODEL, tab, contact=UPLIFT, output_nodes=nodes, window=True)
    assert lin.info["window"] is True and lin.route == "linear"
    assert np.array_equal(lin.raft, linear_fd(MODEL, tab, ag, 0.005, contact=UPLIFT, output_nodes=nodes,
                                              grid=GridOptions(window=True)).raft)


def test_methods_by_registry_experimental_ones_warn_and_are_never_the_default():
    """METHODS maps every name SolveOptions accepts; the default is the one robust method and
    runs without a warning; the experimental solvers are out of the package's namespace and
    warn when named."""
    import orchestrator.timefreq as tf
    from orchestrator.timefreq import DEFAULT, METHODS, ExperimentalMethodWarning

    assert not METHODS[DEFAULT].experimental
    assert {n for n, m in METHODS.items() if m.experimental} == {"newton-krylov", "paper"}
    for name in ("newton_krylov", "newton_continuation", "paper_scheme", "NewtonIteration", "PaperIteration"):
        assert name not in tf.__all__
    for name in METHODS:
        SolveOptions(method=name)
    ag = motion(0.5, duration=2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExperimentalMethodWarning)
        res = solve(MODEL, soil(), ag, 0.005, contact=UPLIFT)
    assert res.info["method"] == DEFAULT and res.max_uplift() > 1e-3
    for name in ("newton-krylov", "paper"):              # (their answers: tests/orchestration/test_timefreq.py)
        with pytest.warns(ExperimentalMethodWarning, match=name):
            ex = solve(MODEL, soil(), ag, 0.005, contact=UPLIFT, options=SolveOptions(method=name, max_iter=1))
        assert ex.info["method"] == name


def test_the_solver_imports_pyfftw_without_dask():
    """pyfftw's package init would import dask.array (and xarray, ~0.9 s) for an interface the
    solver does not use: the solver's import leaves dask out, and dask still imports after."""
    code = ("import sys\n"
            "import orchestrator.timefreq\n"
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'dask', 'xarray'}))\n"
            "import dask.array.fft\n"
            "print(callable(dask.array.fft.fft_wrap))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.split("\n")[:2] == ["[]", "True"]
