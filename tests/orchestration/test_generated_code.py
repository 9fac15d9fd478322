"""The methods dataclasses generate, compiled once and kept: the classes they make are those exec
makes, a second process reads them back, a damaged file is ignored and rewritten."""
import json
import subprocess
import sys

from uplift_common.generated_code import GeneratedCode, code_file

PROBE = r"""
import dataclasses, json, sys
from uplift_common.generated_code import GeneratedCode, code_file, installed

def classes():
    @dataclasses.dataclass(frozen=True)
    class Frozen:
        a: int
        b: float = 2.0
        c: tuple = dataclasses.field(default_factory=tuple)

    @dataclasses.dataclass(order=True, eq=True)
    class Ordered:
        x: int
        y: str = "y"

    @dataclasses.dataclass(slots=True, kw_only=True)
    class Slotted:
        p: list = dataclasses.field(default_factory=list)
        q: int = 3
    return Frozen, Ordered, Slotted

def describe(Frozen, Ordered, Slotted):
    f = Frozen(1)
    try:
        f.a = 5
        frozen = "assigned"
    except dataclasses.FrozenInstanceError:
        frozen = "refused"
    methods = {}
    for cls in (Frozen, Ordered, Slotted):
        for name in ("__init__", "__repr__", "__eq__", "__hash__", "__setattr__", "__lt__"):
            fn = cls.__dict__.get(name)
            code = getattr(fn, "__code__", None)
            methods[f"{cls.__name__}.{name}"] = None if code is None else [code.co_code.hex(), repr(code.co_consts),
                                                                            code.co_names, code.co_filename]
    return {"repr": [repr(f), repr(Ordered(2)), repr(Slotted(p=[1]))], "eq": Frozen(1) == Frozen(1),
            "hash": hash(f) == hash(Frozen(1)), "lt": Ordered(1) < Ordered(2), "frozen": frozen,
            "methods": methods}

folder = sys.argv[1]
plain = describe(*classes())
codes = GeneratedCode(None if folder == "-" else code_file(folder))
kept = len(codes.codes)
with installed(codes):
    cached = describe(*classes())
assert "exec" not in vars(dataclasses)
codes.save()
print(json.dumps({"same": plain == cached, "kept": kept, "new": codes.new, "all": len(codes.codes), "plain": plain}))
"""


def _probe(folder):
    out = subprocess.run([sys.executable, "-c", PROBE, str(folder)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_generated_methods_are_exec_s_and_are_read_back_by_the_next_process(tmp_path):
    first = _probe(tmp_path)
    assert first["same"] and first["kept"] == 0 and first["all"] > 10
    assert first["plain"]["frozen"] == "refused" and first["plain"]["eq"] and first["plain"]["lt"]
    second = _probe(tmp_path)                         # read back: nothing compiled, the same classes
    assert second["same"] and second["kept"] == first["all"] and second["all"] == first["all"]
    assert second["plain"] == first["plain"]
    path = code_file(tmp_path)
    blob = bytearray(path.read_bytes())
    blob[len(blob) // 2] ^= 0x01                      # one flipped bit: the file is ignored, then rewritten
    path.write_bytes(bytes(blob))
    damaged = _probe(tmp_path)
    assert damaged["same"] and damaged["kept"] == 0 and damaged["all"] == first["all"]
    assert len(GeneratedCode(path).codes) == first["all"]
    assert _probe("-")["same"]                        # no folder: compiled, nothing kept


def test_a_foreign_or_truncated_file_is_ignored(tmp_path):
    path = code_file(tmp_path)
    for blob in (b"", b"short", b"\0" * 32 + b"not marshal"):
        path.write_bytes(blob)
        assert GeneratedCode(path).codes == {}
