"""Static pushover of the scene's raft on its soil (``uplift pushover``; docs/pushover.md).

The raft carries the structure's weight (brought to the raft centre, plus an optional extra
vertical force) and is rocked by a prescribed rotation theta about the horizontal axis normal
to the chosen direction, in equal steps up to the maximum rotation; at each step the exact
unilateral static contact (``structure.static_contact``: active set, no penalty) gives the
moment, settlement, contact ratio, gaps and the contact-pressure map. The soil is the BEM's
static gap table (6 + N, ``scene_static(scene, "gap")``) or the winkler route's springs
(``routes.winkler.static_springs``), both at the moduli rho vs^2 (a causal soil's relaxed
K(0) times ``profile.static_to_reference``, as the winkler route calibrates its springs).

File layout (HDF5, netCDF4-like: dimension scales, CF units; atomic, checksummed)::

    /   attrs: uplift_file = "pushover", format_version = 1, Conventions, scene, created, soil,
               soil_label, direction_deg, weight_N, extra_vertical_N, vertical_N,
               stiffness_factor, contact, onset_* (rotation_rad, moment_Nm, eccentricity_m,
               node, nodes, at_rest), rocking_stiffness_Nm_per_rad, wall_s,
               provenance (JSON: scene sections, soil inputs, code digest), scene_key (what
               the curve depends on: orchestrator.oncurve.scene_key), raft_load (6,) N, N m: the
               loads on the raft, sha256
        step (step), node (node), dof (dof) coordinates; x, y, area (node)
        rotation, moment, eccentricity, settlement, contact_ratio, max_gap, iterations (step)
        force, pressure, gap (step, node)        raft_q (step, dof)
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from soil_impedance.sweep import CODE as SWEEP_CODE
from soil_impedance.sweep import provenance as sweep_provenance
from structure.static_contact import PushoverCurve, liftoff_onset, pushover, rocking_vector
from uplift_common.code import code_digest
from uplift_common.errors import UserInputError
from uplift_common.files import hdf5_output, require_checksum, save_figure, stamp_checksum

from orchestrator.impedance import scene_static
from orchestrator.oncurve import raft_load, scene_key
from orchestrator.routes.winkler import static_springs
from orchestrator.settings import compute_threads

KIND = "pushover"
FORMAT_VERSION = 1
SOILS = ("bem", "winkler")
#: the code a pushover file depends on (its digest is stored in the provenance)
CODE = ("structure.static_contact", "structure.winkler", "orchestrator.pushover", "orchestrator.routes.winkler",
        *SWEEP_CODE)
#: default maximum rotation, in multiples of the lift-off onset rotation (Winkler rectangle: a
#: contact ratio of 1/sqrt(20) = 22 % at the end)
DEFAULT_ONSET_MULTIPLE = 20.0
CONTACT = "exact unilateral contact by active set on the static problem (no penalty)"
STEP_VARIABLES = {"rotation": ("rad", "prescribed rocking rotation of the raft"),
                  "moment": ("N m", "overturning moment that holds the rotation (beyond the weight's own)"),
                  "eccentricity": ("m", "moment / total vertical load"),
                  "settlement": ("m", "vertical settlement of the raft centre, positive down"),
                  "contact_ratio": ("1", "area in contact / total area"),
                  "max_gap": ("m", "largest gap (edge uplift)"),
                  "iterations": (None, "active-set iterations of the step")}
NODE_VARIABLES = {"force": ("N", "contact force at the interface node, >= 0"),
                  "pressure": ("Pa", "contact pressure: force / tributary area"),
                  "gap": ("m", "gap between raft and soil at the interface node, >= 0")}


class PushoverError(UserInputError):
    """Pushover inputs that cannot go together (a soil the scene lacks, no vertical load, a bad
    direction), or a file that is not a pushover file."""


@dataclass(frozen=True, eq=False)
class PushoverRun:
    """A pushover of one scene: the curve and how it was made. direction_deg: the rocking
    direction (degrees from x towards y); weight_N the structure's weight, extra_vertical_N the
    extra downward force; stiffness_factor the factor applied to the BEM's static stiffness."""
    scene: str
    soil: str
    soil_label: str
    direction_deg: float
    curve: PushoverCurve
    weight_N: float
    extra_vertical_N: float
    stiffness_factor: float
    wall_s: float
    xy: np.ndarray
    area: np.ndarray
    provenance: dict = field(default_factory=dict)
    load: np.ndarray | None = None          # (6,) N, N m: the loads on the raft (raft_load + the extra force)
    scene_key: str = ""                     # orchestrator.oncurve.scene_key: what the curve depends on

    @property
    def eccentricity(self) -> np.ndarray:
        return self.curve.moment / self.curve.vertical


