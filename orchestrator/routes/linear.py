"""``linear``: the BEM table per frequency, raft bonded (no uplift): the exact linear
reference. The scene's gap table, motion, contact penalty and output nodes handed to
``orchestrator.timefreq.linear_fd``.

API::

    from orchestrator.routes.linear import run_linear
    res = run_linear(motion, model, table_gap, contact=contact, output_nodes=nodes)
"""
from __future__ import annotations

from orchestrator.routes.base import Route, register, route_model
from soil_impedance.blocked import in_memory

#: keyword overrides that are not GridOptions fields
LINEAR_KEYWORDS = ("damping", "threads", "route")


def run_linear(motion, model, table_gap, *, contact, output_nodes, **overrides):
    """RouteResult of ``linear_fd`` on the BEM gap table ``table_gap`` (ImpedanceTable, 6+N)
    for ``motion`` (orchestrator.motion.Motion: acc (nt, 3) m/s^2, dt s), the structure
    ``model``, the ContactSettings ``contact`` (its penalty; contact disabled) and the output
    node names. overrides : fields of GridOptions (pad_s, wrap_tol, bilinear, nfft, window),
    and damping, threads, route.
    """
    # the solver's imports (pyfftw, scipy.interpolate: ~0.7 s) when the route runs, not with the registry
    from orchestrator.timefreq import GridOptions, linear_fd, with_overrides

    grid, rest = with_overrides(overrides, GridOptions())
    unknown = sorted(set(rest) - set(LINEAR_KEYWORDS))
    if unknown:
        raise ValueError(f"run_linear: unknown option {unknown[0]!r}; options: GridOptions fields or "
                         f"{', '.join(LINEAR_KEYWORDS)}")
    return linear_fd(model, table_gap, motion.acc, motion.dt, contact=contact, output_nodes=output_nodes,
                     grid=grid, **rest)


def run(ctx, progress=None):
    return run_linear(ctx.motion, route_model(ctx), in_memory(ctx.tables["gap"]), contact=ctx.scene.contact,
                      output_nodes=ctx.scene.output.nodes, **ctx.options)


ROUTE = register(Route(
    name="linear",
    summary="linear FD: the BEM impedance table applied per frequency, raft bonded (no uplift): the exact "
            "linear reference, drawn dashed as 'no uplift' on the other figures",
    run=run,
    options=("pad_s",),
    time_stepped=False,
    bench={"disk-halfspace": {"pad_s": (0.25, 1.0, 4.0), "element_size": (3.0, 2.0, 1.5)},
           "reactor": {"pad_s": (0.25, 1.0, 4.0), "element_size": (4.0, 3.0, 2.28)}},
    quick={"disk-halfspace": {"pad_s": (0.25, 1.0)}},
    uplift=False,
))
