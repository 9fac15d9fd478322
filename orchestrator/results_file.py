"""One results file for every route (HDF5, readable as netCDF4 by xarray), and the per-route summary.

Layout (``format_version`` 2; every array in SI units, every variable with CF ``units`` and
``long_name`` attributes; the coordinates are HDF5 dimension scales, so that xarray names the
dimensions)::

    /                        attrs: uplift_file = "results", format_version = 2, Conventions,
                                    scene, created, sha256 (checksum of the file's content),
                                    scene_toml (the scene as it ran, TOML: ``load_scene`` reads it),
                                    overrides (JSON: the command line's --pga, --dt, --duration,
                                    --max-pga, each {option, value, key, was, now})
    /motion/                 attrs: dt (s), label, components ("x,y,z")
        time (time) s   direction (direction)   acc (time, direction) m s-2: ground acceleration
    /routes/<route>/         attrs: route, status (converged | stopped | refused), message, wall_s,
                                    notes (JSON: skipped, warnings, precheck, timings), info (JSON),
                                    and the summary numbers (SUMMARY_ATTRS: max_uplift_m, ...)
        coordinates  time (time) s, node (node) interface node index, x (node) m, y (node) m,
                     direction ("x", "y", "z"), output (output): structure output node names,
                     energy_term (energy_term), frequency (frequency) Hz
        raft_translation (time, direction) m     raft_rotation (time, direction) rad
        gap, contact_force, soil_w (time, node) m, N, m     newton_iters (time)
        a plate raft (foundation.raft.kind = "plate"): plate_vertex (plate_vertex), plate_vertex_x,
        plate_vertex_y (plate_vertex) m, plate_vertex_held (plate_vertex) 1 (the held region's
        vertices), plate_deflection (time, node) m, plate_vertex_deflection (time, plate_vertex) m
        (relative to the static state and to the free field); contact_pressure (time, node) Pa
        (contact_force / the cell's area), and at the instant of peak uplift (attribute time_s)
        uplift_map (node) m and contact_pressure_map (node) Pa; moment ("Mx", "My", "Mxy"),
        base_cell (base_cell): the cells around the stick base (interface node indices),
        plate_moment (time, base_cell, moment) N m m-1 and plate_moment_peak (node, moment)
        N m m-1 (bending moments per unit length, static + dynamic, top fibre in tension
        positive; the peak: the largest magnitude over time) when the route computes them
        acc (time, output, direction) m s-2      disp (time, output, direction) m
        energy (time, energy_term) J
        floor_spectrum (output, direction, frequency) m s-2: 5 % pseudo-acceleration (NaN where
                     the direction is round-off), floor_spectrum_peak (output, direction) m s-2
                     and its frequency floor_spectrum_peak_frequency (output, direction) Hz,
        peak_acc (output) m s-2
    /interface/              attrs: kind (circle | rectangle | nodes | cells), mesh_source (JSON: a
                                    mesh file's path, sha256, format, group and the raft centre in
                                    its coordinates; "null" for the other foundations)
        coordinates  node (node), vertex (vertex), axis ("x", "y"), x (node) m, y (node) m
        polygon (node, vertex, axis) m: the patch of each interface node about the raft centre
                     (a mesh file's cells, triangles with a vertex repeated; the squares of the
                     same area for the other foundations), area (node) m2

acc, disp, energy and the spectra are left out of a route that has none (a refused route keeps
only its empty time and node coordinates). Open it with xarray::

    xarray.open_datatree(path, engine="h5netcdf")                          # the whole file
    xarray.open_dataset(path, group="routes/winkler", engine="h5netcdf")   # one route

(``open_results`` does the same after verifying the checksum). ``read_results`` gives the
RouteResults back, exactly, from this layout and from the layout before it (version 1, no
``format_version``: raft (nt, 6), xy (N, 2), acc/<node>, disp/<node>, energy/<term>; no summary).

A route that stopped early is written with what it computed, status "stopped" and its
``message`` (the reason). The file is written atomically: an existing file at the same path
stays intact until the new one is complete.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import h5py
import numpy as np

from uplift_common.files import (ChangedFileError, OutputPathError, RecordedFile, hdf5_output, output_target,
                                 require_checksum, stamp_checksum)
from structure.results import RouteResult, RunNotes, Status

from orchestrator.motion import G, Motion
from orchestrator.spectra import FLOOR_DAMPING, FLOOR_FREQUENCIES_HZ, floor_spectra
from uplift_common.errors import UserInputError

#: root attribute ``uplift_file`` of a results file, and the layout this code writes
KIND = "results"
FORMAT_VERSION = 2
ARRAYS = ("time", "raft", "gap", "contact_force", "soil_w", "newton_iters", "xy")
GROUPS = ("acc", "disp", "energy")
DIRECTIONS = ("x", "y", "z")
REMEDY = "run `uplift run SCENE -o FILE` again to make a good one"
#: the summary numbers stored as route attributes: attribute -> (summary key, axis key or None)
SUMMARY_ATTRS = {"max_uplift_m": ("max_uplift_m", None), "max_uplift_time_s": ("max_uplift_time_s", None),
                 "max_raft_rotation_rad": ("max_raft_rotation_rad", None),
                 "max_raft_rotation_x_rad": ("max_raft_rotation_axes_rad", "x"),
                 "max_raft_rotation_y_rad": ("max_raft_rotation_axes_rad", "y"),
                 "min_contact_fraction": ("min_contact_fraction", None)}
#: per-node histories of version 2: name -> (units, long name)
NODE_HISTORIES = {"gap": ("m", "uplift (gap) of the interface node, >= 0"),
                  "contact_force": ("N", "total compressive contact force at the interface node"),
                  "soil_w": ("m", "dynamic vertical soil displacement under the interface node")}


class ResultsFileError(UserInputError):
    """A results file that is missing, unreadable or not of this layout, or an output path that
    cannot be written (exit 2 in the CLI)."""


def check_output_path(path) -> Path:
    """Refuse, before any computation, an output file the run could not write: its folder
    missing or not writable, the path a folder, or anything else that is not a regular file (a
    device, a FIFO: a rename would replace it). A symlink is followed: the target is checked
    and written, the link survives. Returns ``path``."""
    path = Path(path)
    if path.is_dir():
        raise ResultsFileError(f"output {str(path)!r} is a folder: give a file name, e.g. {path / 'results.h5'}")
    try:
        target = output_target(path)
    except OutputPathError as exc:
        raise ResultsFileError(str(exc)) from None
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise ResultsFileError(f"output folder {str(folder)!r} does not exist: create it or choose another -o path")
    if not os.access(folder, os.W_OK):
        raise ResultsFileError(f"output folder {str(folder)!r} is not writable: choose another -o path")
    return path


def check_output_folder(path, names=(), option: str = "-o") -> Path:
    """Refuse, before any computation, an output folder that cannot take the files ``names``:
    ``path`` (or a folder on its way) a file, not writable, or one of ``names`` inside it
    present and not a regular file (a symlink to one is followed). Returns ``path``."""
    path = Path(path)
    parts = [*reversed(path.absolute().parents), path.absolute()]
    for p in parts:
        if p.exists() or p.is_symlink():
            if not p.is_dir():
                where = "is" if p == path.absolute() else f"lies under {str(p)!r}, which is"
                raise ResultsFileError(f"{option} {str(path)!r} {where} not a folder: give a folder "
                                       "(it is created if it does not exist)")
            existing = p
    if not os.access(existing, os.W_OK):
        raise ResultsFileError(f"{option} {str(path)!r}: folder {str(existing)!r} is not writable; choose another "
                               "folder")
    for name in names:
        try:
            output_target(path / name)
        except OutputPathError as exc:
            raise ResultsFileError(f"{option} {str(path)!r}: {exc}") from None
    return path


def write_results(path, results: dict, motion=None, scene_name: str = "", scene_toml: str = "",
                  overrides=(), mesh=None, mesh_source=None, extra=None) -> Path:
    """Write ``{route: RouteResult}`` (and the motion, the scene as TOML, the overrides of the
    command line, the interface ``mesh`` (InterfaceMesh) with the ``mesh_source`` it was read
    from (``soil_impedance.mesh_file.MeshSource`` or None)) to one HDF5 file of the layout of
    this module (format_version 2: netCDF4 dimension scales, CF units, the per-route summary),
    atomically, with the checksum of its whole content. ``extra(f)``, when given, writes more
    groups into the open file before the checksum (the soil cases and design spectra of
    ``orchestrator.design``), through the same recording file (``RecordedFile``: the checksum
    is computed from what is written, the same digest as read back)."""
    path = check_output_path(path)
    with hdf5_output(path) as h5:
        f = RecordedFile(h5)                    # the checksum from what is written, not read back
        f.attrs.update(uplift_file=KIND, format_version=FORMAT_VERSION, Conventions="CF-1.8", scene=scene_name,
                       scene_toml=scene_toml, overrides=json.dumps(list(overrides)),
                       created=time.strftime("%Y-%m-%dT%H:%M:%S"))
        if motion is not None:
            _write_motion(f.create_group("motion"), motion)
        routes = f.create_group("routes", track_order=True)
        area = None if mesh is None else np.asarray(mesh.area, float)
        for name, res in results.items():
            _write_route(routes.create_group(name), res, area)
        if mesh is not None:
            _write_interface(f.create_group("interface"), mesh, mesh_source)
        if extra is not None:
            extra(f)
        stamp_checksum(f)
    return path


def patch_polygons(mesh) -> np.ndarray:
    """(N, 4, 2) m: the patch of each interface node, counter-clockwise about the raft centre:
    the cells of a finite-element mesh, else the square of the node's patch (``cell`` side on a
    grid, sqrt(area) otherwise, as the BEM takes it)."""
    if mesh.cells is not None:
        return np.asarray(mesh.cells, float)
    h = mesh.patch_half_sides[:, None, None]
    corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    return np.asarray(mesh.xy, float)[:, None, :] + h * corners[None]


def _write_interface(g, mesh, source) -> None:
    """The interface mesh: each node's patch polygon and area, its kind and the file it came from."""
    g.attrs["kind"] = mesh.kind
    g.attrs["mesh_source"] = json.dumps(None if source is None else source.as_dict())
    _coordinate(g, "node", np.arange(mesh.n), None, "interface node (index in the foundation mesh)")
    _coordinate(g, "vertex", np.arange(4), None, "vertex of the patch polygon (counter-clockwise)")
    _coordinate(g, "axis", ["x", "y"], None, "horizontal axis")
    for k, axis in enumerate("xy"):
        _variable(g, axis, mesh.xy[:, k], ("node",), "m", f"{axis} of the interface node about the raft centre")
    _variable(g, "polygon", patch_polygons(mesh), ("node", "vertex", "axis"), "m",
              "patch of the interface node about the raft centre (a triangle repeats a vertex)", "x y")
    _variable(g, "area", mesh.area, ("node",), "m2", "area of the patch", "x y")


