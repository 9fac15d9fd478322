"""Native FMUs: the soil, the structure and the coupled system as compiled C code that needs no
Python in the host (the C runtime in fmus/native/, FMI 2.0 or FMI 3.0 co-simulation, C
standard library only).

``build_native_fmus(data, outdir, coupled)`` writes ``structure.fmu``, ``soil.fmu`` (and
``coupled.fmu``) with the variables, the coupling and the answers of the Python FMUs
(fmus/build.py): the same variable names, causalities, units and value references, the same
split coupling with the stamps x_time / g_time (fmus/coupling.py), the same discrete equations
(results equal to round-off). Each FMU holds

    modelDescription.xml    FMI 2.0: with <SourceFiles> (the C files of sources/)
    binaries/<platform>/<modelIdentifier>.<so|dll|dylib>   one runtime, compiled at export for
                            linux64, win64 and darwin64 (FMI 2.0 platform names; FMI 3.0:
                            x86_64-linux, x86_64-windows, x86_64-darwin, aarch64-darwin) by the
                            C compiler of the ``ziglang`` package (it cross-compiles), or by the
                            system compiler (``cc``, $CC) for the host platform only
    sources/*.c, *.h        the runtime's sources, so a tool can compile for another platform
                            (with the FMI headers of the tool); FMI 3.0: with
                            sources/buildDescription.xml
    resources/uplift.bin    the model data in the binary format of fmus/native/README.md

The two versions share the runtime (instance, model, variables, FMU states) and differ in the
entry layer (fmi2.c, fmi3.c) and the model description: FMI 3.0 declares the interface vectors
as arrays (fmus.schema.variables3: the gap DOFs over the structural parameter N) over the same
elements, which the resource record ``fmi3_float64`` maps.

What is a function of the model only is computed here, once, by the Python objects the
Python FMUs use: the structure's matrices, the static preload (P0, delta0) and the penalty
(``structure.NewmarkStepper``), the soil's poles and residues split into real poles and
conjugate pairs, and for the structure FMU the history gains Gx, Gv (fmus.coupling.history_gains);
the soil's passivity is verified here. The C code builds what depends on the step size (the
soil's recursion coefficients and D0, the condensed effective matrices) for dt and for each
step-halving level. Native FMUs run the recursive convolution of the rational model only
(the default soil factory).
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import struct
import subprocess
import sys
import tempfile
import zlib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fmus.coupling import history_gains
from fmus.resources import DEFAULT_SOIL_FACTORY, soil_from_model
from fmus.schema import ROLES, UNITS, slot_table, variables, variables3
from uplift_common.errors import ComputationError
from uplift_common.files import atomic_output
from uplift_common.lazy import lazy_module

# the FMU's description and archive: loaded when an FMU is built, not by a run of the in-process
# library (fmus.native_stepper reads this module's records and compiler)
ET = lazy_module("xml.etree.ElementTree")
uuid = lazy_module("uuid")
zipfile = lazy_module("zipfile")

if TYPE_CHECKING:
    from fmus.build import FmuData

NATIVE = Path(__file__).resolve().parent / "native"
#: the runtime's C files (fmus/native/) and its headers (fmus/native/include/, shipped beside the
#: C files in the FMU's sources/ so that a tool compiles them with no include path of ours):
#: the FMI 2.0 entry layer and the files both versions share
CORE = ("instance.c", "model.c", "variables.c", "state.c", "stepper.c", "soil.c", "linalg.c", "resources.c")
SOURCES = ("fmi2.c",) + CORE
#: the FMI 3.0 entry layer and the same files
SOURCES3 = ("fmi3.c",) + CORE
HEADERS = ("uplift.h", "fmu.h", "uplift_crc32.h", "uplift_messages.h", "uplift_schema.h")
RESOURCE_FILE = "uplift.bin"
#: FMI 2.0 platform -> (zig target, shared library suffix); glibc 2.17 for old Linux hosts
PLATFORMS = {"linux64": ("x86_64-linux-gnu.2.17", "so"), "win64": ("x86_64-windows-gnu", "dll"),
             "darwin64": ("x86_64-macos", "dylib")}
#: FMI 3.0 platform tuple -> (zig target, suffix): the same three and Apple silicon
PLATFORMS3 = {"x86_64-linux": ("x86_64-linux-gnu.2.17", "so"), "x86_64-windows": ("x86_64-windows-gnu", "dll"),
              "x86_64-darwin": ("x86_64-macos", "dylib"), "aarch64-darwin": ("aarch64-macos", "dylib")}
FMI_VERSIONS = (2, 3)
CFLAGS = ("-std=c99", "-O3", "-ffp-contract=off", "-fvisibility=hidden", "-fPIC", "-shared")
COMPILERS = ("zig", "cc")
#: the contact settings of the Newton iteration (structure.ContactSettings) a caller may override
NEWTON_KEYS = ("tol", "max_iter", "max_subdiv")


def role_class(role: str):
    """The Python FMU class of ``role``: its model name, identifier, description and author are
    reused. Imported on use (pythonfmu): stepping the runtime in process does not need it."""
    from fmus.coupled_fmu import UpliftCoupled
    from fmus.soil_fmu import UpliftSoil
    from fmus.structure_fmu import UpliftStructure
    return {"soil": UpliftSoil, "structure": UpliftStructure, "coupled": UpliftCoupled}[role]
MAGIC = b"UPLIFTNB"
VERSION = 1
KINDS = {"f8": 1, "i8": 2, "text": 3}


class NativeBuildError(ComputationError):
    """The C runtime could not be compiled (the message has the compiler's output)."""


# ---- the variables (fmus/schema.py) -----------------------------------------------------------
def layout(vars_: list) -> dict:
    """What the C runtime needs of the variables (fmus.schema.variables): n_real, the first value
    reference of each slot as the record ``vr.<slot>`` (-1 when absent; the runtime looks them up
    by name), the causality of each Real (0 input, 1 output), the Boolean's reference."""
    reals = [v for v in vars_ if v.type == "Real"]
    booleans = [v for v in vars_ if v.type == "Boolean"]
    return {"n_real": float(len(reals)),
            **{f"vr.{slot}": float(vr) for slot, vr in slot_table(vars_).items()},
            "causality": np.array([0 if v.causality == "input" else 1 for v in reals], np.int64),
            "vr_internal_motion": float(booleans[0].value_reference if booleans else -1)}


def layout3(vars_: list, vars3: list) -> dict:
    """``layout`` for the FMI 3.0 FMU: the same elements, the Boolean's FMI 3.0 value reference,
    the run of elements (first, length) of each Float64 variable in value-reference order
    (``fmi3_float64``), the value reference of the structural parameter N (``fmi3_vr_N``)."""
    floats = [v for v in vars3 if v.type == "Float64"]
    if [v.value_reference for v in floats] != list(range(len(floats))):
        raise ValueError("the FMI 3.0 Float64 variables must have the value references 0, 1, ...")
    ref = {v.type: v.value_reference for v in vars3 if v.type != "Float64"}
    return {**layout(vars_), "vr_internal_motion": float(ref.get("Boolean", -1)),
            "fmi3_float64": np.array([(v.first, v.length) for v in floats], np.int64).reshape(-1, 2),
            "fmi3_vr_N": float(ref["UInt64"])}


# ---- the binary resource file -----------------------------------------------------------------
def encode_resources(records: dict) -> bytes:
    """The bytes of a resource file (fmus/native/README.md): ``records`` maps a name (<= 32
    ASCII characters) to a float (a float64 scalar), a str (UTF-8 text), or an ndarray of
    float64 or int64 (up to 4 dimensions, C order). An array already of its record's type and C
    order is not copied before the one copy into the result."""
    parts, size, crc = [], 0, 0
    for name, value in records.items():
        key = name.encode("ascii")
        if len(key) > 32:
            raise ValueError(f"resource record name {name!r} is longer than 32 characters")
        if isinstance(value, str):
            kind, dims, data = KINDS["text"], (len(value.encode()),), value.encode()
        else:
            arr = np.asarray(value)
            if arr.dtype.kind in "iub":
                arr = arr.astype("<i8", copy=False)
                kind = KINDS["i8"]
            else:
                arr = arr.astype("<f8", copy=False)
                kind = KINDS["f8"]
            if arr.ndim > 4:
                raise ValueError(f"resource record {name!r} has {arr.ndim} dimensions (at most 4)")
            dims, data = arr.shape, np.ascontiguousarray(arr).reshape(-1).view(np.uint8)
        for part in (key.ljust(32, b"\0") + struct.pack("<II", kind, len(dims))
                     + struct.pack("<4Q", *(tuple(dims) + (0,) * (4 - len(dims)))) + struct.pack("<Q", len(data)),
                     data, b"\0" * (-len(data) % 8)):
            parts.append(part)
            crc = zlib.crc32(part, crc)
            size += len(part)
    return b"".join([MAGIC, struct.pack("<IIQII", VERSION, len(records), 32 + size, crc, 0), *parts])


def decode_resources(data: bytes) -> dict:
    """The records of a resource file (the reverse of encode_resources; checks as the C reader)."""
    if data[:8] != MAGIC:
        raise ValueError("not an uplift resource file (magic)")
    version, count, size, checksum = struct.unpack_from("<IIQI", data, 8)
    if version != VERSION or size != len(data) or checksum != zlib.crc32(data[32:]):
        raise ValueError("uplift resource file: wrong version, size or checksum")
    out, off = {}, 32
    for _ in range(count):
        name = data[off:off + 32].rstrip(b"\0").decode("ascii")
        kind, ndim = struct.unpack_from("<II", data, off + 32)
        dims = struct.unpack_from("<4Q", data, off + 40)[:ndim]
        (nbytes,) = struct.unpack_from("<Q", data, off + 72)
        raw = data[off + 80:off + 80 + nbytes]
        off += 80 + nbytes + (-nbytes % 8)
        if kind == KINDS["text"]:
            out[name] = raw.decode()
        else:
            arr = np.frombuffer(raw, "<f8" if kind == KINDS["f8"] else "<i8").reshape(dims)
            out[name] = arr.item() if ndim == 0 else arr.copy()
    return out


# ---- compiling the runtime ----------------------------------------------------------------------
def fmi_headers() -> Path:
    """The folder of the FMI 2.0 and 3.0 headers (fmi2Functions.h, fmi3Functions.h ...), shipped by fmpy."""
    import fmpy                        # a dependency of the project; only its C headers are used
    folder = Path(fmpy.__file__).resolve().parent / "c-code"
    if not all((folder / h).is_file() for h in ("fmi2Functions.h", "fmi3Functions.h")):
        raise NativeBuildError(f"the FMI headers are not in {folder}: reinstall fmpy (pip install fmpy)")
    return folder


def _version(fmi_version) -> int:
    if fmi_version not in FMI_VERSIONS:
        raise ValueError(f"fmi_version = {fmi_version!r}: use one of {', '.join(map(str, FMI_VERSIONS))}")
    return int(fmi_version)


def platforms_of(fmi_version: int = 2) -> dict:
    """{platform name of the FMI version: (zig target, library suffix)}."""
    return PLATFORMS if _version(fmi_version) == 2 else PLATFORMS3


def sources_of(fmi_version: int = 2) -> tuple:
    """The C files of the runtime of the FMI version (its entry layer and the shared files)."""
    return SOURCES if _version(fmi_version) == 2 else SOURCES3


def host_platform(fmi_version: int = 2) -> str:
    """The platform name (FMI 2.0: linux64 ...; FMI 3.0: x86_64-linux ...) of this machine (the one
    the system compiler builds for)."""
    import platform as _platform
    if _version(fmi_version) == 2:
        name = {"linux": "linux64", "darwin": "darwin64", "win32": "win64"}.get(sys.platform)
    else:
        arch = {"x86_64": "x86_64", "amd64": "x86_64", "arm64": "aarch64", "aarch64": "aarch64"}.get(
            _platform.machine().lower())
        system = {"linux": "linux", "darwin": "darwin", "win32": "windows"}.get(sys.platform)
        name = f"{arch}-{system}" if arch and system else None
    table = platforms_of(fmi_version)
    if name not in table:
        raise ValueError(f"the host platform {sys.platform!r} is none of {', '.join(table)}")
    return name


def compile_runtime(platforms=None, compiler: str = "zig", fmi_version: int = 2, sources=None,
                    progress=None) -> dict:
    """{platform: bytes of the shared library} of the C runtime of ``fmi_version`` for
    ``platforms`` (names of that version, default: all of platforms_of(fmi_version));
    ``sources``: its C files in fmus/native/ (default: those of the FMUs, sources_of);
    ``progress(done, total, platform)`` (orchestrator.progress's protocol) after each platform.

    compiler "zig": the C compiler of the ``ziglang`` package (cross-compiles to every platform;
    its cache makes a repeated build ~0.3 s, the first one per platform takes seconds to a
    minute while it builds that platform's C library stubs); "cc": the system compiler ($CC,
    else cc) for the host platform only."""
    table = platforms_of(fmi_version)
    platforms = tuple(table) if platforms is None else tuple(platforms)
    if compiler not in COMPILERS:
        raise ValueError(f"compiler = {compiler!r}: use one of {', '.join(COMPILERS)}")
    bad = [p for p in platforms if p not in table]
    if bad or not platforms:
        raise ValueError(f"platforms {bad or '(none)'}: give some of {', '.join(table)}")
    if compiler == "cc" and set(platforms) != {host_platform(fmi_version)}:
        raise ValueError(f"compiler = 'cc' builds for the host platform ({host_platform(fmi_version)}) only: use "
                         "compiler = 'zig' to cross-compile")
    include = fmi_headers()
    sources = [str(NATIVE / s) for s in (sources or sources_of(fmi_version))]
    out = {}
    with tempfile.TemporaryDirectory(prefix="uplift_native_") as tmp:
        for platform in platforms:
            target, suffix = table[platform]
            lib = Path(tmp) / f"uplift.{suffix}"
            if compiler == "zig":
                cmd = [sys.executable, "-m", "ziglang", "cc", "-target", target, "-s"]
            else:
                cmd = [os.environ.get("CC", "cc")]
            cmd += [*CFLAGS, f"-I{include}", f"-I{NATIVE / 'include'}", "-o", str(lib), *sources, "-lm"]
            try:
                proc = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, timeout=900)
            except FileNotFoundError as exc:
                raise NativeBuildError(f"no C compiler {cmd[0]!r} ({exc}): pip install ziglang, or set $CC") from None
            if proc.returncode != 0 or not lib.is_file():
                hint = (" (pip install ziglang: a dependency of uplift)" if "No module named ziglang" in proc.stderr
                        else "")
                raise NativeBuildError(f"compiling the native FMU runtime for {platform} failed{hint}:\n"
                                       f"{' '.join(cmd)}\n{proc.stderr[-4000:]}")
            out[platform] = lib.read_bytes()
            if progress is not None:
                progress(len(out), len(platforms), platform)
    return out


