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
"""
from __future__ import annotations

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