def read_interface(path) -> dict | None:
    """{"kind", "polygon" (N, 4, 2) m, "area" (N,) m2, "xy" (N, 2) m, "mesh_source" (dict or
    None)} of a results file's interface (its checksum verified), None in a file written
    without it."""
    with _opened(path) as (f, _):
        if "interface" not in f:
            return None
        g = f["interface"]
        return {"kind": str(g.attrs["kind"]), "polygon": g["polygon"][()], "area": g["area"][()],
                "xy": np.column_stack([g["x"][()], g["y"][()]]), "mesh_source": json.loads(g.attrs["mesh_source"])}


def _describe(ds, units: str | None, long_name: str) -> None:
    """The CF attributes of a variable: ``units`` (None: a label, no units) and ``long_name``."""
    if units is not None:
        ds.attrs["units"] = units
    ds.attrs["long_name"] = long_name


def _coordinate(g, name: str, values, units: str | None, long_name: str):
    """The coordinate ``name`` (name,) of group ``g``, made an HDF5 dimension scale: netCDF4's
    dimension ``name``, which xarray reads as a named dimension. Labels are UTF-8 strings."""
    values = np.asarray(values)
    if values.dtype.kind in "UO":
        values = np.array([str(v) for v in values], dtype=h5py.string_dtype())
    ds = g.create_dataset(name, data=values)
    ds.make_scale(name)
    _describe(ds, units, long_name)
    return ds


