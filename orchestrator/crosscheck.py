"""``uplift export SCENE -o DIR --cross-check XDIR``: the exported FMUs as test FMUs of the FMI
cross-check (github.com/modelica/fmi-cross-check, rules 4.1), with their reference results.

``write_cross_check(exported, xdir)`` writes, for each FMU (Model = structure, soil, coupled)::

    xdir/fmus/<2.0 | 3.0>/cs/<platform>/uplift/<version>/<Model>/
        <Model>.fmu       a copy of the exported FMU
        <Model>_ref.opt   StartTime, StopTime, StepSize, RelTol, OutputIntervalLength: the FMU's
                          DefaultExperiment (fixed step dt from 0 to the end of the motion)
        <Model>_in.csv    every input of the FMU at every communication point t = k dt
        <Model>_ref.csv   the headline outputs at the same points
        README.md         what the FMU is, what drives it, how the files were made

<platform> is the host's (FMI 2.0: fmpy.platform, e.g. linux64; FMI 3.0: fmpy.platform_tuple,
e.g. x86_64-linux): the reference is that host's run. <version> is the installed uplift's. In
the FMI 3.0 folders an array variable is one CSV column of space-separated values (fmpy's
read_csv reads it as an array).

The reference run. The pair (structure.fmu, soil.fmu) is run under a parallel (Jacobi) master:
before the step from t each FMU is given the other's outputs at t, which are exactly the rows at
t of its ``_in.csv``; coupled.fmu is run alone. Every FMU keeps its default parameters, as a
cross-check importer does (it cannot set any): the structure and the coupled FMUs run on the
motion bundled in them (internal_motion = true) and do not read their inputs ``ag_x``, ``ag_y``,
``ag_z``. Those columns hold a_g(t + dt) of that motion (zero after its end), the FMUs' convention.
A replay of ``_in.csv`` (inputs held at the rows' values, read at the communication points)
through one FMU alone reproduces its ``_ref.csv`` (bit for bit on the exporting host): the pair
is exact under Jacobi (fmus/coupling.py), and the coupled FMU is the monolithic step.

``check_cross_check(xdir)`` returns what fmpy's checker (``fmpy.cross_check.validate_vendor_repo``)
finds in the folder (its repository walk knows FMI 1.0 and 2.0 only: the FMI 3.0 folders are
given to its per-folder check, ``validate_test_fmu``), plus a run longer than fmpy's cross-check
runner can step (see ``FMPY_MAX_INTERVALS``); ``write_cross_check`` returns the same list with
the paths.
"""
from __future__ import annotations

import importlib.metadata
import io
import platform as _platform
import shutil
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy
from fmpy import platform as FMPY_PLATFORM, platform_tuple as FMPY_PLATFORM_TUPLE, read_model_description
from fmpy.cross_check.validate_vendor_repo import validate_repo, validate_test_fmu
from fmpy.util import read_ref_opt_file

from fmus.resources import MOTION_FILE
from fmus.schema import AG, vector3
from fmus.native_build import RESOURCE_FILE, decode_resources
from uplift_common.files import atomic_folder, atomic_output

from orchestrator.export import HEADLINE, Export
from orchestrator.master import FmuSlave

TOOL = "uplift"
#: the distribution whose version names the cross-check folder
DISTRIBUTION = "uplift-ssi"
#: the soil's _ref.csv: its history force g on the SOIL_REFERENCE_DOFS DOFs of largest peak (what
#: it sends the structure; a component at round-off level would make a meaningless reference)
#: and its dissipated energy; the structure's and the coupled FMU's: the headline outputs
SOIL_REFERENCE_DOFS = 6
#: the FMUs ignore a tolerance (fixed step); this is the relative agreement a replay reaches
REL_TOL = 1e-8
#: fmpy's cross-check runner (python -m fmpy.cross_check --simulate) passes no output interval to
#: simulate_fmu, which then doubles the DefaultExperiment's step until the run has at most this
#: many intervals: past it the FMU is stepped at 2 dt and refuses the step
FMPY_MAX_INTERVALS = 1000

README = """\
# {model}: {description}

FMI {fmi} co-simulation FMU exported by `uplift export` (uplift {version}){scene}. {runtime}

## Experiment (`{model}_ref.opt`)

Fixed communication step StepSize = {dt!r} s from StartTime = 0 to StopTime = {stop!r} s ({steps}
steps): the FMU's DefaultExperiment. The FMU refuses another step size or start time. It ignores
a tolerance; RelTol is the relative agreement a replay of `{model}_in.csv` reaches with
`{model}_ref.csv`.

## Inputs (`{model}_in.csv`)

One row per communication point t = k dt, set before the step from t.

{inputs}

## Reference (`{model}_ref.csv`)

{outputs}

Computed with the FMU's default parameters ({how}) on {platform}, Python {python}, numpy {numpy},
scipy {scipy}.
"""
AG_TEXT = ("- `ag_x`, `ag_y`, `ag_z` (m/s2): a_g(t + dt), the ground acceleration along x, y, z at the end\n"
           "  of the coming step, of the motion bundled in the FMU (its components; zero past its end). Read\n"
           "  only when the parameter `internal_motion` is false; by default (true, as here) the bundled\n"
           "  motion drives the FMU. With internal_motion = false the FMU also reads them at initialisation\n"
           "  as a_g(0), which the row at t = 0 gives as a_g(dt): such a replay differs unless a_g(0) = a_g(dt).")
