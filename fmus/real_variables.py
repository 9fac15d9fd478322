"""The Real variables of a Python FMU: one float64 bank indexed by value reference, filled
from the schema (fmus/schema.py), and the units written into the model description."""
from __future__ import annotations

import numpy as np

from fmus.schema import UNITS, vectors


class RealBank:
    """All Real variables of an FMU in one float64 vector indexed by value reference.

    pythonfmu calls ``get_real(vrs)`` / ``set_real(vrs, values)`` once per FMI call with a
    fresh Python list of value references; with the bank these are one numpy gather / scatter
    instead of one Python getter per scalar (a 247-DOF interface would otherwise cost ~1000
    Python calls per step). ``index(vrs)`` memoises the list -> index conversion, since a host
    asks for the same lists every step.
    """

    MAX_INDICES = 64                    # memoised value-reference lists (a host uses a few)

    def __init__(self):
        self.values = np.zeros(0)
        self.slots = {}                 # name -> slice or index into values
        self._indices = {}              # (len, first, last) -> (the list, its index)

    def grow(self, n: int) -> None:
        self.values = np.concatenate([self.values, np.zeros(n)])

    def index(self, vrs):
        """Index into ``values`` of the value references ``vrs`` (a list): a slice when they are
        consecutive, else an int array. Memoised; a hit is checked against the whole list
        (one C-level list comparison), so it is exact."""
        if type(vrs) is not list:       # pythonfmu passes lists; anything else is made one
            vrs = [int(v) for v in vrs]
        key = (len(vrs), vrs[0], vrs[-1]) if vrs else ()
        hit = self._indices.get(key)
        if hit is not None and hit[0] == vrs:
            return hit[1]
        idx = np.asarray(vrs, int)
        if idx.size and not 0 <= idx.min() <= idx.max() < self.values.size:
            raise IndexError(f"value references {idx.min()}..{idx.max()}: the Real variables of "
                             f"this FMU are 0..{self.values.size - 1}")
        if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
            idx = slice(int(idx[0]), int(idx[0]) + idx.size)
        if len(self._indices) >= self.MAX_INDICES:
            self._indices.clear()
        self._indices[key] = (list(vrs), idx)
        return idx


def register_schema(fmu, role: str, n: int, N: int, nodes=()) -> dict:
    """Register every Real variable of ``role`` (fmus.schema.vectors) backed by ``fmu.bank``, in
    schema order, so that the bank index of a variable is its value reference; returns
    {vector name: slice of the bank}. The units go to ``fmu.units`` (written by
    ``BankedSlave.to_xml``)."""
    from pythonfmu import Real
    from pythonfmu.enums import Fmi2Causality

    bank = fmu.bank
    if len(fmu.vars) or bank.values.size:
        raise RuntimeError("register the schema's Real variables first, once")
    units = fmu.__dict__.setdefault("units", {})
    slices = {}
    for vec in vectors(role, nodes):
        names, vunits = vec.names(n, N), vec.units(n, N)
        first = bank.values.size
        bank.grow(len(names))
        for i, (vname, unit) in enumerate(zip(names, vunits)):
            vr = first + i
            fmu.register_variable(Real(vname, causality=getattr(Fmi2Causality, vec.causality),
                                       description=vec.description,
                                       getter=(lambda vr=vr: float(bank.values[vr])),
                                       setter=(lambda v, vr=vr: bank.values.__setitem__(vr, v))), nested=False)
            units[vname] = unit
        slices[vec.name] = bank.slots[vec.name] = slice(first, first + len(names))
    return slices


def add_units(root, units: dict) -> None:
    """Write ``unit`` on the Real variables named in ``units`` and the UnitDefinitions they use
    into a modelDescription element tree (UnitDefinitions placed after CoSimulation, as FMI 2.0
    orders the elements)."""
    import xml.etree.ElementTree as ET

    used = []
    for sv in root.iter("ScalarVariable"):
        unit = units.get(sv.get("name"))
        if unit is not None:
            sv.find("Real").set("unit", unit)
            used.append(unit)
    if not used:
        return
    defs = ET.Element("UnitDefinitions")
    for unit in dict.fromkeys(used):
        ET.SubElement(ET.SubElement(defs, "Unit", name=unit), "BaseUnit",
                      {k: str(v) for k, v in UNITS[unit].items()})
    after = [i for i, el in enumerate(root) if el.tag in ("CoSimulation", "ModelExchange")]
    root.insert(after[-1] + 1 if after else 0, defs)