def _variable(g, name: str, data, dims: tuple, units: str | None, long_name: str, coordinates: str = ""):
    """The variable ``name`` of group ``g`` over the coordinates ``dims`` of ``g`` (attached as
    its dimension scales, one per axis of ``data``); ``coordinates``: its auxiliary coordinates
    (CF, space separated)."""
    ds = g.create_dataset(name, data=data)
    for axis, dim in enumerate(dims):
        ds.dims[axis].attach_scale(g[dim])
    _describe(ds, units, long_name)
    if coordinates:
        ds.attrs["coordinates"] = coordinates
    return ds


def _write_motion(m, motion) -> None:
    """The ground motion: time (nt,) s, direction, acc (nt, 3) m/s²; attrs dt, label, components."""
    m.attrs["dt"], m.attrs["label"] = motion.dt, motion.label
    m.attrs["components"] = ",".join(motion.components)
    _coordinate(m, "time", motion.time, "s", "time from the start of the record")
    _coordinate(m, "direction", DIRECTIONS[:motion.acc.shape[1]], None, "axis of the global frame (z up)")
    _variable(m, "acc", motion.acc, ("time", "direction"), "m s-2", "ground acceleration")


def _write_route(g, res, area=None) -> None:
    """One route's group (the layout of this module): its attributes, histories, floor spectra
    and summary numbers; ``area`` (N,) m² the interface cells' areas (a plate raft's contact
    pressures; None: none written)."""
    g.attrs.update(route=res.route, status=res.status.value, message=res.message, wall_s=res.wall_s,
                   notes=json.dumps(res.notes.as_dict()), info=json.dumps(dict(res.info), default=_jsonable))
    s = summary(res)
    g.attrs["components"] = ",".join(s["components"])
    for attr, (key, axis) in SUMMARY_ATTRS.items():
        g.attrs[attr] = s[key] if axis is None else s[key][axis]
    N = res.gap.shape[1]
    _coordinate(g, "time", res.time, "s", "time from the start of the record")
    _coordinate(g, "direction", DIRECTIONS, None, "axis of the global frame (z up)")
    _coordinate(g, "node", np.arange(N), None, "interface node (index in the foundation mesh)")
    coordinates = ""
    if res.xy is not None:
        if res.xy.shape != (N, 2):
            raise ValueError(f"RouteResult {res.route!r}: xy has shape {res.xy.shape}, the gap has {N} nodes")
        for k, axis in enumerate("xy"):
            _variable(g, axis, res.xy[:, k], ("node",), "m", f"{axis} of the interface node")
        coordinates = "x y"
    _variable(g, "raft_translation", res.raft[:, :3], ("time", "direction"), "m",
              "raft displacement ux, uy, uz relative to the static state and to the free field")
    _variable(g, "raft_rotation", res.raft[:, 3:], ("time", "direction"), "rad", "raft rotation rx, ry, rz about the axis")
    for name, (units, long_name) in NODE_HISTORIES.items():
        _variable(g, name, getattr(res, name), ("time", "node"), units, long_name, coordinates)
    _variable(g, "newton_iters", res.newton_iters, ("time",), "1", "linear solves of the step (0 for linear routes)")
    if res.plate_deflection is not None:
        _write_plate(g, res, coordinates, area)
    _write_outputs(g, res)
    if res.energy:
        _coordinate(g, "energy_term", list(res.energy), None, "term of the energy balance "
                    "(input = kinetic + strain + damping + soil + contact)")
        _variable(g, "energy", np.stack(list(res.energy.values()), axis=1), ("time", "energy_term"), "J",
                  "cumulative work or stored energy")