# ---- the model data of each role ----------------------------------------------------------------
def model_records(data: FmuData, newton: dict | None = None) -> dict:
    """{role: resource records without the layout and the GUID}: the soil model for every role,
    the structure's matrices, static state and settings for the structure and the coupled
    FMUs, the history gains for the structure FMU. Verifies the soil's passivity (once)."""
    from structure import NewmarkStepper
    from structure.spec import contact_from_spec, model_from_spec

    if data.soil_factory != DEFAULT_SOIL_FACTORY:
        raise ValueError(f"soil factory {data.soil_factory!r}: native FMUs run the recursive convolution of the "
                         f"rational model ({DEFAULT_SOIL_FACTORY}) only; export with kind = 'python' for another soil")
    unknown = set(newton or {}) - set(NEWTON_KEYS)
    if unknown:
        raise ValueError(f"newton keys {sorted(unknown)}: allowed {', '.join(NEWTON_KEYS)}")
    dt = float(data.dt)
    n, N = data.soil_model.n, np.asarray(data.xy).shape[0]
    if n != 6 + N:
        raise ValueError(f"the soil model has {n} DOFs, the interface needs 6 + N = {6 + N}")
    soil = soil_from_model(data.soil_model, dt, DEFAULT_SOIL_FACTORY, data.soil_kwargs)     # verifies passivity
    contact = dataclasses.replace(contact_from_spec(data.contact), **(newton or {}))
    model = model_from_spec(data.structure, data.xy, data.area)
    cls = NewmarkStepper
    if getattr(data, "plate", None) is not None:        # a plate raft: the PlateRaftModel the Python FMU rebuilds
        from fmus.build import plate_arrays
        from fmus.stepper import plate_model
        from structure.plate_raft import PlateStepper
        model, cls = plate_model(model, data.plate["properties"], plate_arrays(data.plate)), PlateStepper
    st = cls(model, soil, dt, contact=contact, damping=data.damping, alpha=float(data.alpha), external_soil=True)
    nodes = [model.dofs(model.node_by_name(nm).id)[:3] for nm in data.output_nodes]
    common = soil_records(soil.model, dt, soil.compressed)        # the model the soil runs (compressed or not)
    stepper = {**common, **stepper_records(st, nodes)}
    if data.motion is not None:
        stepper["motion"] = np.asarray(data.motion, float).reshape(-1, 3)
    Gx, Gv = history_gains(soil, dt)
    role = {r: float(ROLES.index(r)) for r in ROLES}                  # the runtime's ROLE_* (uplift_schema.h)
    return {"soil": {**common, "role": role["soil"]}, "structure": {**stepper, "role": role["structure"], "Gx": Gx,
                                                                    "Gv": Gv},
            "coupled": {**stepper, "role": role["coupled"]}}


