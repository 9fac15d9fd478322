"""The rigid-raft impedance of a gap table: its projection Pᵀ K P, its errors, its protection
during passivity enforcement and the correction of a fitted model so that it follows the
table's (docs/formulation.md, "Rational soil model")."""
from __future__ import annotations

import numpy as np

from ..rational import FitError, RationalModel
from ..vectfit import real_basis
from .options import RIGID, RIGID_IM_FLOOR


def rigid_projection(table, node_xy=None):
    """P, shape (6+N, 6), of a "gap" table (DOFs RIGID + w_1..w_N), or None for other tables.

    With the raft bonded to the soil, w_i = uz + rx y_i − ry x_i (``reduction.rigid_transform``),
    so the rigid-raft impedance in full contact is Pᵀ K_gap P with P = [I6; T_v]
    (``reduction.condense_gap_rigid``). node_xy : (N, 2) node coordinates about the raft centre;
    default: the table's mesh rebuilt from its provenance (circle and square-cell rectangle meshes,
    checked against the recorded mesh digest). FitError when they are needed and unknown.
    """
    dofs = list(table.dofs)
    n = len(dofs) - len(RIGID)
    if n <= 0 or tuple(dofs[:6]) != RIGID or dofs[6:] != [f"w{i}" for i in range(n)]:
        return None
    if node_xy is None:
        node_xy = _provenance_nodes(table.provenance)
        if node_xy is None:
            raise FitError("the rigid-raft correction needs the interface node coordinates, which the "
                           "table's provenance does not rebuild: pass node_xy=mesh.xy (shape (N, 2)) or "
                           "rigid_correction=False")
    xy = np.asarray(node_xy, float)
    if xy.shape != (n, 2) or not np.all(np.isfinite(xy)):
        raise FitError(f"node_xy must be finite (N, 2) = ({n}, 2) node coordinates for this gap table, "
                       f"got shape {xy.shape}")
    Tv = np.zeros((n, 6))
    Tv[:, 2], Tv[:, 3], Tv[:, 4] = 1.0, xy[:, 1], -xy[:, 0]      # as reduction.rigid_transform
    return np.vstack([np.eye(6), Tv])


def _provenance_nodes(prov):
    """Node coordinates of the mesh recorded in a sweep's provenance, or None."""
    from ..mesh import MeshError, circle_mesh, rectangle_mesh
    from ..sweep import _mesh_dict
    m = prov.get("mesh") or {}
    try:
        if m.get("kind") == "circle":
            mesh = circle_mesh(m["size"][0], m["cell"])
        elif m.get("kind") == "rectangle" and m.get("cell"):
            mesh = rectangle_mesh(*m["size"], m["cell"])
        else:
            return None
    except (KeyError, TypeError, IndexError, MeshError):
        return None
    return mesh.xy if _mesh_dict(mesh) == m else None


def rigid_model(model, P) -> RationalModel:
    """The rigid-raft impedance Pᵀ K(s) P of ``model`` as a 6×6 RationalModel (same poles): cheap to
    evaluate, unlike the (6+N)² model."""
    return RationalModel(model.poles, P.T @ model.residues @ P, P.T @ model.D @ P, P.T @ model.E @ P,
                         list(RIGID))


def rigid_errors(model, target, freq_hz, P, band, Kt=None):
    """Per rigid DOF d, max over ``band`` (bool mask of freq_hz) of the relative errors of the
    rigid-raft impedance Pᵀ K P, model against target (F, n, n): {d: {"re", "im", "abs"}} with
    re = |ΔRe K_dd|/|Re K_dd|, im = |ΔIm K_dd|/max(|Im K_dd|, RIGID_IM_FLOOR·|K_dd|),
    abs = |ΔK_dd|/|K_dd|.
    The floor (1 % of |K_dd|) keeps the Im measure finite where the target is undamped (Im K(0) = 0)
    and does not ask for the relative accuracy of a negligible damping: a loss factor Im K/|K| below
    1 % (soil damping ratio < 0.5 %, e.g. the rocking radiation damping of an undamped soil at low
    frequency, 0.1 % at a0 = 0.25) weighs nothing beside the structure's 5-7 %; a causal 3 % rock
    has Im K/|K| ≥ 6 % at every f > 0, where the floor never acts.
    Kt : Pᵀ target[band] P (F_band, 6, 6) when the caller has it (a table read in blocks), else None."""
    if Kt is None:
        Kt = P.T @ target[band] @ P
    Km = rigid_model(model, P).frequency_response(np.asarray(freq_hz)[band])
    dt, dm = np.einsum("faa->fa", Kt), np.einsum("faa->fa", Km)
    out = {}
    for k, name in enumerate(RIGID):
        t, m = dt[:, k], dm[:, k]
        im_ref = np.maximum(np.abs(t.imag), RIGID_IM_FLOOR * np.abs(t))
        out[name] = {"re": float(np.max(np.abs(m.real - t.real) / np.abs(t.real))),
                     "im": float(np.max(np.abs(m.imag - t.imag) / im_ref)),
                     "abs": float(np.max(np.abs(m - t) / np.abs(t)))}
    return out