def peak_uplift_step(gap) -> int:
    """The time step of the peak uplift (the first, on a tie; 0 without uplift): where the
    summary's max_uplift_time_s is."""
    gap = np.asarray(gap)
    return int(np.argmax(gap.max(axis=1))) if gap.size else 0


def contact_pressure(contact_force, area) -> np.ndarray:
    """(..., N) Pa: the compressive contact pressure of each interface node, its contact force
    (..., N) N over its cell's area (N,) m²."""
    return np.asarray(contact_force, float) / np.asarray(area, float)


def _write_plate(g, res, coordinates: str, area=None) -> None:
    """A plate raft's deflections: at the interface nodes (time, node) and at the plate's vertices
    (time, plate_vertex), with the vertices' coordinates and the held ones; with ``area`` the
    contact pressures (time, node) and the uplift and pressure maps at peak uplift; the bending
    moments when the route gives them."""
    m = res.plate_vertices.shape[0]
    _coordinate(g, "plate_vertex", np.arange(m), None, "vertex of the plate raft (DKT mesh on the interface cells)")
    for k, axis in enumerate("xy"):
        _variable(g, f"plate_vertex_{axis}", res.plate_vertices[:, k], ("plate_vertex",), "m",
                  f"{axis} of the plate vertex about the raft centre")
    if res.plate_vertex_held is not None:
        _variable(g, "plate_vertex_held", res.plate_vertex_held.astype(np.int8), ("plate_vertex",), "1",
                  "1: the vertex is in the held region (moves rigidly with the stick base), 0: free",
                  "plate_vertex_x plate_vertex_y")
    if area is not None and res.nt:
        k = peak_uplift_step(res.gap)
        p = contact_pressure(res.contact_force, area)
        _variable(g, "contact_pressure", p, ("time", "node"), "Pa",
                  "compressive contact pressure (contact force over the cell's area)", coordinates)
        _variable(g, "uplift_map", res.gap[k], ("node",), "m", "uplift (gap) of the interface node at the "
                  "instant of peak uplift", coordinates).attrs["time_s"] = float(res.time[k])
        _variable(g, "contact_pressure_map", p[k], ("node",), "Pa", "compressive contact pressure at the "
                  "instant of peak uplift", coordinates).attrs["time_s"] = float(res.time[k])
    if res.plate_moment is not None:
        _coordinate(g, "moment", ["Mx", "My", "Mxy"], None, "bending moment per unit length (Mx: about the "
                    "plate's y axis, from the curvature along x; Mxy: the twisting moment)")
        _coordinate(g, "base_cell", res.plate_moment_cells, None, "interface cell around the stick base (node "
                    "index): vertices both in and out of the held region")
        _variable(g, "plate_moment", res.plate_moment, ("time", "base_cell", "moment"), "N m m-1",
                  "bending moment per unit length in the cell around the stick base (static + dynamic; positive: "
                  "top fibre in tension)")
        _variable(g, "plate_moment_peak", res.plate_moment_peak, ("node", "moment"), "N m m-1",
                  "largest magnitude over time of the bending moment per unit length in the cell", coordinates)
    _variable(g, "plate_deflection", res.plate_deflection, ("time", "node"), "m",
              "plate raft deflection at the interface node (its cell's vertices interpolated), relative to the "
              "static state and to the free field", coordinates)
    _variable(g, "plate_vertex_deflection", res.plate_vertex_deflection, ("time", "plate_vertex"), "m",
              "plate raft deflection at the vertex, relative to the static state and to the free field",
              "plate_vertex_x plate_vertex_y")


