"""The FMU schema: every variable of the three FMUs once, the refusal messages once, the limits
the FMI boundary enforces. Both kinds of FMU are built from it: the Python adapters register
their variables from ``variables(role, ...)``, the native builder writes the same list into the
model description and the first value reference of each vector into ``resources/uplift.bin``
(records ``vr.<vector>``, looked up by name by the C runtime), and the C runtime's message
table ``fmus/native/include/uplift_messages.h`` is generated from ``MESSAGES``
(``c_messages_header``) and its positional tables ``fmus/native/include/uplift_schema.h`` from
``ROLES``, ``ENERGY_TERMS``, ``SLOTS`` and the vectors (the slots' names, lengths and which role
needs which) and ``ROW`` (the layout of a row of the in-process run) (``c_schema_header``);
a test keeps both files equal to what these functions write (``python -m fmus.schema`` writes
them).

A *vector* is a named run of Real variables with consecutive value references: ``x[0..n-1]``
over the interface DOFs [q, w] (n = 6 + N: raft ux, uy, uz, rx, ry, rz, then the soil's vertical
displacement under each of the N interface nodes), ``P[0..N-1]`` over the nodes, the three
motion inputs ``ag_x, ag_y, ag_z`` (the vector ``ag``, ``AG``), or a scalar. Its unit follows the DOF kind of each element (``QUANTITIES``):
translations and gap DOFs m, m/s, N; rotations rad, rad/s, N.m.

Value references are allocated in list order, Reals first (0, 1, ...), then the Boolean
``internal_motion``. Names of the elements are ``name[i]`` unless a vector lists its own
(``elements``): the motion inputs are ``ag_x, ag_y, ag_z`` (m/s2, one per component of the
scene's motion), three consecutive references in the slot ``ag``.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

INPUT, OUTPUT, PARAMETER = "input", "output", "parameter"

#: the SI units the FMUs use, as exponents of the SI base units (FMI 2.0 BaseUnit)
UNITS = {"1": {}, "s": {"s": 1}, "m": {"m": 1}, "rad": {"rad": 1}, "m/s": {"m": 1, "s": -1},
         "rad/s": {"rad": 1, "s": -1}, "m/s2": {"m": 1, "s": -2}, "N": {"kg": 1, "m": 1, "s": -2},
         "N.m": {"kg": 1, "m": 2, "s": -2}, "J": {"kg": 1, "m": 2, "s": -2}}

#: quantity -> (unit on a translation or gap DOF, unit on a rotation DOF)
QUANTITIES = {"displacement": ("m", "rad"), "velocity": ("m/s", "rad/s"), "force": ("N", "N.m"),
              "acceleration": ("m/s2", "m/s2"), "time": ("s", "s"), "energy": ("J", "J"),
              "count": ("1", "1"), "angle": ("rad", "rad")}

#: the energy terms of the stepper, in output order: equal to structure.newmark.ENERGY_TERMS (tested; not
#: imported, so that an FMU instantiates without loading the stepper and scipy)
ENERGY_TERMS = ("input", "kinetic", "strain", "damping", "soil", "contact", "contact_potential")
#: the ground-motion inputs of the structure and the coupled FMU: a_g(t + dt) along x, y, z, m/s2
AG = ("ag_x", "ag_y", "ag_z")

#: one row of the in-process run (fmus/native/simulate.c, read by fmus/native_stepper.py), per
#: sample: (part, length as {symbol: coefficient}) in order, the symbols "1", "N" (interface
#: nodes), "m" (output nodes) and "E" (the energy terms); per output node its absolute
#: acceleration (3) then its displacement (3)
ROW = (("raft", {"1": 6}), ("gap", {"N": 1}), ("contact_force", {"N": 1}), ("soil_w", {"N": 1}),
       ("nodes", {"m": 6}), ("energy", {"E": 1}))


def row_slices(N: int, m: int) -> dict:
    """{part of ROW: its slice of a row} for N interface nodes and m output nodes."""
    value = {"1": 1, "N": N, "m": m, "E": len(ENERGY_TERMS)}
    out, at = {}, 0
    for part, length in ROW:
        k = sum(c * value[sym] for sym, c in length.items())
        out[part], at = slice(at, at + k), at + k
    return out


def row_width(N: int, m: int) -> int:
    """The length of a row of the in-process run: 6 + 3 N + 6 m + len(ENERGY_TERMS)."""
    return row_slices(N, m)[ROW[-1][0]].stop


@dataclass(frozen=True)
class Vector:
    """A named run of Real variables.

    size : "n" (interface DOFs [q, w]), "N" (interface nodes), "3" (x, y, z) or "1" (a scalar)
    quantity : a key of QUANTITIES (the unit of each element follows its DOF kind)
    slot : the runtime's name of the run (default: name); the acc_/disp_ vectors of the output
           nodes share the slot "nodes", the energy terms the slot "energy"
    """
    name: str
    causality: str
    size: str
    quantity: str
    description: str
    slot: str | None = None
    elements: tuple | None = None

    def length(self, n: int, N: int) -> int:
        return {"n": n, "N": N, "3": 3, "1": 1}[self.size]

    def units(self, n: int, N: int) -> tuple:
        """(length,) units: on [q, w] the rotations rx, ry, rz (elements 3..5) take the rotation unit."""
        trans, rot = QUANTITIES[self.quantity]
        k = self.length(n, N)
        if self.size == "n":
            return (trans,) * 3 + (rot,) * 3 + (trans,) * (k - 6)
        return (trans,) * k

    def names(self, n: int, N: int) -> list:
        if self.elements is not None:
            return list(self.elements)
        return [self.name] if self.size == "1" else [f"{self.name}[{i}]" for i in range(self.length(n, N))]


@dataclass(frozen=True)
class Variable:
    """One scalar variable of a model description (value references: Reals in order, then Booleans)."""
    name: str
    value_reference: int
    causality: str
    description: str
    unit: str | None = None
    type: str = "Real"
    start: str | None = None
    variability: str | None = None
    slot: str | None = None


# ---- the vectors of each role ----------------------------------------------------------------
SOIL = (
    Vector("x", INPUT, "n", "displacement", "interface displacements"),
    Vector("xdot", INPUT, "n", "velocity", "interface velocities"),
    Vector("x_time", INPUT, "1", "time", "time of x"),
    Vector("g", OUTPUT, "n", "force", "history force for the structure's next step without its latest state's part"),
    Vector("g_time", OUTPUT, "1", "time", "start of the structure step g is meant for"),
    Vector("f", OUTPUT, "n", "force", "total force on the soil"),
    Vector("dissipated_energy", OUTPUT, "1", "energy", "energy dissipated in the soil"),
)
#: the structure FMU's own vectors, before those of the stepper
STRUCTURE = (
    Vector("g", INPUT, "n", "force", "soil history force without the part of the structure's latest state"),
    Vector("g_time", INPUT, "1", "time", "start of the step g is meant for"),
    Vector("x_time", OUTPUT, "1", "time", "time of x"),
)


def stepper_vectors(nodes) -> tuple:
    """The vectors of the structure and the coupled FMU (``fmus/stepper.py``)."""
    out = [Vector("ag", INPUT, "3", "acceleration", "ground acceleration at t + dt", elements=AG),
           Vector("x", OUTPUT, "n", "displacement", "interface displacements [q, w]"),
           Vector("xdot", OUTPUT, "n", "velocity", "interface velocities"),
           Vector("P", OUTPUT, "N", "force", "total contact forces"),
           Vector("gap", OUTPUT, "N", "displacement", "uplift")]
    for nm in nodes:
        out += [Vector(f"acc_{nm}", OUTPUT, "3", "acceleration", f"absolute acceleration of {nm}", slot="nodes"),
                Vector(f"disp_{nm}", OUTPUT, "3", "displacement", f"displacement of {nm}", slot="nodes")]
    out += [Vector(f"energy.{term}", OUTPUT, "1", "energy", f"energy term {term}", slot="energy")
            for term in ENERGY_TERMS]
    out += [Vector("newton_iters", OUTPUT, "1", "count", "linear solves of the last step"),
            Vector("max_uplift", OUTPUT, "1", "displacement", "running maximum of the uplift"),
            Vector("max_raft_rotation", OUTPUT, "1", "angle", "running maximum of the raft rotation")]
    return tuple(out)


INTERNAL_MOTION_DESCRIPTION = "true: the ground motion bundled in resources; false: the inputs ag_x, ag_y, ag_z"
ROLES = ("soil", "structure", "coupled")
#: the slots the C runtime looks up (records vr.<slot> of resources/uplift.bin; -1 when absent)
SLOTS = ("x", "xdot", "x_time", "g", "g_time", "f", "dissipated_energy", "ag", "P", "gap", "nodes", "energy",
         "newton_iters", "max_uplift", "max_raft_rotation")


def vectors(role: str, nodes=()) -> tuple:
    """The Real vectors of an FMU of ``role`` (soil, structure, coupled), in value-reference order."""
    if role == "soil":
        return SOIL
    if role == "structure":
        return STRUCTURE + stepper_vectors(nodes)
    if role == "coupled":
        return stepper_vectors(nodes)
    raise ValueError(f"role {role!r}: one of {', '.join(ROLES)}")


def variables(role: str, n: int, N: int, nodes=(), motion: bool = False) -> list:
    """Every variable of an FMU of ``role`` with n = 6 + N interface DOFs, N interface nodes, the
    named output ``nodes``; ``motion``: a motion is bundled (start of internal_motion)."""
    out, vr = [], 0
    for vec in vectors(role, nodes):
        start = "0" if vec.causality == INPUT else None
        for name, unit in zip(vec.names(n, N), vec.units(n, N)):
            out.append(Variable(name, vr, vec.causality, vec.description, unit, start=start, slot=vec.slot or vec.name))
            vr += 1
    if role != "soil":
        out.append(Variable("internal_motion", vr, PARAMETER, INTERNAL_MOTION_DESCRIPTION,
                            type="Boolean", start="true" if motion else "false", variability="fixed"))
    return out


# ---- FMI 3.0: arrays ------------------------------------------------------------------------------
#: an interface vector [q, w] of FMI 3.0 in parts of one unit each: (suffix, first element,
#: length: 3 or "N", 0 for the translation unit or 1 for the rotation unit, what)
INTERFACE_VECTORS = ("x", "xdot", "g", "f")
INTERFACE_PARTS = (("_raft_u", 0, 3, 0, "raft translations ux, uy, uz"),
                   ("_raft_r", 3, 3, 1, "raft rotations rx, ry, rz"),
                   ("_w", 6, "N", 0, "the soil's vertical displacement under each interface node"))


def vector3(name: str) -> str:
    """The vector an FMI 3.0 variable is part of: ``x`` for x_raft_u, x_raft_r, x_w (the
    interface vectors' parts), else the name itself."""
    for suffix, *_ in INTERFACE_PARTS:
        if name.endswith(suffix) and name[:-len(suffix)] in INTERFACE_VECTORS:
            return name[:-len(suffix)]
    return name


@dataclass(frozen=True)
class Variable3:
    """One variable of an FMI 3.0 model description: a Float64 scalar or array over the run of
    elements ``first .. first + length - 1`` of the FMI 2.0 variables (``variables``), the
    structural parameter N (UInt64) or the Boolean internal_motion.

    dimension : None (a scalar), an int (a fixed length) or "N" (the structural parameter N)
    vector : the FMI 2.0 vector (fmus.schema.Vector name) the variable is a part of
    """
    name: str
    value_reference: int
    causality: str
    description: str
    type: str = "Float64"
    unit: str | None = None
    dimension: int | str | None = None
    start: str | None = None
    variability: str | None = None
    first: int = 0
    length: int = 1
    vector: str | None = None


def variables3(role: str, n: int, N: int, nodes=(), motion: bool = False) -> list:
    """Every variable of the FMI 3.0 FMU of ``role``: each vector of ``vectors`` as one array, an
    interface vector [q, w] as the three arrays of INTERFACE_PARTS (an FMI 3.0 array has one
    unit: the raft's translations, its rotations, the gap DOFs), the motion as the scalars
    ag_x, ag_y, ag_z, scalars as scalars; then the independent variable time, the structural
    parameter N and (not the soil) the Boolean internal_motion. Value references 0, 1, ... in
    that order; ``first`` and ``length`` map each Float64 variable to the elements of
    ``variables`` (the runtime's bank; time: first = -1, the FMU's time)."""
    out, first = [], 0
    for vec in vectors(role, nodes):
        k, units = vec.length(n, N), vec.units(n, N)
        start = "0" if vec.causality == INPUT else None
        if vec.size == "n":
            parts = [(vec.name + suffix, first + off, N if ln == "N" else ln, "N" if ln == "N" else ln,
                      f"{vec.description}: {what}", units[off]) for suffix, off, ln, _, what in INTERFACE_PARTS]
        elif vec.elements is not None:
            parts = [(name, first + i, 1, None, vec.description, units[i]) for i, name in enumerate(vec.elements)]
        else:
            dim = None if vec.size == "1" else ("N" if vec.size == "N" else k)
            parts = [(vec.name, first, k, dim, vec.description, units[0])]
        for name, at, length, dim, description, unit in parts:
            out.append(Variable3(name, len(out), vec.causality, description, unit=unit, dimension=dim, start=start,
                                 first=at, length=length, vector=vec.name))
        first += k
    out.append(Variable3("time", len(out), "independent", "simulation time", unit="s", first=-1))
    out.append(Variable3("N", len(out), "structuralParameter", "number of interface nodes", type="UInt64",
                         start=str(N), variability="fixed"))
    if role != "soil":
        out.append(Variable3("internal_motion", len(out), PARAMETER, INTERNAL_MOTION_DESCRIPTION, type="Boolean",
                             start="true" if motion else "false", variability="fixed"))
    return out


def slot_of(vec: Vector) -> str:
    """The slot of a vector: its own ``slot``, else its name."""
    return vec.slot or vec.name


def slot_length(slot: str) -> dict:
    """The length of a slot's run of variables, as {symbol: coefficient} over the symbols "1",
    "n" (interface DOFs), "N" (interface nodes) and "nodes" (output nodes): the same in every
    role that has the slot (x: {"n": 1}; nodes: {"nodes": 6}; energy: {"1": 7})."""
    sizes = {"1": ("1", 1), "3": ("1", 3), "n": ("n", 1), "N": ("N", 1)}
    found = set()
    for role in ROLES:
        base, one = vectors(role), vectors(role, ("a",))     # one output node: its vectors count per node
        if not any(slot_of(v) == slot for v in one):
            continue
        terms = {}
        for vec in one:
            if slot_of(vec) == slot:
                sym, k = sizes[vec.size]
                if vec not in base:
                    if sym != "1":
                        raise ValueError(f"slot {slot}: a vector per output node must have a fixed size")
                    sym = "nodes"
                terms[sym] = terms.get(sym, 0) + k
        found.add(tuple(sorted(terms.items())))
    if len(found) != 1:
        raise ValueError(f"slot {slot}: {'in no role' if not found else 'lengths differ between roles'}")
    return dict(found.pop())


def slot_needed(role: str) -> tuple:
    """(len(SLOTS),) 1 where an FMU of ``role`` must have the slot (its vectors without output
    nodes have it), else 0."""
    have = {slot_of(v) for v in vectors(role)}
    return tuple(int(s in have) for s in SLOTS)


def slot_table(variables_) -> dict:
    """{slot: first value reference} of the Real variables (every slot of SLOTS; -1 when absent)."""
    first = {}
    for v in variables_:
        if v.type == "Real":
            first.setdefault(v.slot, v.value_reference)
    unknown = set(first) - set(SLOTS)
    if unknown:
        raise ValueError(f"slots {sorted(unknown)} are not in fmus.schema.SLOTS")
    return {s: first.get(s, -1) for s in SLOTS}


# ---- the FMI boundary: limits and refusals ---------------------------------------------------
#: a communication step shorter than SLIVER dt is a no-op that returns OK (a host that
#: accumulates its time by repeated addition asks for such a step at the end of its run)
SLIVER = 1e-6
#: a communication step within STEP_RTOL (relative) of a whole number of dt is that number
STEP_RTOL = 1e-9
#: a time or stamp within TIME_TOL dt of the expected one is it
TIME_TOL = 1e-6
#: at most this many steps of dt in one communication step (the coupled FMU); a longer one is
#: refused before any work
MAX_STEPS_PER_CALL = 100000

#: the refusals both kinds make, as str.format templates with named fields (numbers in their
#: shortest round-trip form; the FMI version's names ``api``, ``standard``, ``setup`` default to
#: FMI 2.0's, API_FIELDS); the C runtime's copy (include/uplift_messages.h) has the fields as %s
#: in the order they appear
MESSAGES = {
    "refused": "step from t = {t} s refused: {why}",
    "before_init": "{call} before initialisation (call {api}ExitInitializationMode first)",
    "wrong_state": "{call} is not allowed {state} ({standard} co-simulation state machine)",
    "after_terminate": "{call} after {api}Terminate (instantiate the FMU again)",
    "wrong_time": "this FMU is at t = {time} s: steps must follow one another (restore an FMU state to go back)",
    "bad_step": "communication step {h} s: a step must be finite and positive",
    "wrong_step": "communication step {h} s: this FMU steps {allowed} {dt} s per communication step (export it "
                  "again with the step you need)",
    "too_many_steps": "communication step {h} s: more than {limit} steps of {dt} s in one communication step "
                      "(call doStep more often)",
    "past_stop": "communication step {h} s ends at {end} s, past the stop time {stop} s given to {setup}",
    "not_finite": "input {name} = {value}: inputs must be finite (check what is connected to it)",
    "stamp": "input {name} is stamped {stamp_name} = {stamp} s at a step from t = {t} s: it must be the partner's "
             "output at t or at t + dt (connect the partner's {stamp_name} output to this input, with {name})",
    "start_time": "start time {start} s: this FMU starts at t = 0 s, at rest, with the first sample of its record",
    "no_motion": "internal_motion = true but this FMU was exported without a motion: set internal_motion = false "
                 "and drive the inputs ag_x, ag_y, ag_z",
    "bad_state": "the {size} bytes are not a serialised state of this FMU: {why}",
    "state_magic": "not an uplift FMU state",
    "state_version": "format version {version}, this FMU reads version {expected}",
    "state_identity": "a state of another FMU (GUID hash {got}, this FMU {expected})",
    "state_size": "size or length mismatch",
    "state_checksum": "checksum mismatch (the bytes changed since they were written)",
}

#: the serialised FMU state: format version, magic of each kind
STATE_VERSION = 2


#: the names of each FMI version in the messages (the Python FMUs are FMI 2.0)
API_FIELDS = {2: {"api": "fmi2", "standard": "FMI 2.0", "setup": "fmi2SetupExperiment"},
              3: {"api": "fmi3", "standard": "FMI 3.0", "setup": "fmi3EnterInitializationMode"}}


def message(key: str, **fields) -> str:
    """A refusal of MESSAGES with its fields filled in (the FMI 2.0 names unless given)."""
    return MESSAGES[key].format(**{**API_FIELDS[2], **fields})


def _c_sum(terms: dict, names: dict) -> str:
    """A C expression of {symbol: coefficient} with the symbols written as ``names`` gives them
    ("1": the constant, first), in the order of ``names``; "0" when empty."""
    const = terms.get("1", 0)
    parts = [("" if terms[sym] == 1 else f"{terms[sym]} * ") + name for sym, name in names.items() if terms.get(sym)]
    if const or not parts:
        parts.insert(0, str(const))
    return parts[0] if len(parts) == 1 else "(" + " + ".join(parts) + ")"


def c_schema_header() -> str:
    """The C runtime's copy of the positional tables of the schema (fmus/native/include/uplift_schema.h):
    the roles, the energy terms, the slots (enum, names, lengths, needed per role) and the layout
    of a row of the in-process run."""
    ident = lambda s: re.sub(r"\W", "_", s).upper()
    lines = ["/* Generated from fmus/schema.py by fmus.schema.c_schema_header(): do not edit.",
             "   The positional tables the C runtime shares with the Python side: the roles (the",
             "   resource record role), the energy terms in output order, the slots of the variables",
             "   (records vr.<slot>: names, lengths, the slots each role must have) and the layout of",
             "   a row of the in-process run (simulate.c). */",
             "#ifndef UPLIFT_SCHEMA_H", "#define UPLIFT_SCHEMA_H", "",
             "/* fmus.schema.ROLES */",
             "enum { " + ", ".join(f"ROLE_{ident(r)}" for r in ROLES) + ", UP_N_ROLES };", "",
             "/* fmus.schema.ENERGY_TERMS, in output order */",
             "enum { " + ", ".join(f"UP_E_{ident(t)}" for t in ENERGY_TERMS) + ", UP_N_ENERGY };", "",
             "/* fmus.schema.SLOTS: the named runs of Real variables */",
             "enum { " + ", ".join(f"S_{ident(s)}" for s in SLOTS) + ", NSLOT };",
             "#define UP_SLOT_NAMES { " + ", ".join(f'"{s}"' for s in SLOTS) + " }",
             "/* the length of each slot's run: n interface DOFs, N interface nodes, nnodes output nodes */",
             "#define UP_SLOT_LENGTHS(n, N, nnodes) { "
             + ", ".join(_c_sum(slot_length(s), {"n": "(n)", "N": "(N)", "nodes": "(nnodes)"}) for s in SLOTS) + " }",
             "/* 1 where a role must have the slot (a row per role, in the order of the roles) */",
             "#define UP_SLOT_NEEDED { \\",
             *(f"    {{{', '.join(map(str, slot_needed(r)))}}}, /* {r} */ \\" for r in ROLES),
             "}", "",
             "/* fmus.schema.ROW: the offset of each part of a row of the in-process run and its width,",
             "   N interface nodes, m output nodes */"]
    names = {"N": "(N)", "m": "(m)", "E": "UP_N_ENERGY"}
    before = {}
    for part, length in ROW:
        lines.append(f"#define UP_ROW_{ident(part)}(N, m) {_c_sum(before, names)}")
        before = {sym: before.get(sym, 0) + length.get(sym, 0) for sym in {**before, **length}}
    lines += [f"#define UP_ROW_WIDTH(N, m) {_c_sum(before, names)}", "", "#endif", ""]
    return "\n".join(lines)


def c_headers() -> dict:
    """{file name in fmus/native/include: its text} of the headers generated from the schema."""
    return {"uplift_messages.h": c_messages_header(), "uplift_schema.h": c_schema_header()}


def c_messages_header() -> str:
    """The C runtime's copy of MESSAGES, limits and state version (fmus/native/include/uplift_messages.h)."""
    lines = ["/* Generated from fmus/schema.py by fmus.schema.c_messages_header(): do not edit.",
             "   The refusals both kinds of FMU make (printf formats, fields as %s in the order of",
             "   the Python template) and the limits of the FMI boundary. */",
             "#ifndef UPLIFT_MESSAGES_H", "#define UPLIFT_MESSAGES_H", ""]
    for key, text in MESSAGES.items():
        c = re.sub(r"\{\w+\}", "%s", text.replace("%", "%%")).replace("\\", "\\\\").replace('"', '\\"')
        lines.append(f'#define UP_MSG_{key.upper()} "{c}"')
    lines += ["", f"#define UP_SLIVER {SLIVER!r}", f"#define UP_STEP_RTOL {STEP_RTOL!r}",
              f"#define UP_TIME_TOL {TIME_TOL!r}", f"#define UP_MAX_STEPS_PER_CALL {MAX_STEPS_PER_CALL}",
              f"#define UP_STATE_VERSION {STATE_VERSION}", "", "#endif", ""]
    return "\n".join(lines)


if __name__ == "__main__":                 # python -m fmus.schema: write the generated C headers
    from pathlib import Path
    for name, text in c_headers().items():
        (Path(__file__).resolve().parent / "native" / "include" / name).write_text(text)