def parse_direction(text) -> float:
    """The rocking direction in degrees from x towards y: "x" (0), "y" (90) or a number of degrees."""
    if isinstance(text, (int, float)):
        value = float(text)
    elif str(text).strip().lower() in ("x", "y"):
        return 0.0 if str(text).strip().lower() == "x" else 90.0
    else:
        try:
            value = float(text)
        except ValueError:
            raise PushoverError(f"--direction {text!r}: give x, y or an angle in degrees from x towards y, "
                                "e.g. 45") from None
    if not math.isfinite(value):
        raise PushoverError(f"--direction {text!r} must be a finite angle in degrees")
    return value


def soil_stiffness(scene, soil: str, cache_dir=None):
    """(K (6+N, 6+N) real, label, stiffness factor) of the soil for ``soil`` "bem" | "winkler"."""
    if soil == "winkler":
        springs, label = static_springs(scene, cache_dir)
        return springs.static_stiffness().toarray(), f"winkler: {label}", 1.0
    if soil != "bem":
        raise PushoverError(f"--soil {soil!r}: choose one of {', '.join(SOILS)}")
    if scene.profile is None:
        raise PushoverError("--soil bem needs the BEM soil: the scene has no [soil] half-space (it gives "
                            "winkler moduli only); use --soil winkler or add soil.halfspace")
    factor = scene.profile.static_to_reference
    K = factor * np.real(scene_static(scene, "gap", cache_dir))
    return K, "bem: static gap table K(0) (6 + N), at the moduli rho vs^2", factor


def scene_pushover(scene, soil: str | None = None, direction="x", steps: int = 50, max_rotation: float | None = None,
                   vertical_load: float = 0.0, cache_dir=None, progress=None) -> PushoverRun:
    """The static pushover of the scene (see the module docstring). soil: "bem" (default when the
    scene has a half-space) or "winkler"; direction "x" | "y" | degrees; steps: the number of equal
    rotation steps (steps + 1 points from 0, and the onset rotation inserted when it lies
    between them); max_rotation rad (default: DEFAULT_ONSET_MULTIPLE
    times the lift-off onset rotation); vertical_load N, downward, added to the weight."""
    scene.check_rigid_raft("the static pushover")
    with compute_threads():          # small dense solves: threaded BLAS only slows them (orchestrator.settings)
        return _pushover(scene, soil, direction, steps, max_rotation, vertical_load, cache_dir, progress)