INPUTS = {
    "structure": "- `g[0..n-1]` (N, N.m), `g_time` (s): the soil FMU's outputs at t (its history force for\n"
                 "  the structure's step from t, stamped g_time = t).\n" + AG_TEXT,
    "soil": "- `x[0..n-1]` (m, rad), `xdot[0..n-1]` (m/s, rad/s), `x_time` (s): the structure FMU's\n"
            "  outputs at t, the interface displacements and velocities [q, w] (q: raft ux, uy, uz, rx,\n"
            "  ry, rz; w: the vertical gap DOF of each interface node), stamped x_time = t.",
    "coupled": AG_TEXT,
}
#: what runs an FMU of each kind (the README's words)
RUNTIME = {"python": "A pythonfmu FMU:\nit runs in the host's Python (3.10 or later, with the packages of the FMU's\n"
                     "`resources/requirements.txt`: numpy, scipy, h5py, threadpoolctl).",
           "native": "A native FMU:\ncompiled C (the C standard library only), no Python needed in the host; the\n"
                     "sources are in the FMU."}
#: the FMI 3.0 FMUs' interface vectors as arrays (fmus.schema.variables3)
ARRAYS3 = ("In this FMI 3.0 FMU each vector [q, w] is three arrays: `<v>_raft_u` (3: the raft's ux, uy,\n"
           "uz), `<v>_raft_r` (3: rx, ry, rz) and `<v>_w` (N, the structural parameter: the gap DOFs), one\n"
           "CSV column each, values separated by spaces.")
HEADLINE_TEXT = ("`max_uplift` (m): running maximum of the uplift over the interface nodes;\n"
                 "`max_raft_rotation` (rad): running maximum of the raft rotation hypot(rx, ry).")
SOIL_TEXT = ("`{names}` (N, N.m for the rotations g[3..5]): the soil's history force for the structure's\n"
             "next step without the part driven by the structure's latest state, on the {k} DOFs of\n"
             "[q, w] with the largest peak{energy}.")
SOIL_TEXT3 = ("`{names}` (N, N.m): the soil's history force on the raft (translations, rotations) for the\n"
              "structure's next step without the part driven by the structure's latest state{energy}.")
PAIR = ("the pair structure.fmu + soil.fmu under a parallel (Jacobi) master, each FMU given the other's\n"
        "outputs at t, the rows of its `_in.csv`, before the step from t")
HOW = {"structure": PAIR, "soil": PAIR,
       "coupled": "coupled.fmu alone; it equals the pair's structure reference to round-off"}


@dataclass(frozen=True)
class CrossCheck:
    """What write_cross_check wrote: the repository root, each model's folder (model name ->
    Path) and what fmpy's checker (and the step-count check) reports, empty when compliant."""
    root: Path
    models: dict
    problems: tuple