def soil_records(soil_model, dt: float, compressed=None) -> dict:
    """The soil's records (every role): dt, n_dof, the poles split into real poles and one pole
    per conjugate pair, their residues, D and E; with ``compressed`` (a
    soil_impedance.hhistory.CompressedHistory of ``soil_model``'s history blocks: a soil built
    with history = "hmatrix") its records hm_*, from which the runtime takes the history product."""
    n = soil_model.n
    pr, Rr, pc, Rc = soil_model.pole_split
    out = {"dt": float(dt), "n_dof": float(n), "poles_real": pr,
           "poles_pair": _interleaved(pc).reshape(-1, 2),
           "residues_real": Rr, "residues_pair": _interleaved(Rc).reshape(-1, n, n, 2),
           "D": soil_model.D, "E": soil_model.E}
    if compressed is not None:
        out.update(compressed.records())
    return out


def _interleaved(z) -> np.ndarray:
    """(..., 2) float64: the real and imaginary parts of the complex array ``z`` side by side
    (``np.stack([z.real, z.imag], -1)``): the float view of z's own memory when it is a C-ordered
    complex128 array (the same numbers, not copied)."""
    z = np.asarray(z)
    if z.dtype == np.complex128 and z.flags.c_contiguous:
        return z.view(np.float64).reshape(z.shape + (2,))
    return np.stack([z.real, z.imag], -1)


