"""Benchmark: reactor stick model on a Winkler mattress with uplift, 10 s at dt = 5 ms.

Soil: rock E = 15 GPa, nu = 0.3, rho = 2500 kg/m^3; rigid-disk static springs (R = 20 m)
shared by tributary area over circle_mesh(20, 2.28) (241 nodes). Damping as in the paper
(§4.2): RCC-G composite modal damping (7 % structure, disk radiation ratios per direction
weighted by soil strain energy), no dashpots; ``--dashpots`` uses rho Vp A_i, rho Vs A_i
dashpots with 7 % fixed-base modal damping instead. Motion: seeded broadband accelerogram (structure.broadband), 0.25 g along x.
Prints a table: wall time, Newton solves per step, factorisations, uplift; the same with
contact disabled (linear, one factorisation). Budget: < 5 s on 2 cores.

    python benchmarks/structure_step.py [--pga 0.25] [--seed 1] [--opensees]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from soil_impedance.mesh import circle_mesh
from structure import G_ACC, ContactSettings, WinklerSoil, simulate
from structure.broadband import broadband_accelerogram
from structure.spec import model_from_spec
from structure.winkler import (dashpots_from_waves, disk_radiation_ratios, disk_static_stiffness,
                               rccg_modal_damping, springs_from_rigid_impedance)


def setup(pga_g: float, seed: int, duration=10.0, dt=0.005, dashpots=False):
    """(model, soil, ag (nt, 3), dt, damping) for the reactor benchmark."""
    mesh = circle_mesh(20.0, 2.28)
    E, nu, rho = 15e9, 0.3, 2500.0
    G = E / (2 * (1 + nu))
    vs = np.sqrt(G / rho)
    vp = vs * np.sqrt((2 - 2 * nu) / (1 - 2 * nu))
    model = model_from_spec({"model": "reactor"}, mesh.xy, mesh.area)
    springs = springs_from_rigid_impedance(disk_static_stiffness(G, nu, 20.0), mesh.xy, mesh.area,
                                           match="rocking")
    if dashpots:
        cv, ch = dashpots_from_waves(mesh.area, rho, vp, vs)
        soil = WinklerSoil(mesh.xy, springs.kv, springs.kx, cv, ch)
        damping = None
    else:
        soil = springs
        damping, _ = rccg_modal_damping(model, soil, 0.07,
                                        radiation=lambda f: disk_radiation_ratios(f, 20.0, vs))
    ag = np.zeros((int(round(duration / dt)) + 1, 3))
    ag[:, 0] = broadband_accelerogram(duration, dt, pga_g * G_ACC, seed=seed)
    return model, soil, ag, dt, damping


def run_opensees(model, soil, kp, ag, dt, a1):
    """The same model in OpenSeesPy: elasticTimoshenkoBeam sticks, rigid links to the 241 raft
    points, ENT (no-tension) penalty springs kp in series with Winkler springs kv (dashpots
    cv), horizontal springs kh (ch) on the raft points, gravity first (static, Newton), then
    Newmark average acceleration with Newton; structural damping C = a1 K_beams (region
    Rayleigh). Returns (wall s of the transient, raft ry (nt,), gap (nt, N))."""
    import openseespy.opensees as ops
    ops.wipe()
    ops.model("basic", "-ndm", 3, "-ndf", 6)
    for n in model.nodes:
        ops.node(n.id, *map(float, n.xyz))
    ops.geomTransf("Linear", 1, -1.0, 0.0, 0.0)
    rigid_shear = 1e6     # no shear area given: our beams have no shear deformation (Euler-Bernoulli)
    for k, b in enumerate(model.beams):
        ops.element("elasticTimoshenkoBeam", 1 + k, *b.nodes, b.E, b.G, b.A, b.J, b.Iy, b.Iz,
                    b.Asz or rigid_shear * b.A, b.Asy or rigid_shear * b.A, 1)
    m = model.mass
    for n in model.nodes:
        d = model.dofs(n.id)
        if np.any(m[d] > 0):
            ops.mass(n.id, *map(float, m[d]))
    N = model.n_interface
    rid = model.raft.node
    base = 100000
    mat = 1
    for i, (x, y) in enumerate(model.raft.xy):
        p, s, g = base + i, 2 * base + i, 3 * base + i
        ops.node(p, float(x), float(y), 0.0)
        ops.node(s, float(x), float(y), 0.0)
        ops.node(g, float(x), float(y), 0.0)
        ops.fix(g, 1, 1, 1, 1, 1, 1)
        ops.fix(s, 1, 1, 0, 1, 1, 1)
        ops.rigidLink("beam", rid, p)
        ops.uniaxialMaterial("ENT", mat, float(kp[i]))
        ops.uniaxialMaterial("Elastic", mat + 1, float(soil.kv[i]), float(soil.cv[i]))
        ops.uniaxialMaterial("Elastic", mat + 2, float(soil.kx[i]), float(soil.cx[i]))
        ops.element("zeroLength", 10 * base + i, s, p, "-mat", mat, "-dir", 3)
        ops.element("zeroLength", 11 * base + i, g, s, "-mat", mat + 1, "-dir", 3)
        ops.element("zeroLength", 12 * base + i, g, p, "-mat", mat + 2, mat + 2, "-dir", 1, 2)
        mat += 3
    ops.region(1, "-eleRange", 1, len(model.beams), "-rayleigh", 0.0, 0.0, a1, 0.0)
    ops.timeSeries("Linear", 1)
    ops.pattern("Plain", 1, 1)
    for n in model.nodes:
        mz = m[model.dofs(n.id)[2]]
        if mz > 0:
            ops.load(n.id, 0.0, 0.0, -G_ACC * float(mz), 0.0, 0.0, 0.0)
    ops.constraints("Transformation")
    ops.numberer("RCM")
    ops.system("UmfPack")
    ops.test("NormDispIncr", 1e-10, 50)
    ops.algorithm("Newton")
    ops.integrator("LoadControl", 1.0)
    ops.analysis("Static")
    ops.analyze(1)
    ops.loadConst("-time", 0.0)
    ry_static = ops.nodeDisp(rid, 5)
    ops.timeSeries("Path", 2, "-dt", dt, "-values", *map(float, ag[:, 0]))
    ops.pattern("UniformExcitation", 2, 1, "-accel", 2)
    ops.wipeAnalysis()
    ops.constraints("Transformation")
    ops.numberer("RCM")
    ops.system("UmfPack")
    ops.test("NormDispIncr", 1e-10, 50)
    ops.algorithm("Newton")
    ops.integrator("Newmark", 0.5, 0.25)
    ops.analysis("Transient")
    nt = ag.shape[0]
    ry = np.zeros(nt)
    gap = np.zeros((nt, N))
    t0 = time.perf_counter()
    t_extract = 0.0
    for k in range(1, nt):
        if ops.analyze(1, dt) != 0:
            raise RuntimeError(f"OpenSees failed at step {k}")
        t1 = time.perf_counter()
        ry[k] = ops.nodeDisp(rid, 5) - ry_static
        d = np.array([ops.nodeDisp(base + i, 3) - ops.nodeDisp(2 * base + i, 3) for i in range(N)])
        gap[k] = np.maximum(0.0, d)           # zeroLength deformation > 0: open (total)
        t_extract += time.perf_counter() - t1
    wall = time.perf_counter() - t0 - t_extract
    ops.wipe()
    return wall, ry, gap


def opensees_comparison(pga_g, seed):
    """Side-by-side with OpenSeesPy on the dashpot variant (damping that both codes can
    express: C = a1 K_beams, 7 % at the 8 Hz first fixed-base mode)."""
    from structure import Damping
    from structure.damping import fixed_base_modes
    model, soil, ag, dt, _ = setup(pga_g, seed, dashpots=True)
    f1 = fixed_base_modes(model).freq[0]
    a1 = 2 * 0.07 / (2 * np.pi * f1)
    r = simulate(model, soil, ag, dt, damping=Damping("rayleigh", a1=a1))
    try:
        w_os, ry_os, gap_os = run_opensees(model, soil, r.info["penalty"], ag, dt, a1)
    except ImportError:
        print("openseespy is not installed (pip install openseespy; apt-get install -y libblas3 liblapack3)")
        return
    ry = r.raft[:, 4]
    print(f"\nOpenSeesPy side by side (dashpot soil, C = a1 K_beams, a1 = {a1:.3g} s):")
    print(f"{'code':>12} | {'wall s':>8} | {'max ry mrad':>11} | {'max uplift mm':>13} | {'lifted frac':>11}")
    print(f"{'uplift':>12} | {r.wall_s:8.3f} | {1e3*np.abs(ry).max():11.5f} | {1e3*r.max_uplift():13.5f} | {r.uplift_fraction().max():11.3f}")
    print(f"{'OpenSeesPy':>12} | {w_os:8.3f} | {1e3*np.abs(ry_os).max():11.5f} | {1e3*gap_os.max():13.5f} | {(gap_os > 0).mean(axis=1).max():11.3f}")
    print(f"run-time ratio OpenSeesPy / uplift: {w_os / r.wall_s:.2f}")
    print(f"largest difference in raft rotation: {np.abs(ry - ry_os).max():.3e} rad "
          f"({np.abs(ry - ry_os).max() / np.abs(ry_os).max():.2%} of peak)")
    print(f"largest difference in uplift: {np.abs(r.gap - gap_os).max():.3e} m "
          f"({np.abs(r.gap - gap_os).max() / max(gap_os.max(), 1e-30):.2%} of peak)")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pga", type=float, default=0.25, help="peak ground acceleration, g")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--dashpots", action="store_true", help="dashpots instead of RCC-G damping")
    p.add_argument("--opensees", action="store_true", help="also run OpenSeesPy (if installed)")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    model, soil, ag, dt, damping = setup(a.pga, a.seed, dashpots=a.dashpots)
    t_setup = time.perf_counter() - t0
    rows = []
    for label, contact in (("uplift", ContactSettings()), ("linear", ContactSettings(enabled=False))):
        r = simulate(model, soil, ag, dt, contact=contact, damping=damping)
        it = r.newton_iters[1:]
        rows.append((label, r.wall_s, r.nt - 1, it.mean(), it.max(), r.info["factorisations"],
                     1e3 * r.max_uplift(), r.uplift_fraction().max(),
                     1e3 * np.abs(r.raft[:, 4]).max(), np.abs(r.acc["top_outer"][:, 0]).max()))
    print(f"reactor on Winkler, {model.n_dof} DOFs ({model.n_interface} interface nodes), "
          f"{ag.shape[0] - 1} steps of {dt*1e3:g} ms, PGA {a.pga} g, seed {a.seed}")
    hdr = ("run", "wall s", "steps", "solves/step", "max solves", "LU", "max uplift mm",
           "lifted frac", "max ry mrad", "top acc m/s2")
    print(" | ".join(f"{h:>12}" for h in hdr))
    for row in rows:
        print(" | ".join(f"{v:>12.4g}" if not isinstance(v, str) else f"{v:>12}" for v in row))
    print(f"real-time factor (uplift): {rows[0][1] / (dt * (ag.shape[0] - 1)):.3f}; "
          f"setup (model, modes, RCC-G damping): {t_setup:.2f} s")
    if a.opensees:
        opensees_comparison(a.pga, a.seed)


if __name__ == "__main__":
    main()