def _write_outputs(g, res) -> None:
    """The structure's output nodes: acc, disp (time, output, direction), their floor spectra
    and peaks, the peak acceleration; disp over its own ``disp_output`` coordinate when its
    nodes are not those of acc."""
    names = list(res.acc)
    if names:
        _coordinate(g, "output", names, None, "output node of the structure")
        acc = np.stack([res.acc[n] for n in names], axis=1)
        _variable(g, "acc", acc, ("time", "output", "direction"), "m s-2", "absolute acceleration of the output node")
        peak = [float(np.abs(a).max()) if a.size else 0.0 for a in res.acc.values()]
        _variable(g, "peak_acc", peak, ("output",), "m s-2", "peak absolute acceleration over time and directions")
        if res.nt > 1:
            _write_spectra(g, floor_spectra(res.acc, float(res.time[1] - res.time[0]), names))
    if res.disp:
        dim = "output" if set(res.disp) == set(names) else "disp_output"
        disp_names = names if dim == "output" else list(res.disp)
        if dim != "output":
            _coordinate(g, dim, disp_names, None, "output node of the structure (displacements)")
        _variable(g, "disp", np.stack([res.disp[n] for n in disp_names], axis=1), ("time", dim, "direction"), "m",
                  "displacement of the output node relative to the free field")


