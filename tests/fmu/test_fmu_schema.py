"""One schema for both kinds of FMU (fmus/schema.py): every variable of every FMU of both kinds
is the schema's (name, value reference, causality, unit, description, start); the two kinds'
model descriptions are identical except for their implementation parts; the units of both
ends of every connection of system.ssd / system.ssp and of the cross-check folders match;
the C runtime's message table and its positional tables (uplift_schema.h: roles, energy
terms, slots, the in-process run's row layout) are generated from the schema; two runtimes compiled with
different FMI2_FUNCTION_PREFIX link into one binary; the Python FMUs' requirements.txt lists
exactly the third-party modules their bundled code imports at module level."""
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description

from helpers import small_scene
from fmus import schema
from fmus.bundle import LAZY_REQUIREMENTS, PROVIDED, REQUIREMENTS, third_party
from fmus.native_build import NATIVE, SOURCES, fmi_headers, sources_of

ROLES = ("structure", "soil", "coupled")
SCENE = small_scene()
N = SCENE.mesh.xy.shape[0]
NODES = ["top_outer", "internals_37m"]


def kinds(exported, exported_native):
    return {"python": exported, "native": exported_native}


@pytest.mark.parametrize("kind", ["python", "native"])
@pytest.mark.parametrize("role", ROLES)
def test_every_variable_comes_from_the_schema(exported, exported_native, kind, role):
    md = read_model_description(str(getattr(kinds(exported, exported_native)[kind], role)))
    want = schema.variables(role, 6 + N, N, NODES, motion=True)
    got = [(v.name, v.valueReference, v.type, v.causality, v.unit, v.description, v.start)
           for v in md.modelVariables]
    assert got == [(v.name, v.value_reference, v.type, v.causality, v.unit, v.description, v.start)
                   for v in want]
    units = {v.name: v.unit for v in md.modelVariables}
    if role != "soil":                            # rotations of [q, w]: rad, rad/s; the rest m, m/s
        assert [units[f"x[{i}]"] for i in range(8)] == ["m"] * 3 + ["rad"] * 3 + ["m"] * 2
        assert [units[f"xdot[{i}]"] for i in (2, 3, 6)] == ["m/s", "rad/s", "m/s"]
    forces = "g" if role != "coupled" else None
    if forces:
        assert [units[f"g[{i}]"] for i in (0, 3, 5, 6)] == ["N", "N.m", "N.m", "N"]
    defined = {u.name for u in md.unitDefinitions}
    assert {u for u in units.values() if u} <= defined


