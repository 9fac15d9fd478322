"""The ``simulate`` driver: a time history of a structure on a soil under a ground motion,
recorded into one RouteResult.

It decides how to run (the closed-contact linear march when nothing can open, else the
stepper step by step), records the stepper's outputs and energies, and freezes the records
into a RouteResult. It uses the stepper's public interface only (``step()``,
``march_closed``, ``closed_histories``, its state and outputs).
"""
from __future__ import annotations

import time as _time
from types import SimpleNamespace

import numpy as np

from uplift_common.blas import single_threaded_blas
from .contact import ContactSettings
from .errors import ConvergenceError, StructureError
from .model import StructureModel
from .newmark import ENERGY_TERMS, NewmarkStepper
from .plate_raft import PlateRaftModel, PlateStepper, raft_point_operators
from .preload import StaticState
from .results import RouteResult, RunNotes, Status


def simulate(model: StructureModel, soil, ag, dt: float, contact: ContactSettings | None = None,
             damping=None, alpha: float = 0.0, output_nodes=None, progress=None,
             route: str = "newmark", static: StaticState | None = None, raft_points=None) -> RouteResult:
    """Time history of the structure on ``soil`` under ground acceleration ``ag``.

    model : StructureModel (a rigid raft, NewmarkStepper) or PlateRaftModel (a plate raft,
    PlateStepper; the result then carries the plate's deflections, its moments at the stick base
    and their peaks over the plate, which vertices are held).

    ag : (nt, 3) m/s^2 at t_k = k dt (x, y, z); output_nodes : node names (default: all
    named nodes); raft_points : {name: (x, y) m} points of a plate raft whose absolute
    acceleration and displacement join ``acc`` and ``disp`` under that name (the nearest plate
    vertex: its deflection and the raft's in-plane rigid motion; ``info["raft_points"]`` gives the
    vertex and its coordinates; a rigid raft raises StructureError); progress : callable(done,
    total) or None, called as the run goes with
    done = k + 1 of total = nt samples. Returns a RouteResult; on a Newton failure raises
    ConvergenceError with ``.result`` holding the samples computed so far.

    What is skipped (``info["skipped"]``, ``info["precheck"]``): with the contact disabled,
    or enabled with ``contact.precheck`` and the raft in full contact at rest, the run is the
    closed-contact linear recursion (``NewmarkStepper.march_closed``: one factorisation, one solve per
    step, outputs and energies computed at the end over the whole history). With the contact
    enabled that run stops at the first step where a node would go into tension (the gap
    opens), the soil is rolled back and the nonlinear stepper runs from t = 0, so a run with
    uplift is exactly what ``precheck=False`` gives. Without tension the closed solution is
    the unilateral one (the penalty law is linear while closed); it equals the Newton path to
    round-off amplified by the penalty's conditioning (~1e-10 relative, as between any two
    linear solvers of this system).
    """
    with single_threaded_blas():
        return _simulate(model, soil, ag, dt, contact, damping, alpha, output_nodes, progress,
                         route, static, raft_points)


