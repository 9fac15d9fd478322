"""Dynamic runs on the static pushover curve (issue 39, item 3; docs/pushover.md, *Runs on the curve*).

A run's point is (its largest overturning moment, its largest raft rotation, its smallest
contact ratio), read against the static moment-rotation curve of ``uplift pushover`` of the same
scene, on the same soil, like for like:

- **moment**: the moment about the raft centre of the *total* contact forces P_i = P0_i + p_i
  (the results file's ``contact_force``: static preload included) beyond the weight's own,
  with the pushover's sign: M_rx = -sum P_i y_i - F_rx, M_ry = sum P_i x_i - F_ry (F the
  structure's weight brought to the raft centre, ``raft_load``). The pushover's moment is the
  reaction a . (-Bq^T P - F) of the same contact forces (its soil has no rocking term on the
  raft: the BEM gap table's uz, rx, ry rows are zero, the springs act at the nodes), so
  rocking in direction n gives M = n . r-moment = a . (M_rx, M_ry). A run rocks in every
  direction: its point takes the magnitude |M| = sqrt(M_rx^2 + M_ry^2) (N m) in the rocking
  plane, and the largest over time.
- **rotation**: the magnitude sqrt(rx^2 + ry^2) of the raft rotation (rad; the results file's
  ``raft_rotation``, relative to the static state, as ``max_raft_rotation_rad``); the
  pushover's theta is measured from the level raft. The two origins agree when the weight acts
  at the raft centre (the static state is level); otherwise the run's rotations are about its
  tilted static state (the report says so when the curve's moment at theta = 0 is not zero).
- **contact ratio**: the area of the nodes with gap = 0 over the raft area (the pushover's
  definition, with the mesh's tributary areas), smallest over time.
- **soil**: the winkler route against the pushover on its own springs (``--soil winkler``:
  ``static_springs``, the springs it steps on, without dashpots); monolithic, cosim, timefreq
  and linear against the pushover on the BEM's static gap table (``--soil bem``). The linear
  route is bonded (its contact force may be a tension): it is drawn, marked "no uplift".

``scene_key`` identifies what a pushover depends on (mesh, soil, structure, winkler springs):
``run_scene`` stores it in each route's ``info``, an ensemble file in its attributes, a pushover
file in its own, so that a curve is drawn only under runs of the same scene.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass

import numpy as np

from soil_impedance.sweep import provenance as sweep_provenance
from uplift_common.errors import UserInputError

#: routes compared with the pushover on their own springs; every other one with the BEM's
SPRING_ROUTES = ("winkler",)


class OnCurveError(UserInputError):
    """A pushover that cannot be drawn under the runs: of another scene (``Curve.check_key``),
    or a file without a scene key."""


def raft_load(model) -> np.ndarray:
    """(6,) N and N m: the structure's weight brought to the raft centre (T^T f_gravity)."""
    return model.rigid_transform.T @ model.gravity_load()


def scene_key(scene) -> str:
    """A digest (16 hex digits) of what a pushover of ``scene`` depends on: the interface mesh
    (its nodes and areas, the cells of a finite-element mesh), the contact kind, the soil
    profile, the structure and the winkler springs' calibration; not the motion, the analysis
    or the code version."""
    mesh = scene.mesh
    bem = None
    if scene.profile is not None:
        bem = sweep_provenance(scene.profile, mesh, scene.contact_kind, None, "gap")
        bem = {k: v for k, v in bem.items() if k != "code_version"}
    parts = {"mesh": {"kind": mesh.kind, "size": list(mesh.size), "cell": mesh.cell, "n": mesh.n,
                      "xy": hashlib.sha256(np.ascontiguousarray(mesh.xy, float).tobytes()).hexdigest(),
                      "area": hashlib.sha256(np.ascontiguousarray(mesh.area, float).tobytes()).hexdigest()},
             "structure": None if scene.structure is None else scene.structure.as_table(),
             "winkler": {"springs": scene.winkler.springs, "match": scene.winkler.match,
                         "moduli": None if scene.winkler.moduli is None else list(scene.winkler.moduli)},
             "bem": bem}
    if mesh.cells is not None:                 # (only then: the keys of the other meshes are kept)
        parts["mesh"]["cells"] = hashlib.sha256(np.ascontiguousarray(mesh.cells, "<f8").tobytes()).hexdigest()
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def route_soil(route: str) -> str:
    """The pushover soil a route is compared with: "winkler" (its own springs) or "bem"."""
    return "winkler" if route in SPRING_ROUTES else "bem"


def rocking_direction(components) -> tuple[float, str]:
    """(degrees, why) of the pushover drawn under a run of the motion ``components``: x (0) for
    an x motion, y (90) for a y motion, x for both (then the magnitudes of the run are read
    against the curve in x; a square or circular raft rocks alike in both)."""
    horizontal = [c for c in components if c in ("x", "y")]
    if horizontal == ["y"]:
        return 90.0, "the motion's direction y"
    if horizontal == ["x"]:
        return 0.0, "the motion's direction x"
    if not horizontal:
        return 0.0, "x (the motion has no horizontal component)"
    return 0.0, "x (the motion shakes in x and y: the run's magnitudes are read against the curve in x)"