def _description_without_implementation(fmu) -> str:
    """The model description with what depends on the kind removed: the root's guid and
    generation attributes, CoSimulation (capabilities, SourceFiles), LogCategories; attributes
    sorted."""
    with zipfile.ZipFile(fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    for key in ("guid", "generationTool", "generationDateAndTime", "numberOfEventIndicators"):
        root.attrib.pop(key, None)
    for tag in ("CoSimulation", "LogCategories"):
        for el in root.findall(tag):
            root.remove(el)
    for el in root.iter():
        el.attrib = dict(sorted(el.attrib.items()))
        el.text = el.tail = None
    return ET.tostring(root, encoding="unicode")


@pytest.mark.parametrize("role", ROLES)
def test_the_two_kinds_differ_only_in_their_implementation(exported, exported_native, role):
    a, b = (_description_without_implementation(getattr(e, role)) for e in (exported, exported_native))
    assert a == b


def _connections(ssd_text: str):
    ns = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription"}
    root = ET.fromstring(ssd_text)
    return [(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
            for c in root.iterfind(".//ssd:Connection", ns)]


@pytest.mark.parametrize("kind", ["python", "native"])
def test_units_match_across_every_connection_of_the_ssd_and_ssp(exported, exported_native, kind, tmp_path):
    e = kinds(exported, exported_native)[kind]
    with zipfile.ZipFile(e.ssp) as z:
        z.extractall(tmp_path)
    for ssd, folder in ((e.ssd, e.ssd.parent), (tmp_path / "SystemStructure.ssd", tmp_path)):
        root = ET.fromstring(Path(ssd).read_text())
        sources = {c.get("name"): folder / c.get("source") for c in root.iter()
                   if c.tag.endswith("Component")}
        units = {comp: {v.name: (v.unit, v.causality) for v in read_model_description(str(src)).modelVariables}
                 for comp, src in sources.items()}
        conns = _connections(Path(ssd).read_text())
        assert len(conns) == 3 * (6 + N) + 2                  # x, xdot, x_time; g, g_time
        for a, va, b, vb in conns:
            (ua, ca), (ub, cb) = units[a][va], units[b][vb]
            assert (ca, cb) == ("output", "input") and ua == ub and ua is not None, (a, va, b, vb, ua, ub)
        rotational = [va for a, va, b, vb in conns if units[a][va][0] in ("rad", "rad/s", "N.m")]
        assert len(rotational) == 9                      # x, xdot, g on rx, ry, rz
        # every connector is a variable of its FMU with its causality; the structure's motion
        # inputs are there, free (the motion is bundled), in m/s2
        connectors = {(comp.get("name"), c.get("name")): c.get("kind") for comp in root.iter()
                      if comp.tag.endswith("Component") for c in comp.iter() if c.tag.endswith("Connector")}
        for (comp, name), kind_ in connectors.items():
            assert units[comp][name][1] == kind_, (comp, name)
        connected = {(a, va) for a, va, _, _ in conns} | {(b, vb) for _, _, b, vb in conns}
        for name in schema.AG:
            assert connectors[("structure", name)] == "input" and units["structure"][name][0] == "m/s2"
            assert ("structure", name) not in connected


def test_units_match_across_the_cross_check_folders(exported, tmp_path):
    """Each input column of a model's _in.csv is its partner's output of the same name (the
    pair under Jacobi): the units of both ends match."""
    from fmpy.util import read_csv
    from orchestrator.crosscheck import write_cross_check
    xc = write_cross_check(exported, tmp_path / "xc", "small")
    md = {m: {v.name: (v.unit, v.causality) for v in read_model_description(str(xc.models[m] / f"{m}.fmu"))
              .modelVariables} for m in ROLES}
    checked = 0
    for model, partner in (("soil", "structure"), ("structure", "soil")):
        for name in read_csv(str(xc.models[model] / f"{model}_in.csv")).dtype.names[1:]:
            unit, causality = md[model][name]
            assert causality == "input"
            if name in md[partner]:
                assert md[partner][name] == (unit, "output"), name
                checked += 1
    assert checked == 2 * (6 + N) + 1 + (6 + N) + 1                 # x, xdot, x_time; g, g_time


def test_energy_terms_are_the_steppers():
    """The schema names the stepper's energy terms without importing it (an FMU instantiates
    without scipy): the two tuples must stay equal, and equal to what the stepper computes."""
    from structure.newmark import ENERGY_TERMS
    assert schema.ENERGY_TERMS == ENERGY_TERMS
    exported_terms = [v.name for v in schema.variables("structure", n=7, N=1, nodes=())
                      if v.name.startswith("energy.")]
    assert exported_terms == [f"energy.{t}" for t in ENERGY_TERMS]


def test_c_message_table_is_generated_from_the_schema():
    header = NATIVE / "include" / "uplift_messages.h"
    assert header.read_text() == schema.c_messages_header(), \
        "regenerate: python -c 'from fmus.schema import c_messages_header; print(c_messages_header(), end=\"\")'"
    c = "".join((NATIVE / s).read_text() for s in sorted(set(SOURCES) | set(sources_of(3))))
    for key in schema.MESSAGES:                                    # every refusal used by the runtime
        assert f"UP_MSG_{key.upper()}" in c, key


def test_c_positional_tables_are_generated_from_the_schema():
    """uplift_schema.h (the roles, the energy terms, the slots' names, lengths and the slots each
    role needs, the row layout of the in-process run) is what the schema writes; the C files use
    its tables, not copies; the lengths and needs it writes are those of the schema's variables."""
    header = NATIVE / "include" / "uplift_schema.h"
    assert header.read_text() == schema.c_schema_header(), "regenerate: python -m fmus.schema"
    c = {name: (NATIVE / name).read_text() for name in ("instance.c", "simulate.c", "stepper.c")}
    for name, uses in (("instance.c", ("UP_SLOT_NAMES", "UP_SLOT_LENGTHS(", "UP_SLOT_NEEDED")),
                       ("simulate.c", ("UP_ROW_WIDTH(", "UP_ROW_ENERGY(", "UP_ROW_GAP(")),
                       ("stepper.c", tuple(f"e[UP_E_{t.upper()}]" for t in schema.ENERGY_TERMS))):
        for use in uses:
            assert use in c[name], (name, use)
    assert "enum { S_" not in (NATIVE / "include" / "fmu.h").read_text()     # no second slot table
    nodes = ("a", "b")
    for role in schema.ROLES:
        vars_ = [v for v in schema.variables(role, n=6 + N, N=N, nodes=nodes) if v.type == "Real"]
        value = {"1": 1, "n": 6 + N, "N": N, "nodes": len(nodes)}
        for slot, need in zip(schema.SLOTS, schema.slot_needed(role)):
            count = sum(v.slot == slot for v in vars_)
            assert count in (0, sum(c * value[sym] for sym, c in schema.slot_length(slot).items())), (role, slot)
            assert need <= (count > 0), (role, slot)
    at = schema.row_slices(N, 2)
    assert [at[part] for part, _ in schema.ROW] == sorted(at.values(), key=lambda s: s.start)
    assert schema.row_width(N, 2) == 6 + 3 * N + 12 + len(schema.ENERGY_TERMS) == at["energy"].stop


@pytest.mark.parametrize("version", [2, 3])
def test_two_runtimes_link_into_one_binary(tmp_path, version):
    """The soil's and the structure's runtime compiled with their own FMI2_FUNCTION_PREFIX
    (FMI3_FUNCTION_PREFIX: the FMI 3.0 runtime), as a tool importing source-code FMUs does, link
    into one shared object: no symbol collides."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None or sys.platform != "linux":
        pytest.skip("needs Linux and a C compiler")
    objects = []
    for prefix in ("UpliftSoil_", "UpliftStructure_"):
        for src in sources_of(version):
            obj = tmp_path / f"{prefix}{src}.o"
            subprocess.run([cc, "-std=c99", "-O0", "-fPIC", f"-DFMI{version}_FUNCTION_PREFIX={prefix}",
                            f"-I{fmi_headers()}", f"-I{NATIVE / 'include'}", "-c", str(NATIVE / src), "-o", str(obj)],
                           check=True)
            objects.append(str(obj))
    lib = tmp_path / "both.so"
    proc = subprocess.run([cc, "-shared", "-Wl,--no-undefined", *objects, "-o", str(lib), "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    symbols = subprocess.run(["nm", "-g", "--defined-only", str(lib)], capture_output=True, text=True).stdout
    names = [line.split()[-1] for line in symbols.splitlines() if line.strip()]
    ours = [s for s in names if f"fmi{version}" in s or s.startswith("up_") or "_up_" in s]
    assert f"UpliftSoil_fmi{version}DoStep" in ours and f"UpliftStructure_fmi{version}DoStep" in ours
    assert all(s.startswith(("UpliftSoil_", "UpliftStructure_")) for s in ours), ours


@pytest.mark.parametrize("role", ROLES)
def test_requirements_list_what_the_bundled_code_imports(exported, role, tmp_path):
    with zipfile.ZipFile(getattr(exported, role)) as z:
        names = z.namelist()
        z.extractall(tmp_path)
        listed = z.read("resources/requirements.txt").decode().splitlines()
    (private,) = {n.split("/")[1] for n in names if n.startswith("resources/_uplift_")}
    imported = third_party(tmp_path / "resources" / private)
    required = {line.split(">")[0].split(";")[0].strip() for line in listed if line[:1].isalpha()}
    assert imported <= required and required <= imported | set(LAZY_REQUIREMENTS), (imported, required)
    assert {"numpy", "scipy"} <= imported and "threadpoolctl" in required and set(required) <= set(REQUIREMENTS)
    assert "h5py" not in imported          # an FMU reads no HDF5: the lazy namespaces keep table.py out
    assert "pythonfmu" in PROVIDED and "resources/pythonfmu/fmi2slave.py" in names
    # modules an FMU never runs are not carried
    assert not any(n.endswith(("fit_plot.py", "native_build.py", "fmus/build.py", "bundle.py")) for n in names)