def stepper_records(st, node_dofs) -> dict:
    """The structure's records (structure and coupled roles) from a ``structure.NewmarkStepper``
    (its matrices, static state, penalty and contact settings: the C stepper steps the same
    equations) and the DOFs (ux, uy, uz) of the output nodes, (nodes, 3)."""
    contact = st.contact
    if not 0 <= contact.max_subdiv <= 30 or contact.max_iter < 1:
        raise ValueError(f"newton: max_subdiv = {contact.max_subdiv} must lie in [0, 30] and max_iter = "
                         f"{contact.max_iter} be >= 1")
    ns = st.ns
    dense = lambda a: np.asarray(a[:ns, :ns].toarray(), float)
    plate = st.Bq3 is None                      # structure.plate_raft.PlateStepper: a plate raft
    return {"ns": float(ns), "N": float(st.N), "alpha": st.alpha,
            "contact_enabled": float(contact.enabled), "contact_tol": float(contact.tol),
            "contact_max_iter": float(contact.max_iter), "contact_max_subdiv": float(contact.max_subdiv),
            "M": st.M, "Ks": dense(st.Ks), "Cs": dense(st.Cs), "Mr": st.Mr[:ns],
            "Bq3": np.zeros((st.N, 3)) if plate else st.Bq3, "kp": st.kp,
            "P0": st.P0, "delta0": st.delta0, "node_dofs": np.array(node_dofs, np.int64).reshape(-1, 3),
            **(plate_records(st) if plate else {})}