def rigid_protection(prob, P) -> np.ndarray:
    """``enforce_passivity``'s ``protect`` for a gap table: P with column d scaled by √(κ/ref_d),
    κ = max_f ‖S K_target S‖_F (the scale of the relative Frobenius measure the enforcement minimises)
    and ref_d = RIGID_IM_FLOOR · min over the band of |(Pᵀ K P)_dd| (the smallest error scale of
    ``rigid_errors``), so that a change of the rigid-raft impedance costs about as much as its
    relative error in the order-selection criterion."""
    if getattr(prob, "streamed", False):                  # Pᵀ K P taken in the problem's first pass
        ref = RIGID_IM_FLOOR * np.abs(np.einsum("faa->fa", prob.rigid_raw[prob.band])).min(axis=0)
    else:
        KP = prob.table.matrices[prob.band] @ P
        ref = RIGID_IM_FLOOR * np.abs(np.einsum("ia,fia->fa", P, KP)).min(axis=0)
    kappa = 1.0 / prob.w_rel.min()
    return P * np.sqrt(np.divide(kappa, ref, out=np.ones_like(ref), where=ref > 0))[None, :]


def rigid_error(errors) -> float:
    """The order-selection measure of ``rigid_errors``' output: max over rigid DOFs of the Re and Im errors."""
    return max((max(e["re"], e["im"]) for e in errors.values()), default=0.0)


def rigid_correct(model, target, freq_hz, P, floor=0.02, f_c=0.0, Kt=None) -> RationalModel:
    """``model`` + Q Δ(s) Qᵀ: the rigid-raft impedance Pᵀ K P corrected to follow the target's.

    Δ(s) = D_Δ + Σ_k R_Δk/(s − p_k) (the model's poles, no s term so E is untouched, symmetric
    residues, conjugate pairs) fits the 6×6 residual Pᵀ (K_target − K_model) P by weighted linear
    least squares, one per upper-triangle entry (i, j), with Re and Im weighted separately relative
    to the target: 1/max(|Re K_ij|, ε) and 1/max(|Im K_ij|, ε), ε = ``floor``·√(|K_ii K_jj|), so
    that the small imaginary parts (rocking damping at low a0) count as much as the stiffnesses.
    Q = P_a (P_aᵀ P_a)⁻¹ on the model's active DOFs (zero rows stay zero): Pᵀ Q = I, hence
    Pᵀ (Q Δ Qᵀ) P = Δ exactly; the rank-6 change of the w block is smooth (linear in x, y).
    target : (F, n, n) complex, the (causal) target at ``freq_hz``. f_c : below it (where the
    target's Im K is the faded hysteretic one) Im K is weighted like Re K, relative to |K_ij|.
    Weights with a zero denominator (an entry identically zero) are dropped.
    Kt : Pᵀ target P (F, 6, 6) when the caller has it (a table read in blocks; target is then unused).
    """
    f = np.asarray(freq_hz, float)
    w_ref = 2 * np.pi * float(model.provenance.get("f_max_hz") or f[-1])
    if Kt is None:
        Kt = P.T @ target @ P
    Delta = Kt - rigid_model(model, P).frequency_response(f)
    A = real_basis(2j * np.pi * f / w_ref, model.poles / w_ref, const=True, linear=False)
    diag = np.abs(np.einsum("faa->fa", Kt))
    m = model.order
    Cd = np.zeros((m + 1, 6, 6))
    for i, j in zip(*np.triu_indices(6)):
        eps = floor * np.sqrt(diag[:, i] * diag[:, j])
        if not np.any(eps > 0):
            continue
        dr = np.maximum(np.abs(Kt[:, i, j].real), eps)
        di = np.maximum(np.abs(Kt[:, i, j].imag), np.where(f >= f_c, eps, np.maximum(np.abs(Kt[:, i, j]), eps)))
        wr = np.divide(1.0, dr, out=np.zeros_like(dr), where=dr > 0)
        wi = np.divide(1.0, di, out=np.zeros_like(di), where=di > 0)
        M = np.concatenate([wr[:, None] * A.real, wi[:, None] * A.imag])
        rhs = np.concatenate([wr * Delta[:, i, j].real, wi * Delta[:, i, j].imag])
        col = np.linalg.norm(M, axis=0)
        col[col == 0] = 1.0
        Cd[:, i, j] = Cd[:, j, i] = np.linalg.lstsq(M / col, rhs, rcond=None)[0] / col
    Cd[:m] *= w_ref                                   # basis 1/(ν − p/ω_ref) = ω_ref/(s − p)
    C = np.array(model.coefficients)
    active = np.max(np.abs(C), axis=(0, 2)) > 0
    Pa = P * active[:, None]
    Q = Pa @ np.linalg.inv(Pa.T @ Pa)
    C[:m + 1] += Q[None] @ Cd @ Q.T[None]
    C = 0.5 * (C + C.transpose(0, 2, 1))
    return RationalModel.from_coefficients(model.poles, C, model.dofs, dict(model.provenance, rigid_corrected=True))
