"""The guard of the Python FMUs: a small C library (fmus/pyguard_c/guard.c) that a python FMU ships
as its ``binaries/<platform>/<modelIdentifier>.<so|dll>``, in front of pythonfmu's own library
(shipped beside it as ``pythonfmu-export.<so|dll>`` and loaded from the guard's folder).

pythonfmu's library trusts its arguments: a NULL instance or value array, a resource location
that does not exist, a foreign FMU state pointer crash the host; it checks no GUID, accepts
model exchange and lets a host set an output or a fixed parameter at any time. The guard
refuses each of these with fmi2Error (fmi2Instantiate: NULL) and the reason in the log, as the
native FMUs do (fmus/native/fmi2.c), and forwards every legal call unchanged (the results are
pythonfmu's, bit for bit). What it needs of the FMU is the variable table written at export
from the final model description, ``resources/uplift_guard.txt``:

    uplift-pyguard 1
    guid <the GUID of modelDescription.xml>
    sizes <n Real> <n Integer> <n Boolean> <n String>     (largest value reference + 1 per type)
    <type> <value reference> <causality> <variability> <initial>     one line per variable

(the codes: CAUSALITIES, VARIABILITIES, INITIALS in that order, from 0). The defaults of
``initial`` are FMI 2.0's (table of section 2.2.7: exact for parameters and inputs, calculated
for outputs, calculated parameters and locals).

``compile_guard(platforms)`` compiles it with the C compiler of the ``ziglang`` package (as the
native runtime, fmus/native_build.py), once per process and source; ``install_guard(items)``
puts it into the members of an FMU archive.
"""
from __future__ import annotations

import hashlib
import subprocess
import sys
import tempfile
import threading
import xml.etree.ElementTree as ET
from pathlib import Path

from fmus.native_build import NATIVE, PLATFORMS, NativeBuildError, fmi_headers

SOURCE = Path(__file__).resolve().parent / "pyguard_c" / "guard.c"
#: the headers shared with the native runtime: the message table (fmus/schema.py generates it)
#: and the CRC-32 of serialised states
HEADERS = (NATIVE / "include" / "uplift_messages.h", NATIVE / "include" / "uplift_crc32.h")
TABLE_FILE = "uplift_guard.txt"
INNER_STEM = "pythonfmu-export"
CAUSALITIES = ("parameter", "calculatedParameter", "input", "output", "local", "independent")
VARIABILITIES = ("constant", "fixed", "tunable", "discrete", "continuous")
INITIALS = ("exact", "approx", "calculated")
TYPES = ("Real", "Integer", "Boolean", "String")
GUARD_CFLAGS = ("-std=c99", "-O2", "-fvisibility=hidden", "-fPIC", "-shared")

_lock = threading.Lock()
_compiled: dict = {}


def guard_table(model_description: bytes) -> str:
    """The text of resources/uplift_guard.txt for an FMI 2.0 model description."""
    root = ET.fromstring(model_description)
    rows, sizes = [], dict.fromkeys(TYPES, 0)
    for sv in root.find("ModelVariables"):
        typ = next(child.tag for child in sv if child.tag in TYPES or child.tag == "Enumeration")
        typ = "Integer" if typ == "Enumeration" else typ
        vr = int(sv.get("valueReference"))
        causality = sv.get("causality", "local")
        variability = sv.get("variability", "continuous" if typ == "Real" else "discrete")
        default = "exact" if causality in ("parameter", "input") else "calculated"
        initial = sv.get("initial", default)
        rows.append(f"{typ} {vr} {CAUSALITIES.index(causality)} {VARIABILITIES.index(variability)} "
                    f"{INITIALS.index(initial)}")
        sizes[typ] = max(sizes[typ], vr + 1)
    head = ["uplift-pyguard 1", f"guid {root.get('guid')}", "sizes " + " ".join(str(sizes[t]) for t in TYPES)]
    return "\n".join(head + rows) + "\n"


def compile_guard(platforms) -> dict:
    """{platform: bytes of the guard library} for FMI 2.0 platform names (linux64, win64,
    darwin64), compiled by ziglang's C compiler once per process and source digest."""
    digest = hashlib.sha256(b"\0".join(p.read_bytes() for p in (SOURCE, *HEADERS))).hexdigest()
    out = {}
    for platform in platforms:
        if platform not in PLATFORMS:
            raise ValueError(f"platform {platform!r}: the guard is built for {', '.join(PLATFORMS)}")
        with _lock:
            key = (digest, platform)
            if key not in _compiled:
                _compiled[key] = _compile(platform)
            out[platform] = _compiled[key]
    return out


def _compile(platform: str) -> bytes:
    target, suffix = PLATFORMS[platform]
    with tempfile.TemporaryDirectory(prefix="uplift_pyguard_") as tmp:
        lib = Path(tmp) / f"guard.{suffix}"
        cmd = [sys.executable, "-m", "ziglang", "cc", "-target", target, "-s", *GUARD_CFLAGS,
               f"-I{fmi_headers()}", f"-I{NATIVE / 'include'}", "-o", str(lib), str(SOURCE)]
        if platform == "linux64":
            cmd += ["-ldl", "-lpthread"]
        try:
            proc = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, timeout=900)
        except FileNotFoundError as exc:
            raise NativeBuildError(f"no Python to run ziglang ({exc})") from None
        if proc.returncode != 0 or not lib.is_file():
            hint = " (pip install ziglang: a dependency of uplift)" if "No module named ziglang" in proc.stderr else ""
            raise NativeBuildError(f"compiling the python FMUs' guard for {platform} failed{hint}:\n"
                                   f"{' '.join(cmd)}\n{proc.stderr[-4000:]}")
        return lib.read_bytes()


def install_guard(items: dict, identifier: str) -> dict:
    """The members of a pythonfmu FMU archive ({name: bytes}, its model description final) with
    the guard: each ``binaries/<platform>/<identifier>.<ext>`` of pythonfmu moved to
    ``binaries/<platform>/pythonfmu-export.<ext>`` and the guard in its place, and
    ``resources/uplift_guard.txt``. A platform the guard is not built for is left out of the FMU
    (pythonfmu's library alone would be unguarded)."""
    out = {name: blob for name, blob in items.items() if not name.startswith("binaries/")}
    found = {}
    for name, blob in items.items():
        parts = name.split("/")
        if len(parts) == 3 and parts[0] == "binaries" and parts[2].startswith(identifier + ".") and \
                parts[1] in PLATFORMS and parts[2] == f"{identifier}.{PLATFORMS[parts[1]][1]}":
            found[parts[1]] = blob
    if not found:
        raise NativeBuildError(f"the pythonfmu FMU {identifier} has no binary for {', '.join(PLATFORMS)}")
    guards = compile_guard(sorted(found))
    for platform, blob in sorted(found.items()):
        suffix = PLATFORMS[platform][1]
        out[f"binaries/{platform}/{identifier}.{suffix}"] = guards[platform]
        out[f"binaries/{platform}/{INNER_STEM}.{suffix}"] = blob
    out[f"resources/{TABLE_FILE}"] = guard_table(items["modelDescription.xml"]).encode()
    return out