def plate_records(st) -> dict:
    """A plate raft's records (``structure.plate_raft.PlateStepper``): ``plate_nf`` the free
    vertices (their deflections t in the boundary block [q, t, w]), ``plate_trace_col`` int64 and
    ``plate_trace_val`` float64 (N, w): each node's trace on [q, t] (the slaved vertices through
    q[2:5], the free ones through t; column -1 pads), the contact d_i = trace_i - w_i (the rows of
    ``st.Bc``, whose part on w must be -I)."""
    Bc = st.Bc.tocsr()
    Bc.sum_duplicates()
    nq = 6 + st.model.nf
    rows = []
    for i in range(st.N):
        c, v = Bc.indices[Bc.indptr[i]:Bc.indptr[i + 1]], Bc.data[Bc.indptr[i]:Bc.indptr[i + 1]]
        on = c < nq
        if not (np.array_equal(c[~on], [nq + i]) and np.array_equal(v[~on], [-1.0])):
            raise ValueError(f"the plate's contact operator's row {i} is not (trace on [q, t]) - w_{i}")
        rows.append((c[on], v[on]))
    width = max([len(c) for c, _ in rows] + [1])
    col = np.full((st.N, width), -1, np.int64)
    val = np.zeros((st.N, width))
    for i, (c, v) in enumerate(rows):
        col[i, :len(c)], val[i, :len(c)] = c, v
    return {"plate_nf": float(st.model.nf), "plate_trace_col": col, "plate_trace_val": val}


