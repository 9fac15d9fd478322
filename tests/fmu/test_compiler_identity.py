"""The system compiler's identity in the native library's hash: kept in the library's folder under
the compiler file's key, read back by a warm run instead of starting the compiler."""
import os
import subprocess

import pytest

import fmus.native_stepper as native_stepper


def _fake_compiler(path, version: str):
    path.write_text(f"#!/bin/sh\necho '{version}'\n")
    path.chmod(0o755)


@pytest.mark.skipif(os.name != "posix", reason="a shell script stands for the compiler")
def test_the_compiler_identity_is_kept_read_back_and_asked_again_when_the_compiler_changes(tmp_path, monkeypatch):
    bin_dir, folder = tmp_path / "bin", tmp_path / "native"
    bin_dir.mkdir()
    cc = bin_dir / "fakecc"
    _fake_compiler(cc, "fakecc 1.0")
    monkeypatch.setenv("CC", "fakecc")
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    asked = []
    real = subprocess.run

    def counted(cmd, *args, **kwargs):
        asked.append(cmd)
        return real(cmd, *args, **kwargs)

    monkeypatch.setattr(native_stepper.subprocess, "run", counted)
    first = native_stepper._compiler(folder)
    assert first == ("cc", "fakecc: fakecc 1.0") and len(asked) == 1
    assert native_stepper._compiler(folder) == first and len(asked) == 1         # read back, not asked
    assert native_stepper._compiler() == first and len(asked) == 2              # no folder: asked each time
    assert native_stepper._digest(first[1]) == native_stepper._digest(native_stepper._compiler(folder)[1])

    kept, = folder.glob("compiler-*.txt")
    kept.write_text(kept.read_text().replace("1.0", "9.9"))                      # damaged: asked again
    assert native_stepper._compiler(folder) == first and len(asked) == 3
    assert native_stepper._compiler(folder) == first and len(asked) == 3

    _fake_compiler(cc, "fakecc 2.0")                                            # changed in place
    st = cc.stat()
    os.utime(cc, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    second = native_stepper._compiler(folder)
    assert second == ("cc", "fakecc: fakecc 2.0") and len(asked) == 4
    assert native_stepper._digest(second[1]) != native_stepper._digest(first[1])
    assert len(list(folder.glob("compiler-*.txt"))) == 2