def _write_spectra(g, spectra) -> None:
    """floor_spectrum (output, direction, frequency) m/s² (NaN: round-off direction) and its peak
    and the peak's frequency per output node and direction."""
    _coordinate(g, "frequency", FLOOR_FREQUENCIES_HZ, "Hz", "frequency of the oscillator")
    long = f"{100 * FLOOR_DAMPING:g} % damped pseudo-acceleration response spectrum of the floor acceleration"
    _variable(g, "floor_spectrum", spectra, ("output", "direction", "frequency"), "m s-2", long).attrs[
        "damping"] = FLOOR_DAMPING
    defined = np.isfinite(spectra).any(axis=2)
    peak = np.fmax.reduce(spectra, axis=2)
    at = np.where(defined, FLOOR_FREQUENCIES_HZ[np.argmax(np.where(np.isfinite(spectra), spectra, -np.inf), axis=2)],
                  np.nan)
    _variable(g, "floor_spectrum_peak", peak, ("output", "direction"), "m s-2", f"peak of the {long}")
    _variable(g, "floor_spectrum_peak_frequency", at, ("output", "direction"), "Hz",
              "frequency of the floor-spectrum peak")


#: the writers of this layout, for the groups other modules add through ``write_results(extra=)``
add_coordinate, add_variable, add_route = _coordinate, _variable, _write_route


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if hasattr(obj, "items"):
        return dict(obj)
    return str(obj)


def read_results(path, case: str | None = None) -> dict:
    """Read a results file back as ``{route: RouteResult}`` (format_version 2, or 1: the layout
    before it); a missing, unreadable or foreign file raises ResultsFileError naming it, a
    changed one ChangedFileError. ``case``: the routes of that soil case (``read_cases``; the
    file's top-level routes are those of its first case)."""
    with _opened(path) as (f, version):
        read = _read_route if version >= 2 else _read_route_v1
        return {route: read(route, g) for route, g in _routes_group(f, path, case).items()}


def read_cases(path) -> list:
    """The soil cases of a results file (``orchestrator.design``), in run order; [] for a run of
    one soil (no ``/cases`` group)."""
    with _opened(path) as (f, _):
        return json.loads(f["cases"].attrs["names"]) if "cases" in f else []


def _routes_group(f, path, case):
    """The routes group of ``case`` (None: the top level; a case whose group has the attribute
    ``routes`` is stored there, the first case at the top level ``/routes``)."""
    if case is None:
        return f["routes"]
    names = json.loads(f["cases"].attrs["names"]) if "cases" in f else []
    if case not in names:
        raise ResultsFileError(f"{path} has no soil case {case!r} (cases: {', '.join(names) or 'none'}); "
                               "give one of them")
    return f[str(f[f"cases/{case}"].attrs.get("routes", f"/cases/{case}/routes"))]


def read_summary(path, case: str | None = None) -> dict:
    """``{route: summary}`` as stored in a results file (format_version 2): the dict that
    ``summary`` gives for each route, its numbers read from the file, not computed again
    (``case``: of that soil case)."""
    with _opened(path) as (f, version):
        if version < 2:
            raise ResultsFileError(f"{path} has no stored summary (format_version 1): "
                                   "summary(read_results(path)[route]) computes it, or run `uplift run` again")
        return {route: _stored_summary(g) for route, g in _routes_group(f, path, case).items()}


def open_results(path, group: str | None = None):
    """The results file in xarray, loaded (the file closed), after its checksum is verified: the
    ``xarray.DataTree`` of the whole file, or with ``group`` (e.g. ``"routes/winkler"``) that
    group's ``xarray.Dataset``. A file of format_version 1 (no dimension scales) is refused:
    ``read_results`` reads it."""
    import xarray as xr  # start-up cost (~0.5 s, pandas): only its users pay it
    with _opened(path) as (f, version):
        if version < 2:
            raise ResultsFileError(f"{path} has format_version 1 (no named dimensions): read it with "
                                   "read_results, or run `uplift run SCENE -o FILE` again for an xarray-ready file")
        if group is not None and group.strip("/") not in f:
            raise ResultsFileError(f"{path} has no group {group!r} (routes: {', '.join(f['routes'])}); "
                                   "give group='routes/<route>' or 'motion'")
    if group is None:
        with xr.open_datatree(path, engine="h5netcdf") as tree:
            return tree.load()
    with xr.open_dataset(path, group=group, engine="h5netcdf") as ds:
        return ds.load()