# ---- the model description ---------------------------------------------------------------------
def _common_elements(root, vars_, dt: float, stop_time) -> None:
    """UnitDefinitions, LogCategories and DefaultExperiment, the same in both versions."""
    units = list(dict.fromkeys(v.unit for v in vars_ if v.unit))
    defs = ET.SubElement(root, "UnitDefinitions")
    for unit in units:
        ET.SubElement(ET.SubElement(defs, "Unit", name=unit), "BaseUnit", {k: str(e) for k, e in UNITS[unit].items()})
    cats = ET.SubElement(root, "LogCategories")
    ET.SubElement(cats, "Category", name="logEvents", description="events: instantiation, steps (when logging is on)")
    ET.SubElement(cats, "Category", name="logStatusError", description="errors: refused calls and failed steps")
    ex = {"startTime": "0.0", "stepSize": repr(float(dt))}
    if stop_time is not None:
        ex["stopTime"] = repr(float(stop_time))
    ET.SubElement(root, "DefaultExperiment", ex)


def model_description(role: str, guid: str, vars_: list, dt: float, stop_time) -> bytes:
    """modelDescription.xml of a native FMI 2.0 FMU: the Python FMU's variables, units, model
    structure (outputs without direct feedthrough) and default experiment, CoSimulation with
    SourceFiles."""
    cls = role_class(role)
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": cls.__name__, "guid": guid, "description": cls.description,
        "author": cls.author, "generationTool": "uplift native (fmus/native_build.py)",
        "variableNamingConvention": "structured", "numberOfEventIndicators": "0"})
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": cls.__name__, "needsExecutionTool": "false",
        "canHandleVariableCommunicationStepSize": "false", "canInterpolateInputs": "false",
        "maxOutputDerivativeOrder": "0", "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true",
        "providesDirectionalDerivative": "false"})
    files = ET.SubElement(cs, "SourceFiles")
    for src in SOURCES:
        ET.SubElement(files, "File", name=src)
    _common_elements(root, vars_, dt, stop_time)
    mv = ET.SubElement(root, "ModelVariables")
    outputs = []
    for k, v in enumerate(vars_, start=1):
        attrs = {"name": v.name, "valueReference": str(v.value_reference),
                 "description": v.description, "causality": v.causality}
        if v.variability:
            attrs["variability"] = v.variability
        if v.causality == "output":
            attrs["initial"] = "calculated"
            outputs.append(k)
        sv = ET.SubElement(mv, "ScalarVariable", attrs)
        typed = {}
        if v.start is not None:
            typed["start"] = v.start
        if v.unit:
            typed["unit"] = v.unit
        ET.SubElement(sv, v.type, typed)
    ms = ET.SubElement(root, "ModelStructure")
    for tag in ("Outputs", "InitialUnknowns"):
        node = ET.SubElement(ms, tag)
        for k in outputs:
            ET.SubElement(node, "Unknown", index=str(k), dependencies="")
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def model_description3(role: str, token: str, vars3: list, dt: float, stop_time) -> bytes:
    """modelDescription.xml of a native FMI 3.0 FMU: the variables of fmus.schema.variables3
    (arrays with a <Dimension>: a fixed length, or the structural parameter N), the units and
    the default experiment of the FMI 2.0 FMU, co-simulation only (no event mode, no early
    return, no intermediate update), outputs without direct feedthrough."""
    cls = role_class(role)
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0", "modelName": cls.__name__, "instantiationToken": token,
        "description": cls.description, "author": cls.author,
        "generationTool": "uplift native (fmus/native_build.py)", "variableNamingConvention": "structured"})
    ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": cls.__name__, "needsExecutionTool": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canGetAndSetFMUState": "true",
        "canSerializeFMUState": "true", "providesDirectionalDerivatives": "false",
        "providesAdjointDerivatives": "false", "providesPerElementDependencies": "false",
        "canHandleVariableCommunicationStepSize": "false", "fixedInternalStepSize": repr(float(dt)),
        "maxOutputDerivativeOrder": "0", "providesIntermediateUpdate": "false",
        "mightReturnEarlyFromDoStep": "false", "canReturnEarlyAfterIntermediateUpdate": "false",
        "hasEventMode": "false", "providesEvaluateDiscreteStates": "false"})
    _common_elements(root, vars3, dt, stop_time)
    mv = ET.SubElement(root, "ModelVariables")
    vr_n = next(v.value_reference for v in vars3 if v.name == "N")
    for v in vars3:
        attrs = {"name": v.name, "valueReference": str(v.value_reference), "description": v.description,
                 "causality": v.causality}
        if v.variability:
            attrs["variability"] = v.variability
        elif v.type == "Float64":
            attrs["variability"] = "continuous"
        if v.causality == "output":
            attrs["initial"] = "calculated"
        if v.start is not None:
            attrs["start"] = v.start
        if v.unit:
            attrs["unit"] = v.unit
        el = ET.SubElement(mv, v.type, attrs)
        if v.dimension == "N":
            ET.SubElement(el, "Dimension", valueReference=str(vr_n))
        elif v.dimension is not None:
            ET.SubElement(el, "Dimension", start=str(v.dimension))
    ms = ET.SubElement(root, "ModelStructure")
    for tag in ("Output", "InitialUnknown"):
        for v in vars3:
            if v.causality == "output":
                ET.SubElement(ms, tag, valueReference=str(v.value_reference), dependencies="")
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def build_description(identifier: str) -> bytes:
    """sources/buildDescription.xml of an FMI 3.0 FMU: the C files of the runtime, C99, libm."""
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    conf = ET.SubElement(root, "BuildConfiguration", modelIdentifier=identifier,
                         description="the native uplift runtime: C99 and the C standard library (libc, libm)")
    files = ET.SubElement(conf, "SourceFileSet", language="C99")
    for src in SOURCES3:
        ET.SubElement(files, "SourceFile", name=src)
    ET.SubElement(conf, "Library", name="m", description="libm (on platforms with a separate math library)")
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


