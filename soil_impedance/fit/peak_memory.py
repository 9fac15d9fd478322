"""Peak memory of a rational fit, estimated before it starts (the run-level memory guard,
``orchestrator.memory_guard``, calls it).

The fit (``fit.pipeline.fit``) works on copies of the whole table: the active block of its
matrices, their scaled form, the upper triangles as columns, the unscaled target of the
rigid-raft correction, the model's response over the table's frequencies in the report and in
the passivity test. Measured peaks of the allocations made by the fit (tracemalloc, which sees
every numpy array), the table itself not counted, over the table's bytes 16 F n^2:

    225 nodes (n = 231), 101 frequencies, 6 poles:   6.7
    400 nodes (n = 406),  51 frequencies, 8 poles:   7.1

The model's coefficient and residue arrays, (m + 2) n^2 reals and m n^2 complex for m poles,
are added separately: they matter when the fit has many poles and few frequencies.

A table above ``blocked.STREAM_BYTES`` is on disk and its fit is the streamed fit
(``fit.streamed``, ``streamed_fit_memory``): it never holds the table, and its peak is that of
the model's coefficients and their copies, not of the table (docs/formulation.md, "The fit's
memory").
"""
from __future__ import annotations

from ..blocked import chunk_edge

#: peak of the fit's own allocations over the table's bytes (measured, see the module docstring)
FIT_COPIES = 7.2


def fit_memory(n_dof: int, n_freq: int, max_poles: int) -> dict[str, int]:
    """Estimated peak bytes of fitting a table of ``n_freq`` (n_dof, n_dof) complex matrices
    with at most ``max_poles`` poles, by item (and ``"total"``), the table itself not counted
    (the caller holds it).

    Items: ``work`` the copies of the table (``FIT_COPIES`` x 16 n_freq n_dof^2); ``model``
    the candidate models kept during the order search and the enforcement, two of at most
    ``max_poles`` poles, each its coefficients (m + 2) n^2 reals and residues m n^2 complex."""
    table = 16 * n_freq * n_dof * n_dof
    model = 2 * (8 * (max_poles + 2) + 16 * max_poles) * n_dof * n_dof
    items = {"work": int(FIT_COPIES * table), "model": model}
    items["total"] = sum(items.values())
    return items


#: blocks of F x edge^2 complex entries alive at once in a streamed pass (the block read, its
#: scaled copy, the model's response on it and the difference)
STREAM_BLOCKS = 4
#: (6+N)^2 complex arrays of the streamed problem itself: the frequencies read whole on demand
#: (the hysteretic part and the causal cut-off: up to three) and the hysteretic offset H0
PROBLEM_COPIES = 4
#: models of m poles alive at the streamed fit's peak, each its coefficients (m + 2) n^2 doubles and
#: residues m n^2 complex: the order's rigid-raft corrected model and the enforcement's output (the
#: plain model is dropped once corrected); measured, see ``streamed_fit_memory``
MODEL_COPIES = 2
#: orders' coefficients, (m + 2) n^2 doubles each, alive at once: the streamed order search holds none (it
#: fits every order's E, ``StreamedProblem.search_orders``), the enforcement one order's, fitted again from its poles
SEARCH_COPIES = 1
#: n^2 doubles of the streamed order search beside every order's E (one per pole pair): the active block of
#: an E, its negative eigenvectors and the eigenvalue solver's work
SEARCH_WORK = 3
#: (m + 2) n^2 double arrays of the enforcement beside the models: the scaled coefficients, the
#: corrected ones and their symmetrised copy
ENFORCE_COPIES = 3
#: the certified passivity sweep's G(nu) block: at most 64 frequencies of n^2 doubles and at most
#: this many bytes (``passivity.CHUNK_BYTES``), plus two n^2 doubles of the eigenvalue solver
PASSIVITY_FREQS, PASSIVITY_BYTES = 64, 256 * 2 ** 20


def streamed_fit_memory(n_dof: int, n_freq: int, max_poles: int, block: int | None = None) -> dict[str, int]:
    """Estimated peak bytes of the streamed fit (``fit.streamed.StreamedProblem``) of a table of
    ``n_freq`` (n_dof, n_dof) complex matrices on disk with at most ``max_poles`` poles, by item
    (and ``"total"``); the table is not held (it is read in blocks) and the interpreter is not counted.

    Items: ``blocks`` ``STREAM_BLOCKS`` x 16 n_freq edge^2 (edge: ``block`` or the file's chunk
    edge, ``blocked.chunk_edge``); ``problem`` ``PROBLEM_COPIES`` x 16 n^2; ``search``
    the larger of the order search's E of every order (one per pole pair, n^2 doubles each, and
    ``SEARCH_WORK`` n^2 doubles beside them: ``fit.streamed.StreamedProblem.search_orders``) and
    ``SEARCH_COPIES`` orders' coefficients of at most max_poles poles, (m + 2) n^2 doubles each (the
    order the enforcement fits again from its poles: ``fit.search.OrderSearch.coefficients``); ``models`` ``MODEL_COPIES`` models of max_poles poles and
    ``ENFORCE_COPIES`` coefficient arrays of the enforcement; ``passivity`` the certified sweep's
    G(nu) block (``PASSIVITY_FREQS`` n^2 doubles, at most ``PASSIVITY_BYTES``) and the eigenvalue
    solver's two n^2.

    Measured peaks over what the process held before the fit (``benchmarks/growth.py --fit streamed``,
    the mat's soil at 8 frequencies; ``benchmarks/fit_memory.py`` at 21, ru_maxrss of the process,
    the interpreter's ``BASE_BYTES`` added to the estimate), estimate at the order reached / measured:
    262 DOFs 5 poles 0.075 / 0.097 GiB, 631 DOFs 6 poles 0.47 / 0.57 GiB, 1207 DOFs 6 poles
    (21 frequencies) 1.46 / 1.32 GiB.
    """
    n2 = n_dof * n_dof
    edge = int(block or chunk_edge(n_dof))
    m = int(max_poles)
    pairs = max(1, m // 2)
    items = {"blocks": STREAM_BLOCKS * 16 * n_freq * edge * edge,
             "problem": PROBLEM_COPIES * 16 * n2,
             "search": 8 * max(SEARCH_COPIES * (2 * pairs + 2), pairs + SEARCH_WORK) * n2,
             "models": (MODEL_COPIES * (8 * (m + 2) + 16 * m) + ENFORCE_COPIES * 8 * (m + 2)) * n2,
             "passivity": min(PASSIVITY_FREQS * 8 * n2, PASSIVITY_BYTES) + 2 * 8 * n2}
    items["total"] = sum(items.values())
    return items