def _simulate(model, soil, ag, dt, contact, damping, alpha, output_nodes, progress, route, static, raft_points):
    t0 = _time.perf_counter()
    ag = np.asarray(ag, float)
    if ag.ndim != 2 or ag.shape[1] != 3:
        raise StructureError(f"ground acceleration must have shape (nt, 3), got {ag.shape}")
    if not np.all(np.isfinite(ag)):
        raise StructureError("ground acceleration contains NaN or inf")
    plate = isinstance(model, PlateRaftModel)
    st = (PlateStepper if plate else NewmarkStepper)(model, soil, dt, contact=contact, damping=damping,
                                                      alpha=alpha, static=static, ag0=ag[0])
    names = [n.name for n in model.nodes if n.name] if output_nodes is None else list(output_nodes)
    dofs = {nm: model.dofs(model.node_by_name(nm).id)[:3] for nm in names}
    points, points_info = raft_point_operators(model, raft_points, names)
    nt, N = ag.shape[0], model.n_interface
    res = SimpleNamespace(      # history buffers, filled in place, frozen into a RouteResult at the end
        raft=np.zeros((nt, 6)), gap=np.zeros((nt, N)), contact_force=np.zeros((nt, N)), soil_w=np.zeros((nt, N)),
        acc={nm: np.zeros((nt, 3)) for nm in [*names, *points]}, disp={nm: np.zeros((nt, 3)) for nm in [*names, *points]},
        energy={k: np.zeros(nt) for k in ENERGY_TERMS},
        newton_iters=np.zeros(nt, int))
    if plate:
        res.plate_vertex_deflection = np.zeros((nt, model.n_vertices))
        res.plate_deflection = np.zeros((nt, N))
        res.plate_moment = np.zeros((nt, model.base_cells.size, 3))
        res.plate_moment_peak = np.zeros((N, 3))
    info = dict(settlement=st.static.settlement, P0=st.P0.copy(), penalty=st.kp.copy(),
                delta0=st.delta0.copy(), dt=dt, alpha=alpha, contact_enabled=st.contact.enabled)
    if points:
        info["raft_points"] = points_info
    skipped = []
    enabled = st.contact.enabled
    if not enabled:
        closed, note = True, "not needed: contact disabled (bonded raft, linear)"
    elif not st.contact.precheck:
        closed, note = False, "off (contact.precheck = false): nonlinear contact iterations forced"
    elif not np.all(st.P0 > 0):
        closed, note = False, (f"not run: {int(np.sum(st.P0 <= 0))} interface nodes are not in contact at "
                               "rest, the closed-contact problem is not the unilateral one")
    else:
        closed, note = True, ""
    if closed:
        soil0 = st.soil.get_state()
        out = st.march_closed(ag, enabled, progress)
        if isinstance(out, int):
            st.soil.set_state(soil0)
            closed = False
            note = f"tension at t = {out * dt:.6g} s (step {out}): the contact opens, nonlinear run from t = 0"
        elif not (np.isfinite(out[0][-1]).all() and np.isfinite(out[1][-1]).all()):
            # a linear recursion that overflows stays non-finite to the end
            st.soil.set_state(soil0)          # let the stepper report where it breaks down
            closed = False
            note = "the closed-contact run is not finite: nonlinear run from t = 0"
        else:
            vars(res).update(st.closed_histories(ag, *out, dofs))
            for nm, P in points.items():
                res.acc[nm] = (P @ out[0][:, 2].T).T + ag
                res.disp[nm] = (P @ out[0][:, 0].T).T
            note = note or "no tension: the closed-contact (linear) solution is the unilateral one"
            skipped.append(
                "contact disabled: one linear solve per step, no Newton" if not enabled else
                "no tension in the linear pre-check: nonlinear contact iterations skipped")
    failure, n_subdivided = (None, 0) if closed else _nonlinear(st, res, ag, dofs, progress, points)
    info.update(factorisations=st.n_factorisations, subdivided_steps=n_subdivided)
    out = RouteResult(route=route, time=dt * np.arange(nt), **vars(res), wall_s=_time.perf_counter() - t0,
                      xy=np.array(model.raft.xy), plate_vertices=np.array(model.points) if plate else None,
                      plate_moment_cells=model.base_cells.copy() if plate else None,
                      plate_vertex_held=model.slaved.copy() if plate else None,
                      notes=RunNotes(skipped=skipped, precheck=note), info=info)
    if failure is not None:
        exc, k = failure
        exc.result = out.truncated(k, Status.STOPPED, str(exc))
        raise exc
    return out


def _nonlinear(st: NewmarkStepper, res: SimpleNamespace, ag, dofs, progress, points=None):
    """The step-by-step run (Newton on the contact), recorded into the buffers ``res``.
    Returns (failure, subdivided steps): failure is None or (ConvergenceError, first step not
    computed)."""
    ni, nt = st.ni, ag.shape[0]

    def record(k):
        res.raft[k] = st.u[ni:ni + 6]
        res.gap[k] = st.gap()
        res.contact_force[k] = st.P
        res.soil_w[k] = st.u[st.ns:]
        for nm, d in dofs.items():
            res.acc[nm][k] = st.a[d] + st.ag
            res.disp[nm][k] = st.u[d]
        for key, val in st.energies().items():
            res.energy[key][k] = val
        for nm, P in (points or {}).items():
            res.acc[nm][k] = P @ st.a + st.ag
            res.disp[nm][k] = P @ st.u
        if hasattr(res, "plate_deflection"):
            res.plate_vertex_deflection[k], res.plate_deflection[k] = st.plate_deflections(st.u)
            Mk = st.plate_moments(st.u)
            res.plate_moment[k] = Mk[st.model.base_cells]
            np.maximum(res.plate_moment_peak, np.abs(Mk), out=res.plate_moment_peak)

    record(0)
    n_subdivided = 0
    for k in range(1, nt):
        st.set_ground_acceleration(ag[k])
        try:
            res.newton_iters[k] = st.step()
            n_subdivided += st.last_substeps > 1
        except ConvergenceError as exc:
            return (exc, k), n_subdivided
        record(k)
        if progress is not None:
            progress(k + 1, nt)
    return None, n_subdivided
