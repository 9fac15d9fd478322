"""The plain C test hosts of the native FMUs (tests/fmu/native: host.c for FMI 2.0, host3.c for
FMI 3.0) and the unpacked FMU they run."""
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

NATIVE_HOSTS = Path(__file__).resolve().parents[1] / "fmu" / "native"


def compile_host(source: str, folder: Path) -> Path:
    """The host ``source`` (in tests/fmu/native) compiled by the system compiler into ``folder``;
    skips the test where that cannot be done (not Linux, no compiler)."""
    from fmus.native_build import fmi_headers
    cc = shutil.which("cc") or shutil.which("gcc")
    if sys.platform != "linux" or cc is None:
        pytest.skip("the C host test needs Linux and a C compiler")
    exe = folder / Path(source).stem
    subprocess.run([cc, "-O1", "-rdynamic", f"-I{fmi_headers()}", str(NATIVE_HOSTS / source), "-o", str(exe),
                    "-ldl", "-lm"], check=True, capture_output=True, text=True)
    return exe


def compile_harness(code: str, folder: Path, name: str, sources) -> Path:
    """A C test program ``code`` (written to ``folder``/``name``.c) linked with the runtime files
    ``sources`` of fmus/native, as the runtime is compiled (-O3, no contraction), baseline kernels
    only (a third of the compile time: every width computes the same bits,
    test_native_stepper.py); skips the test where that cannot be done (not Linux, no compiler)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if sys.platform != "linux" or cc is None:
        pytest.skip("needs Linux and a C compiler")
    native = Path(__file__).resolve().parents[2] / "fmus" / "native"
    src, exe = folder / f"{name}.c", folder / name
    src.write_text(code)
    subprocess.run([cc, "-std=c99", "-O3", "-ffp-contract=off", "-DUP_BASELINE_ONLY", f"-I{native / 'include'}",
                    f"-I{native}", str(src), *[str(native / s) for s in sources], "-o", str(exe), "-lm"],
                   check=True, capture_output=True, text=True)
    return exe


def unpack_fmu(fmu, dest: Path, platform: str):
    """Unzip an FMU; returns (folder, its ``platform`` library (binaries/<platform>/*.so), GUID or
    instantiation token, {variable name: value reference})."""
    from fmpy import read_model_description
    with zipfile.ZipFile(fmu) as z:
        z.extractall(dest)
    md = read_model_description(str(fmu))
    lib = dest / "binaries" / platform / f"{md.coSimulation.modelIdentifier}.so"
    return dest, lib, md.guid, {v.name: v.valueReference for v in md.modelVariables}