def _pushover(scene, soil, direction, steps, max_rotation, vertical_load, cache_dir, progress) -> PushoverRun:
    t0 = time.perf_counter()
    soil = soil or ("bem" if scene.profile is not None else "winkler")
    angle = parse_direction(direction)
    if not (isinstance(steps, int) and steps >= 1):
        raise PushoverError(f"--steps {steps!r} must be an integer >= 1")
    if max_rotation is not None and not (math.isfinite(max_rotation) and max_rotation > 0):
        raise PushoverError(f"--max-rotation {max_rotation!r} must be a rotation > 0 in rad, e.g. 0.002")
    load = np.zeros(6)
    weight = 0.0
    if scene.structure is not None:
        load = raft_load(scene.model())
        weight = -float(load[2])
    load[2] -= vertical_load
    if -load[2] <= 0:
        raise PushoverError("the raft carries no downward load: the scene has no [structure] (give "
                            "--vertical-load N)" if scene.structure is None else
                            f"the vertical load {-load[2]:.4g} N is not downward: check --vertical-load")
    K, label, factor = soil_stiffness(scene, soil, cache_dir)
    a = rocking_vector(math.radians(angle))
    xy, area = scene.mesh.xy, scene.mesh.area
    on = liftoff_onset(K, xy, load, a)
    if max_rotation is None:
        # lifted at rest: the rotation at which full contact would carry e = r/4 instead
        ref = on.rotation if not on.at_rest else -load[2] * math.sqrt(area.sum() / math.pi) / 4 / on.stiffness
        max_rotation = DEFAULT_ONSET_MULTIPLE * ref
    rotations = np.linspace(0.0, max_rotation, steps + 1)
    if not on.at_rest and 0 < on.rotation < max_rotation:       # the kink of the curve as one of its points
        rotations = np.insert(rotations, np.searchsorted(rotations, on.rotation), on.rotation)
    curve = pushover(K, xy, area, load, a, rotations, progress=progress, onset=on)
    prov = {"scene": scene.name, "soil": soil, "direction_deg": angle, "steps": steps,
            "max_rotation_rad": max_rotation, "vertical_load_N": vertical_load, "contact": CONTACT,
            "mesh": {"kind": scene.mesh.kind, "size": list(scene.mesh.size), "cell": scene.mesh.cell,
                     "n": scene.mesh.n},
            "structure": None if scene.structure is None else scene.structure.as_table(),
            "winkler": {"springs": scene.winkler.springs, "match": scene.winkler.match,
                        "moduli": None if scene.winkler.moduli is None else list(scene.winkler.moduli)},
            "bem": None if scene.profile is None else sweep_provenance(scene.profile, scene.mesh, scene.contact_kind,
                                                                       None, "gap"),
            "code_digest": code_digest(*CODE)[:12]}
    return PushoverRun(scene.name, soil, label, angle, curve, weight, float(vertical_load), factor,
                       time.perf_counter() - t0, np.asarray(xy, float), np.asarray(area, float), prov,
                       load=load.copy(), scene_key=scene_key(scene))


# ---- file ---------------------------------------------------------------------------------------

def _coordinate(f, name, values, units, long_name):
    values = np.asarray(values)
    if values.dtype.kind in "UO":
        values = np.array([str(v) for v in values], dtype=h5py.string_dtype())
    ds = f.create_dataset(name, data=values)
    ds.make_scale(name)
    if units is not None:
        ds.attrs["units"] = units
    ds.attrs["long_name"] = long_name


def _variable(f, name, data, dims, units, long_name):
    ds = f.create_dataset(name, data=np.asarray(data))
    for axis, dim in enumerate(dims):
        ds.dims[axis].attach_scale(f[dim])
    if units is not None:
        ds.attrs["units"] = units
    ds.attrs["long_name"] = long_name


def write_pushover(path, run: PushoverRun) -> Path:
    """Write the pushover to one HDF5 file (the module docstring's layout), atomically, checksummed."""
    c, on = run.curve, run.curve.onset
    with hdf5_output(path) as f:
        f.attrs.update(uplift_file=KIND, format_version=FORMAT_VERSION, Conventions="CF-1.8", scene=run.scene,
                       created=time.strftime("%Y-%m-%dT%H:%M:%S"), soil=run.soil, soil_label=run.soil_label,
                       direction_deg=run.direction_deg, weight_N=run.weight_N, extra_vertical_N=run.extra_vertical_N,
                       vertical_N=c.vertical, stiffness_factor=run.stiffness_factor, contact=CONTACT,
                       onset_rotation_rad=on.rotation, onset_moment_Nm=on.moment,
                       onset_eccentricity_m=on.eccentricity, onset_node=on.node, onset_nodes=np.array(on.nodes),
                       onset_at_rest=on.at_rest, rocking_stiffness_Nm_per_rad=on.stiffness, wall_s=run.wall_s,
                       provenance=json.dumps(run.provenance), scene_key=run.scene_key,
                       raft_load=np.zeros(6) if run.load is None else run.load)
        _coordinate(f, "step", np.arange(c.rotation.size), None, "pushover step")
        _coordinate(f, "node", np.arange(run.xy.shape[0]), None, "interface node index")
        _coordinate(f, "dof", ["ux", "uy", "uz", "rx", "ry", "rz"], None, "raft rigid-body DOF")
        _variable(f, "x", run.xy[:, 0], ("node",), "m", "node x about the raft centre")
        _variable(f, "y", run.xy[:, 1], ("node",), "m", "node y about the raft centre")
        _variable(f, "area", run.area, ("node",), "m2", "tributary area of the node")
        values = {"rotation": c.rotation, "moment": c.moment, "eccentricity": run.eccentricity,
                  "settlement": c.settlement, "contact_ratio": c.contact_ratio, "max_gap": c.max_gap,
                  "iterations": c.iterations}
        for name, (units, long_name) in STEP_VARIABLES.items():
            _variable(f, name, values[name], ("step",), units, long_name)
        for name, (units, long_name) in NODE_VARIABLES.items():
            _variable(f, name, getattr(c, name), ("step", "node"), units, long_name)
        _variable(f, "raft_q", c.q, ("step", "dof"), None, "raft displacements (m) and rotations (rad)")
        stamp_checksum(f)
    return Path(path)


