"""Fixed-base modes and structural damping matrices.

Fixed base = raft master node clamped. Massless DOFs (e.g. beam-node rotations without
rotary inertia) are condensed statically, which is exact for the eigenproblem.

Modal damping: C_fb = M Phi diag(2 xi w) Phi^T M over all fixed-base modes (Phi
mass-normalised), so each fixed-base mode has damping ratio xi. It is applied to the
deformation relative to the raft, u_rel = u - T q, i.e. C = L^T C_fb L with L = [I, -T]:
rigid-body motion of the whole building on the soil is not damped by the structure
(soil damping comes from the soil model only). Rayleigh is applied the same way:
C_fb = a0 M_fb + a1 K_fb.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from uplift_common.lazy import lazy_module

from .errors import StructureError
from .model import StructureModel

# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sla = lazy_module("scipy.linalg")


@dataclass(frozen=True, eq=False)
class Modes:
    """Fixed-base modes: freq (m,) Hz, omega (m,) rad/s, shapes (n_struct, m) mass-normalised
    (zero on the raft DOFs), participation (m, 3) modal participation factors."""
    freq: np.ndarray
    omega: np.ndarray
    shapes: np.ndarray
    participation: np.ndarray


def _split(model: StructureModel):
    n_i = model.n_struct - 6
    K = model.stiffness.toarray()[:n_i, :n_i]
    m = model.mass[:n_i]
    massive = np.flatnonzero(m > 0)
    massless = np.flatnonzero(m <= 0)
    return K, m, massive, massless


def fixed_base_modes(model: StructureModel) -> Modes:
    """All fixed-base modes of the structure (raft master clamped)."""
    K, m, a, z = _split(model)
    if a.size == 0:
        raise StructureError("the structure has no mass above the raft: give masses or beam rho")
    Kaa = K[np.ix_(a, a)]
    if z.size:
        Kzz = K[np.ix_(z, z)]
        Kza = K[np.ix_(z, a)]
        try:
            X = -np.linalg.solve(Kzz, Kza)
        except np.linalg.LinAlgError as exc:
            raise StructureError("the fixed-base structure is a mechanism (massless DOFs without "
                                 "stiffness): check beam connectivity and rotation restraints") from exc
        Kaa = Kaa + K[np.ix_(a, z)] @ X
    w2, phi = sla.eigh(0.5 * (Kaa + Kaa.T), np.diag(m[a]))
    if w2[0] <= 0:
        raise StructureError("the fixed-base structure has a zero-frequency mode: a node is not "
                             "connected to the raft by beams or springs")
    omega = np.sqrt(w2)
    shapes = np.zeros((model.n_struct, a.size))
    shapes[a] = phi
    if z.size:
        shapes[z] = X @ phi
    r = model.influence[a]
    part = phi.T @ (m[a, None] * r)
    return Modes(omega / (2 * np.pi), omega, shapes, part)


def _relative_map(model: StructureModel) -> np.ndarray:
    """L (n_i, n_struct): u_rel = u_I - T_I q."""
    n_i = model.n_struct - 6
    L = np.zeros((n_i, model.n_struct))
    L[:, :n_i] = np.eye(n_i)
    L[:, n_i:] = -model.rigid_transform[:n_i]
    return L


def modal_damping_fixed_base(model: StructureModel, ratio, modes: Modes | None = None) -> np.ndarray:
    """C_fb (n_i, n_i) giving damping ratio ``ratio`` (scalar or (m,)) to every fixed-base mode."""
    modes = modes or fixed_base_modes(model)
    n_i = model.n_struct - 6
    m = model.mass[:n_i]
    phi = modes.shapes[:n_i]
    xi = np.broadcast_to(np.asarray(ratio, float), modes.omega.shape)
    Mphi = m[:, None] * phi
    return (Mphi * (2 * xi * modes.omega)) @ Mphi.T


def damping_matrix(model: StructureModel, damping=None) -> np.ndarray:
    """Structural damping matrix C (n_struct, n_struct), dense, acting on deformations
    relative to the raft. ``damping``: None -> model.damping; a Damping; or a float (modal
    ratio); or an explicit (n_struct, n_struct) array, returned as is."""
    from .model import Damping
    d = model.damping if damping is None else damping
    if isinstance(d, (int, float)):
        d = Damping("modal", ratio=float(d))
    if isinstance(d, np.ndarray):
        if d.shape != (model.n_struct, model.n_struct):
            raise StructureError(f"damping matrix must have shape {(model.n_struct,) * 2}, got {d.shape}")
        return d
    n_i = model.n_struct - 6
    if d.kind == "none":
        return np.zeros((model.n_struct, model.n_struct))
    if d.kind == "modal":
        Cfb = modal_damping_fixed_base(model, d.ratio)
    elif d.kind == "rayleigh":
        Cfb = d.a0 * np.diag(model.mass[:n_i]) + d.a1 * model.stiffness.toarray()[:n_i, :n_i]
    else:
        raise StructureError(f"unknown damping kind {d.kind!r}: use 'modal', 'rayleigh' or 'none'")
    L = _relative_map(model)
    return L.T @ Cfb @ L