class _opened:
    """``with _opened(path) as (f, version)``: the results file open with h5py, its checksum
    verified, its format_version (1 without one) checked, at least one route in it; the errors of
    a bad file as ResultsFileError naming it (ChangedFileError for a changed one)."""

    def __init__(self, path):
        self.path = Path(path)
        self.f = None

    def __enter__(self):
        path = self.path
        if not path.is_file():
            raise ResultsFileError(f"results file {str(path)!r} does not exist: run `uplift run SCENE -o FILE` first")
        try:
            self.f = h5py.File(path, "r")
        except OSError as exc:   # h5py: not an HDF5 file, truncated file
            raise ResultsFileError(f"{path} is not a readable HDF5 results file ({exc}); "
                                   "run `uplift run SCENE -o FILE` to make one") from None
        try:
            require_checksum(self.f, path, REMEDY)
            version = _format_version(self.f, path)
            if "routes" not in self.f or not len(self.f["routes"]):
                raise ResultsFileError(f"{path} holds no routes (/routes/<route>): not a results file of "
                                       "`uplift run`; run `uplift run SCENE -o FILE` to make one")
        except BaseException:
            self.f.close()
            raise
        return self.f, version

    def __exit__(self, kind, exc, tb):
        self.f.close()
        if isinstance(exc, (ResultsFileError, ChangedFileError)) or exc is None:
            return False
        if isinstance(exc, OSError):
            raise ResultsFileError(f"{self.path} is not a readable HDF5 results file ({exc}); "
                                   "run `uplift run SCENE -o FILE` to make one") from None
        if isinstance(exc, (KeyError, TypeError, ValueError)):
            raise ResultsFileError(f"{self.path} does not have the results layout of `uplift run` ({exc}); "
                                   "see orchestrator/results_file.py") from None
        return False


def _format_version(f, path) -> int:
    """The file's format_version: 1 without the attribute (the layout before it), this code's
    FORMAT_VERSION or an older one; a newer or foreign one raises ResultsFileError."""
    stored = f.attrs.get("format_version")
    if stored is None:
        return 1
    try:
        version = int(stored)
    except (TypeError, ValueError):
        version = None
    if version is None or not 1 <= version <= FORMAT_VERSION:
        shown = stored.decode(errors="replace") if isinstance(stored, bytes) else getattr(stored, "item", lambda: stored)()
        raise ResultsFileError(f"{path} has format_version {shown!r}; this uplift reads results files of versions "
                               f"1 to {FORMAT_VERSION}: update uplift to read it, or run `uplift run SCENE -o FILE` "
                               "with this version")
    return version


def _labels(g, name) -> list:
    """The string coordinate ``name`` of group ``g`` as a list of str."""
    return [str(v) for v in g[name].asstr()[()]]


def _read_route(route, g) -> RouteResult:
    """A RouteResult from a route group of format_version 2."""
    kw = {"time": g["time"][()], "newton_iters": g["newton_iters"][()],
          "raft": np.concatenate([g["raft_translation"][()], g["raft_rotation"][()]], axis=1),
          **{name: g[name][()] for name in NODE_HISTORIES}}
    if "x" in g:
        kw["xy"] = np.column_stack([g["x"][()], g["y"][()]])
    if "plate_deflection" in g:
        kw.update(plate_deflection=g["plate_deflection"][()], plate_vertex_deflection=g["plate_vertex_deflection"][()],
                  plate_vertices=np.column_stack([g["plate_vertex_x"][()], g["plate_vertex_y"][()]]))
        if "plate_vertex_held" in g:
            kw["plate_vertex_held"] = g["plate_vertex_held"][()].astype(bool)
        if "plate_moment" in g:
            kw.update(plate_moment=g["plate_moment"][()], plate_moment_peak=g["plate_moment_peak"][()],
                      plate_moment_cells=g["base_cell"][()])
    for key, dim in (("acc", "output"), ("disp", "disp_output" if "disp_output" in g else "output")):
        if key in g:
            values = g[key][()]
            kw[key] = {name: values[:, i] for i, name in enumerate(_labels(g, dim))}
    if "energy" in g:
        values = g["energy"][()]
        kw["energy"] = {term: values[:, k] for k, term in enumerate(_labels(g, "energy_term"))}
    return _route_result(route, g, kw)


def _read_route_v1(route, g) -> RouteResult:
    """A RouteResult from a route group of format_version 1 (raft (nt, 6), xy (N, 2), the
    groups acc/<node>, disp/<node>, energy/<term>)."""
    kw = {key: g[key][()] for key in ARRAYS if key in g}
    kw.update({key: {k: v[()] for k, v in g[key].items()} for key in GROUPS if key in g})
    return _route_result(route, g, kw)