def tool_version() -> str:
    """The installed uplift's version (it names the cross-check folder)."""
    try:
        return importlib.metadata.version(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        raise ValueError("uplift is not installed, and the cross-check folder is named by its version: "
                         "pip install -e . in the project's folder") from None


def model_folder(xdir, model: str, fmi_version: int = 2) -> Path:
    """``xdir/fmus/<2.0|3.0>/cs/<platform>/uplift/<version>/<model>``: the cross-check folder of a
    model (platform: FMI 2.0 linux64 ..., FMI 3.0 x86_64-linux ...)."""
    platform = FMPY_PLATFORM_TUPLE if fmi_version == 3 else FMPY_PLATFORM
    return Path(xdir, "fmus", f"{fmi_version}.0", "cs", platform, TOOL, tool_version(), model)


def bundled_motion_ahead(structure_fmu, nt: int) -> np.ndarray:
    """(nt, 3) m/s^2: row k is a_g(t_k + dt) of the motion bundled in ``structure_fmu`` (zero past
    its end), what the FMU's inputs ``ag_x``, ``ag_y``, ``ag_z`` mean at the communication point t_k."""
    with zipfile.ZipFile(structure_fmu) as z:
        names = z.namelist()
        if f"resources/{MOTION_FILE}" in names:                     # a pythonfmu FMU
            with np.load(io.BytesIO(z.read(f"resources/{MOTION_FILE}")), allow_pickle=False) as m:
                acc = np.asarray(m["acc"], float)
        elif f"resources/{RESOURCE_FILE}" in names:                 # a native FMU
            acc = decode_resources(z.read(f"resources/{RESOURCE_FILE}")).get("motion")
        else:
            acc = None
    if acc is None:
        raise ValueError(f"{structure_fmu} bundles no motion: export it with one "
                         "(orchestrator.export.export_scene always does)")
    acc = np.asarray(acc, float).reshape(-1, 3)
    ahead = np.zeros((nt, 3))
    ahead[:min(nt, acc.shape[0] - 1)] = acc[1:nt + 1]
    return ahead


def _names(slave: FmuSlave, vectors) -> list:
    """(variable name, number of values) in the order of ``slave.get(*vectors)``: FMI 2.0 scalars,
    FMI 3.0 scalars and arrays."""
    group = vector3 if slave.version == 3 else (lambda name: name.split("[")[0])
    return [(v.name, slave._length(v)) for vec in vectors for v in slave.md.modelVariables if group(v.name) == vec]


def _split(rows: np.ndarray, names) -> dict:
    """{name: (nt,) or (nt, k) history} of the columns of ``rows`` (nt, m) over ``names`` (_names)."""
    offs = np.cumsum([0] + [k for _, k in names])
    return {name: rows[:, a] if k == 1 else rows[:, a:a + k] for (name, k), a in zip(names, offs)}


def reference_histories(exported: Export) -> dict:
    """{model: (inputs, outputs)} of the reference runs (see the module docstring), each a dict
    {scalar variable name: (nt,) history at t = k dt}: every input of the FMU, and the outputs
    its _ref.csv holds (SOIL_REFERENCE_DOFS)."""
    dt = exported.dt
    nt = int(round(exported.stop_time / dt)) + 1
    ag = bundled_motion_ahead(exported.structure, nt)
    s_out, g_out = ("x", "xdot", "x_time") + HEADLINE, ("g", "g_time", "dissipated_energy")
    with FmuSlave(exported.structure, "structure") as S, FmuSlave(exported.soil, "soil") as G, \
            FmuSlave(exported.coupled, "coupled") as C:
        for fmu in (S, C):
            fmu.set(*AG, ag[0])
            fmu.initialize()
        G.initialize()
        s_names, g_names = _names(S, s_out), _names(G, g_out)
        nx, ng = S.size("x") * 2 + 1, G.size("g") + 1
        A, B = np.empty((nt, sum(S.size(v) for v in s_out))), np.empty((nt, sum(G.size(v) for v in g_out)))
        Y = np.empty((nt, len(HEADLINE)))
        A[0], B[0], Y[0] = S.get(*s_out), G.get(*g_out), C.get(*HEADLINE)
        for k in range(1, nt):
            t = (k - 1) * dt
            S.set("g", "g_time", *AG, np.concatenate([B[k - 1, :ng], ag[k - 1]]))
            G.set("x", "xdot", "x_time", A[k - 1, :nx])
            C.set(*AG, ag[k - 1])
            for fmu in (S, G, C):
                fmu.do_step(t, dt)
            A[k], B[k], Y[k] = S.get(*s_out), G.get(*g_out), C.get(*HEADLINE)
        inputs = {m: [v.name for v in fmu.md.modelVariables if v.causality == "input"]
                  for m, fmu in (("structure", S), ("soil", G))}
    ag_cols = dict(zip(AG, ag.T))
    pair = {**_split(A, s_names), **_split(B, g_names), **ag_cols}
    if S.version == 3:                  # whole arrays: the raft's part of g (6 values)
        soil_ref = ["g_raft_u", "g_raft_r"]
    else:
        peak = np.abs(B[:, :ng - 1]).max(axis=0)
        soil_ref = [g_names[i][0] for i in np.sort(np.argsort(-peak, kind="stable")[:SOIL_REFERENCE_DOFS])]
    if np.isfinite(pair["dissipated_energy"]).all():        # NaN: the soil object does not report it
        soil_ref.append("dissipated_energy")
    pick = lambda names: {n: pair[n] for n in names}
    return {"structure": (pick(inputs["structure"]), pick(HEADLINE)),
            "soil": (pick(inputs["soil"]), pick(soil_ref)),
            "coupled": (ag_cols, dict(zip(HEADLINE, Y.T)))}


def write_csv(path, dt: float, columns: dict) -> Path:
    """A CSV by the cross-check rules: header of double-quoted names, "time" first, one row per
    t = k dt, numbers as C literals that read back exactly (shortest round-trip repr); a column
    of shape (nt, k) is an array, its k values separated by spaces (FMI 3.0)."""
    nt = len(next(iter(columns.values())))
    cols = [dt * np.arange(nt)] + [np.asarray(c, float) for c in columns.values()]
    bad = [name for name, c in columns.items() if not np.all(np.isfinite(c))]
    if bad:
        raise ValueError(f"{path}: column {bad[0]} is not finite (the cross-check's CSV files hold numbers only)")
    cell = lambda c, k: " ".join(map(repr, c[k].tolist())) if c.ndim == 2 else repr(float(c[k]))
    lines = [",".join(f'"{n}"' for n in ("time", *columns))]
    lines += [",".join(cell(c, k) for c in cols) for k in range(nt)]
    with atomic_output(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    return Path(path)


def readme(model: str, exported: Export, outputs, scene_name: str = "") -> str:
    """The README.md of a model's cross-check folder (``outputs``: the names in its _ref.csv)."""
    if model == "soil":
        g = [n for n in outputs if n.startswith("g")]
        energy = "; `dissipated_energy` (J): energy dissipated in the soil so far" * ("dissipated_energy" in outputs)
        text = (SOIL_TEXT3 if exported.fmi_version == 3 else SOIL_TEXT).format(names="`, `".join(g), k=len(g),
                                                                                energy=energy)
    else:
        text = HEADLINE_TEXT
    fmu = getattr(exported, model)
    with zipfile.ZipFile(fmu) as z:
        kind = "native" if f"resources/{RESOURCE_FILE}" in z.namelist() else "python"
    v3 = exported.fmi_version == 3
    return README.format(
        model=model, description=read_model_description(str(fmu)).description, fmi=f"{exported.fmi_version}.0",
        runtime=RUNTIME[kind], version=tool_version(), scene=f", scene {scene_name!r}" if scene_name else "",
        dt=exported.dt, stop=exported.stop_time, steps=int(round(exported.stop_time / exported.dt)),
        inputs=INPUTS[model] + ("\n\n" + ARRAYS3 if v3 and model != "coupled" else ""), outputs=text,
        how=HOW[model], platform=FMPY_PLATFORM_TUPLE if v3 else FMPY_PLATFORM,
        python=_platform.python_version(), numpy=np.__version__, scipy=scipy.__version__)


def write_cross_check(exported: Export, xdir, scene_name: str = "") -> CrossCheck:
    """Write the cross-check folders of the three exported FMUs under ``xdir`` (the root of a
    cross-check repository; created if missing, files of the same names replaced) and check
    them (check_cross_check). Raises CosimError (a RuntimeError) if a reference run fails."""
    dt = exported.dt
    opt = {"StartTime": 0.0, "StopTime": exported.stop_time, "StepSize": dt, "RelTol": REL_TOL,
           "OutputIntervalLength": dt}
    folders = {}
    for model, (inputs, outputs) in reference_histories(exported).items():
        folder = folders[model] = model_folder(xdir, model, exported.fmi_version)
        with atomic_folder(folder) as stage:     # the model's folder changes as a whole, or not at all
            shutil.copyfile(getattr(exported, model), stage / f"{model}.fmu")
            (stage / f"{model}_ref.opt").write_text("".join(f"{k}, {v!r}\n" for k, v in opt.items()))
            write_csv(stage / f"{model}_in.csv", dt, inputs)
            write_csv(stage / f"{model}_ref.csv", dt, outputs)
            (stage / "README.md").write_text(readme(model, exported, outputs, scene_name))
    return CrossCheck(root=Path(xdir), models=folders, problems=check_cross_check(xdir))


def check_cross_check(xdir) -> tuple:
    """What fmpy's checker finds in the cross-check repository ``xdir`` (file sizes, model
    description, .opt, CSV headers against the FMU's variables), plus every model whose run has
    more than FMPY_MAX_INTERVALS steps (fmpy's runner would step it at 2 dt). Empty: compliant."""
    _, _, problems = validate_repo(str(xdir))
    for opt_file in sorted(Path(xdir, "fmus", "3.0").glob("*/*/*/*/*/*_ref.opt")):     # FMI 3.0 folders
        problems += validate_test_fmu(str(opt_file.parent))
    for opt_file in sorted(Path(xdir, "fmus").rglob("*_ref.opt")):
        opt = read_ref_opt_file(str(opt_file))
        steps = (opt["StopTime"] - opt["StartTime"]) / opt["StepSize"]
        if steps > FMPY_MAX_INTERVALS + 1e-6:
            problems.append(f"{opt_file}: {steps:.0f} steps of {opt['StepSize']!r} s: fmpy's cross-check runner "
                            f"steps a run of more than {FMPY_MAX_INTERVALS} intervals at a multiple of StepSize, "
                            "which this fixed-step FMU refuses (export a shorter motion, [motion] duration_s, "
                            "or a larger [analysis] dt for the cross-check)")
    return tuple(problems)