def read_pushover(path) -> dict:
    """The arrays and attributes of a pushover file (checksum verified): {"attrs": {...}, name: array}."""
    path = Path(path)
    if not path.is_file():
        raise PushoverError(f"pushover file {str(path)!r} does not exist")
    with h5py.File(path, "r") as f:
        require_checksum(f, path)
        if f.attrs.get("uplift_file") != KIND:
            raise PushoverError(f"{path} is not a pushover file (uplift_file = {f.attrs.get('uplift_file')!r})")
        out = {name: f[name][()] for name in f}
        out["attrs"] = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}
    return out


# ---- summary and figure -------------------------------------------------------------------------

def pushover_json(run: PushoverRun) -> dict:
    """The ``uplift pushover --json`` object: the onset and the curve per step (no pressure maps)."""
    c, on = run.curve, run.curve.onset
    return {"scene": run.scene, "soil": run.soil, "soil_label": run.soil_label, "direction_deg": run.direction_deg,
            "weight_N": run.weight_N, "extra_vertical_N": run.extra_vertical_N, "vertical_N": c.vertical,
            "stiffness_factor": run.stiffness_factor, "contact": CONTACT, "nodes": int(run.xy.shape[0]),
            "onset": {"rotation_rad": on.rotation, "moment_Nm": on.moment, "eccentricity_m": on.eccentricity,
                      "node": on.node, "nodes": list(on.nodes), "at_rest": on.at_rest,
                      "rocking_stiffness_Nm_per_rad": on.stiffness},
            "steps": {"rotation_rad": c.rotation.tolist(), "moment_Nm": c.moment.tolist(),
                      "eccentricity_m": run.eccentricity.tolist(), "settlement_m": c.settlement.tolist(),
                      "contact_ratio": c.contact_ratio.tolist(), "max_gap_m": c.max_gap.tolist(),
                      "iterations": c.iterations.tolist()},
            "wall_s": run.wall_s}


def pushover_figure(run: PushoverRun):
    """Moment-rotation and contact ratio-moment, the lift-off onset marked."""
    from orchestrator.plots import pyplot  # matplotlib: only when a figure is drawn
    plt = pyplot()
    c, on = run.curve, run.curve.onset
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax1.plot(1e3 * c.rotation, 1e-6 * c.moment, "-o", ms=2.5, label=f"{run.soil} pushover")
    ax2.plot(1e-6 * c.moment, 100 * c.contact_ratio, "-o", ms=2.5, label=f"{run.soil} pushover")
    if not on.at_rest:
        lab = f"lift-off onset: M = {1e-6 * on.moment:.4g} MN m, e = {on.eccentricity:.4g} m"
        ax1.plot(1e3 * on.rotation, 1e-6 * on.moment, "r*", ms=12, label=lab)
        ax2.axvline(1e-6 * on.moment, color="r", ls="--", label=lab)
    ax1.set_xlabel("raft rotation θ (mrad)")
    ax1.set_ylabel("overturning moment M (MN m)")
    ax2.set_xlabel("overturning moment M (MN m)")
    ax2.set_ylabel("contact ratio (% of the raft area)")
    ax2.set_ylim(0, 105)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    ax1.legend(fontsize=8, loc="lower right")
    ax2.legend(fontsize=8, loc="lower left")
    fig.suptitle(f"{run.scene}: static pushover on the {run.soil_label}, direction {run.direction_deg:g}°, "
                 f"vertical load {1e-6 * c.vertical:.4g} MN", fontsize=9)
    fig.tight_layout()
    return fig


def plot_pushover(run: PushoverRun, path) -> Path:
    from orchestrator.plots import pyplot  # matplotlib: only when a figure is drawn
    plt = pyplot()
    fig = pushover_figure(run)
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return Path(path)