def overturning_moment(contact_force, xy, load) -> np.ndarray:
    """(nt, 2) N m: the moment about the raft centre's x and y axes of the contact forces
    ``contact_force`` (nt, N) N at the nodes ``xy`` (N, 2) m, beyond the moment of the raft's
    loads ``load`` (6,) (the weight at rest): M_rx = -sum P y - F_rx, M_ry = sum P x - F_ry, the
    pushover's sign (rocking vector a: its moment is a . (M_rx, M_ry))."""
    P = np.asarray(contact_force, float)
    xy = np.asarray(xy, float)
    load = np.asarray(load, float)
    return np.column_stack([-(P @ xy[:, 1]) - load[3], P @ xy[:, 0] - load[4]])


def run_extremes(res, xy, area, load) -> dict:
    """A run's largest |M| (N m) and its time (s), its moment magnitude at t = 0 (N m), the
    total contact force then over the static vertical load (the static capacity N x (distance
    to the edge) grows with it), largest raft rotation sqrt(rx^2 + ry^2) (rad) and smallest
    contact ratio by area (1)."""
    M = np.hypot(*overturning_moment(res.contact_force, xy, load).T)
    rot = np.hypot(res.raft[:, 3], res.raft[:, 4])
    area = np.asarray(area, float)
    contact = (res.gap <= 0) @ area / area.sum()
    k = int(np.argmax(M))
    return {"max_moment_Nm": float(M[k]), "max_moment_time_s": float(res.time[k]), "moment_at_start_Nm": float(M[0]),
            "vertical_ratio_at_max_moment": float(res.contact_force[k].sum() / -load[2]) if load[2] < 0 else float("nan"),
            "max_rotation_rad": float(rot.max()), "min_contact_ratio": float(contact.min())}


# ---- the curve, from a pushover run or file -----------------------------------------------------

@dataclass(frozen=True, eq=False)
class Curve:
    """A pushover curve as drawn under runs: soil "bem" | "winkler", its label, direction
    (degrees), rotation (rad), moment (N m), contact_ratio (1) per step; the onset (rad, N m;
    NaN when lifted at rest), the full-contact rocking stiffness (N m / rad), the vertical load
    (N), the raft loads (6,), the nodes xy (N, 2) m and areas (N,) m2, the scene name and key,
    and where it comes from (``source``: "computed" or the file)."""
    soil: str
    soil_label: str
    direction_deg: float
    rotation: np.ndarray
    moment: np.ndarray
    contact_ratio: np.ndarray
    onset_rotation: float
    onset_moment: float
    stiffness: float
    vertical: float
    load: np.ndarray
    xy: np.ndarray
    area: np.ndarray
    scene: str
    scene_key: str
    source: str

    @classmethod
    def from_run(cls, run, source: str = "computed") -> Curve:
        """From an ``orchestrator.pushover.PushoverRun``."""
        c, on = run.curve, run.curve.onset
        nan = float("nan")
        return cls(run.soil, run.soil_label, run.direction_deg, c.rotation, c.moment, c.contact_ratio,
                   nan if on.at_rest else on.rotation, nan if on.at_rest else on.moment, on.stiffness, c.vertical,
                   np.asarray(run.load, float), run.xy, run.area, run.scene, run.scene_key, source)

    @classmethod
    def from_file(cls, data: dict, source: str) -> Curve:
        """From ``orchestrator.pushover.read_pushover``'s dict; a file without a scene key
        (written before it was stored) is refused."""
        a = data["attrs"]
        if "scene_key" not in a:
            raise OnCurveError(f"pushover file {source} holds no scene key (written before `uplift report` read "
                               "them): make it again with `uplift pushover SCENE -o FILE`")
        nan = float("nan")
        at_rest = bool(a["onset_at_rest"])
        return cls(str(a["soil"]), str(a["soil_label"]), float(a["direction_deg"]), data["rotation"], data["moment"],
                   data["contact_ratio"], nan if at_rest else float(a["onset_rotation_rad"]),
                   nan if at_rest else float(a["onset_moment_Nm"]), float(a["rocking_stiffness_Nm_per_rad"]),
                   float(a["vertical_N"]), np.asarray(a["raft_load"], float),
                   np.column_stack([data["x"], data["y"]]), np.asarray(data["area"], float), str(a["scene"]),
                   str(a["scene_key"]), source)

    def moment_at(self, rotation: float) -> float:
        """The curve's moment at ``rotation`` (rad; linear between its points), NaN beyond its last."""
        if not 0 <= rotation <= self.rotation[-1]:
            return float("nan")
        return float(np.interp(rotation, self.rotation, self.moment))

    def check_key(self, key: str | None, what: str) -> None:
        """Refuse the curve under ``what`` (e.g. "results file run.h5") of scene key ``key``."""
        if not key:
            raise OnCurveError(f"{what} holds no scene key (written before it was stored): the curve of "
                               f"{self.source} cannot be checked against it; run `uplift run` again")
        if key != self.scene_key:
            raise OnCurveError(f"the pushover of {self.source} (scene {self.scene!r}, key {self.scene_key}) is not "
                               f"of the scene of {what} (key {key}): its mesh, soil, structure or springs differ; "
                               "make the pushover of the run's scene (uplift pushover SCENE -o FILE)")