def _route_result(route, g, arrays: dict) -> RouteResult:
    a = g.attrs
    return RouteResult(route=str(a.get("route", route)), status=Status(str(a["status"])),
                       message=str(a.get("message", "")), wall_s=float(a.get("wall_s", 0.0)),
                       notes=RunNotes(**json.loads(a.get("notes", "{}"))), info=json.loads(a.get("info", "{}")),
                       **arrays)


def _stored_summary(g) -> dict:
    """The ``summary`` dict of a route group of format_version 2, from its stored numbers."""
    a = g.attrs
    number = lambda attr: float(a[attr])
    peaks = g["peak_acc"][()] if "peak_acc" in g else ()
    return {
        "status": str(a["status"]),
        "message": str(a["message"]),
        "components": [c for c in str(a["components"]).split(",") if c],
        "max_uplift_m": number("max_uplift_m"),
        "max_uplift_time_s": number("max_uplift_time_s"),
        "max_raft_rotation_rad": number("max_raft_rotation_rad"),
        "max_raft_rotation_axes_rad": {"x": number("max_raft_rotation_x_rad"), "y": number("max_raft_rotation_y_rad")},
        "min_contact_fraction": number("min_contact_fraction"),
        "peak_acc_g": {name: float(p / G) for name, p in zip(_labels(g, "output") if len(peaks) else (), peaks)},
        "wall_s": number("wall_s"),
        "converged": str(a["status"]) == Status.CONVERGED.value,
        **json.loads(a["notes"]),
    }


def read_motion(path):
    """(scene name, created, Motion or None) of a results file (its checksum verified; either
    format_version)."""
    with _opened(path) as (f, _):
        motion = None
        if "motion" in f:
            m = f["motion"]
            axes = tuple(a for a in str(m.attrs.get("components", "")).split(",") if a)
            motion = Motion(float(m.attrs["dt"]), m["acc"][()], str(m.attrs.get("label", "motion")), axes)
        return str(f.attrs.get("scene", "")), str(f.attrs.get("created", "")), motion


def read_scene_record(path) -> dict:
    """{"scene": name, "scene_toml": the scene as it ran ("" in a file written without it),
    "overrides": [the command line's overrides]} of a results file (its checksum verified)."""
    with h5py.File(path, "r") as f:
        require_checksum(f, path, REMEDY)
        return {"scene": str(f.attrs.get("scene", "")), "scene_toml": str(f.attrs.get("scene_toml", "")),
                "overrides": json.loads(f.attrs.get("overrides", "[]"))}


def summary(res) -> dict:
    """The per-route summary of ``uplift run --json`` (see the CLI docs). ``components``: the
    motion's components the route ran (``run_scene`` records them in the result's info; empty
    for a refused route); ``max_raft_rotation_rad``: the peak rocking magnitude
    sqrt(rx² + ry²), with the per-axis peaks |rx|, |ry| in ``max_raft_rotation_axes_rad``."""
    gap = np.asarray(res.gap)
    if gap.size:
        k = np.unravel_index(np.argmax(gap), gap.shape)
        max_uplift, t_uplift = float(gap[k]), float(res.time[k[0]])
        # the fraction of nodes in contact per step, count / N (the mean of the booleans, exactly)
        min_contact = float((np.count_nonzero(gap <= 0, axis=1) / gap.shape[1]).min())
    else:
        max_uplift, t_uplift, min_contact = 0.0, 0.0, 1.0
    rot = np.hypot(res.raft[:, 3], res.raft[:, 4])
    peak = lambda a: float(np.abs(a).max()) if a.size else 0.0
    return {
        "status": res.status.value,
        "message": res.message,
        "components": list(res.info.get("components", ())),
        "max_uplift_m": max_uplift,
        "max_uplift_time_s": t_uplift,
        "max_raft_rotation_rad": peak(rot),
        "max_raft_rotation_axes_rad": {"x": peak(res.raft[:, 3]), "y": peak(res.raft[:, 4])},
        "min_contact_fraction": min_contact,
        "peak_acc_g": {name: float(np.abs(a).max() / G) if a.size else 0.0 for name, a in res.acc.items()},
        "wall_s": float(res.wall_s),
        "converged": bool(res.converged),
        **res.notes.as_dict(),
    }