# ---- the FMUs -------------------------------------------------------------------------------------
def build_native_fmus(data: FmuData, outdir, coupled: bool = False, *, platforms=None,
                      compiler: str = "zig", newton: dict | None = None, fmi_version: int = 2,
                      binaries: dict | None = None, progress=None) -> dict:
    """Write ``outdir/structure.fmu`` and ``outdir/soil.fmu`` (and ``coupled.fmu`` if ``coupled``)
    as native FMUs; returns ``{"structure": path, "soil": path[, "coupled": path]}`` as
    fmus.build.build_fmus does.

    platforms : platform names of the FMI version to compile for (default: all of
                platforms_of(fmi_version): FMI 2.0 linux64, win64, darwin64; FMI 3.0
                x86_64-linux, x86_64-windows, x86_64-darwin, aarch64-darwin)
    compiler : "zig" (the ziglang package, cross-compiles) or "cc" (system compiler, host only)
    newton : overrides of the contact Newton settings {tol, max_iter, max_subdiv} (the scene
             tables leave them at structure.ContactSettings' defaults, as the Python FMUs do)
    fmi_version : 2 (FMI 2.0, scalar variables) or 3 (FMI 3.0, arrays): the same runtime and
                  answers
    binaries : {platform: bytes} the runtime already compiled (e.g. fmus.native_stepper.fmu_binaries,
               cached per content hash), instead of compiling it here
    progress : ``progress(done, total, platform)`` after each platform compiled (compile_runtime)
    """
    version = _version(fmi_version)
    outdir = Path(outdir)
    records = model_records(data, newton)
    binaries = binaries or compile_runtime(platforms, compiler, version, progress=progress)
    n, N = data.soil_model.n, np.asarray(data.xy).shape[0]
    stop = None if data.motion is None else (np.asarray(data.motion).shape[0] - 1) * float(data.dt)
    roles = ("structure", "soil") + (("coupled",) if coupled else ())
    outdir.mkdir(parents=True, exist_ok=True)
    out = {}
    for role in roles:
        vars_ = variables(role, n, N, data.output_nodes, data.motion is not None)
        if version == 2:
            recs = {**records[role], **layout(vars_)}
            md, key = model_description(role, "", vars_, data.dt, stop), "guid"
        else:
            vars3 = variables3(role, n, N, data.output_nodes, data.motion is not None)
            recs = {**records[role], **layout3(vars_, vars3)}
            md, key = model_description3(role, "", vars3, data.dt, stop), "instantiationToken"
        payload = encode_resources(recs)
        guid = str(uuid.UUID(bytes=hashlib.sha256(payload + md).digest()[:16], version=4))
        if version == 3:
            guid = "{" + guid + "}"
        # the token into the description hashed without it: the root element's attribute, written
        # first (an attribute value cannot hold the quotes: they are escaped)
        md = md.replace(f'{key}=""'.encode(), f'{key}="{guid}"'.encode(), 1)
        out[role] = _zip(outdir / f"{role}.fmu", role_class(role).__name__, md,
                         encode_resources({"guid": guid, **recs}), binaries, version)
    return out


def _zip(path: Path, identifier: str, md: bytes, resources: bytes, binaries: dict, fmi_version: int = 2) -> Path:
    """The FMU archive, written atomically, with fixed member dates (same inputs, same bytes)."""
    def add(z, name, blob, method=zipfile.ZIP_DEFLATED):
        info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
        info.compress_type = method
        info.external_attr = 0o644 << 16
        z.writestr(info, blob)

    table = platforms_of(fmi_version)
    with atomic_output(path) as tmp, zipfile.ZipFile(tmp, "w") as z:
        add(z, "modelDescription.xml", md)
        for platform, blob in binaries.items():
            add(z, f"binaries/{platform}/{identifier}.{table[platform][1]}", blob)
        for src in sources_of(fmi_version):
            add(z, f"sources/{src}", (NATIVE / src).read_bytes())
        for header in HEADERS:
            add(z, f"sources/{header}", (NATIVE / "include" / header).read_bytes())
        if fmi_version == 3:
            add(z, "sources/buildDescription.xml", build_description(identifier))
        add(z, f"resources/{RESOURCE_FILE}", resources, zipfile.ZIP_STORED)   # read at every instantiation
    return path