def route_point(res, curve: Curve, uplift: bool = True) -> dict:
    """The point of a route's result on ``curve``: ``run_extremes``, the curve's moment at the
    run's largest rotation (NaN beyond the curve) and the run's largest moment over it, with
    route, soil, uplift (False: a bonded route) and status."""
    xy = curve.xy if res.xy is None else res.xy
    out = {"route": res.route, "soil": curve.soil, "uplift": uplift, "status": res.status.value,
           **run_extremes(res, xy, curve.area, curve.load)}
    static = curve.moment_at(out["max_rotation_rad"])
    out["static_moment_at_rotation_Nm"] = static
    out["moment_over_static"] = out["max_moment_Nm"] / static if static > 0 else float("nan")
    return out


def unplaced(res, curve: Curve | None) -> str:
    """Why a route's result cannot be placed on ``curve`` ("" when it can)."""
    if res.nt == 0:
        return f"{res.status.value}: no histories ({res.message})"
    if curve is None:
        return f"no pushover on the {route_soil(res.route)} soil"
    n = res.contact_force.shape[1]
    if n != curve.xy.shape[0]:
        return f"{n} interface nodes, the curve {curve.xy.shape[0]}"
    if res.xy is not None and not np.allclose(res.xy, curve.xy, atol=1e-9):
        return "its interface nodes are not the curve's"
    return ""


# ---- the figure ---------------------------------------------------------------------------------

def oncurve_figure(curves: dict, points: list, title: str):
    """The curves {soil: Curve} (moment against rotation; contact ratio against moment, the
    onset marked) and the runs' points on them: each a dict with route, soil, uplift,
    max_moment_Nm, max_rotation_rad, min_contact_ratio (an ensemble's cells: many per route,
    drawn small). One colour and marker per route; a route without uplift hollow."""
    from orchestrator.plots import pyplot, route_style  # matplotlib: only when a figure is drawn
    plt = pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.6))
    lines = {"bem": "-", "winkler": "--"}
    for soil, c in curves.items():
        lab = f"static pushover, {soil} ({c.direction_deg:g}°)"
        ax1.plot(1e3 * c.rotation, 1e-6 * c.moment, lines.get(soil, ":"), color="0.3", lw=1.3, label=lab)
        ax2.plot(1e-6 * c.moment, 100 * c.contact_ratio, lines.get(soil, ":"), color="0.3", lw=1.3, label=lab)
        if math.isfinite(c.onset_moment):
            ax1.plot(1e3 * c.onset_rotation, 1e-6 * c.onset_moment, "*", color="0.3", ms=10,
                     label=f"lift-off onset, {soil}: {1e-6 * c.onset_moment:.4g} MN m")
            ax2.plot(1e-6 * c.onset_moment, 100.0, "*", color="0.3", ms=10)
    routes = list(dict.fromkeys(p["route"] for p in points))
    many = len(points) > len(routes)
    for k, route in enumerate(routes):
        mine = [p for p in points if p["route"] == route]
        style = route_style(k)
        hollow = not mine[0]["uplift"]
        kw = dict(marker=style["marker"], color=style["color"], linestyle="none", ms=4 if many else 9,
                  alpha=0.6 if many else 1.0, markerfacecolor="none" if hollow else style["color"],
                  markeredgewidth=1.5)
        lab = f"{route} ({mine[0]['soil']})" + (": no uplift (bonded)" if hollow else "")
        rot = np.array([p["max_rotation_rad"] for p in mine])
        mom = np.array([p["max_moment_Nm"] for p in mine])
        con = np.array([p["min_contact_ratio"] for p in mine])
        ax1.plot(1e3 * rot, 1e-6 * mom, label=lab, **kw)
        ax2.plot(1e-6 * mom, 100 * con, label=lab, **kw)
    ax1.set_xlabel("raft rotation θ; runs: max sqrt(rx² + ry²) (mrad)")
    ax1.set_ylabel("overturning moment M; runs: max |M| (MN m)")
    ax2.set_xlabel("overturning moment M; runs: max |M| (MN m)")
    ax2.set_ylabel("contact ratio; runs: min (% of the raft area)")
    ax2.set_ylim(0, 105)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        ax.set_xlim(left=0)
    ax1.set_ylim(bottom=0)
    shown = [p["max_rotation_rad"] for p in points] + [c.onset_rotation for c in curves.values()]
    shown = [r for r in shown if math.isfinite(r)]
    if shown:           # the curves may run far past the runs (20 x the onset): show the runs
        ax1.set_xlim(right=1e3 * min(max(c.rotation[-1] for c in curves.values()), 1.5 * max(shown)))
    ax1.legend(fontsize=7, loc="lower right")
    ax2.legend(fontsize=7, loc="lower left")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig
