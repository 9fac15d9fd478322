"""A pytest plugin that compiles the native runtime under AddressSanitizer: a developer's check of
the C code (fmus/native/) for memory errors, not part of the suite. With gcc, from the checkout:

    mkdir -p /tmp/asan
    LD_PRELOAD="$(gcc -print-file-name=libasan.so) $(gcc -print-file-name=libstdc++.so.6)" \\
    ASAN_OPTIONS=detect_leaks=0:log_path=/tmp/asan/report PYTHONPATH=tests \\
        python -m pytest -p helpers.asan tests/fmu

Every library ``cc`` compiles in the test process (the host library of the in-process routes and
the native FMUs that fmpy loads) is built with ``-fsanitize=address`` at -O1 (its own content
hash: the usual library is not replaced); zig's cross builds are left as they are. libstdc++ is
preloaded with libasan so that the pythonfmu FMUs' C++ exceptions pass through. Reports go to
``log_path`` (pytest captures the process's stderr): no ``/tmp/asan/report.*`` file whose first
line says ``ERROR: AddressSanitizer`` means no error found. Child processes inherit the preload
and some of them fail for it (the plain C host, built without the sanitizer): their reports
("CHECK failed ... tsd_key_inited") and test failures are not findings.
"""
import fmus.native_build as native_build
import fmus.native_stepper as native_stepper

PLAIN = native_build.CFLAGS
SANITIZED = tuple(f for f in PLAIN if f != "-O3") + ("-O1", "-g", "-fsanitize=address", "-fno-omit-frame-pointer")
_compile_runtime = native_build.compile_runtime


def compile_runtime(platforms=None, compiler="zig", *args, **kwargs):
    """native_build.compile_runtime with the sanitizer's flags when the host's cc compiles."""
    native_build.CFLAGS = SANITIZED if compiler == "cc" else PLAIN
    try:
        return _compile_runtime(platforms, compiler, *args, **kwargs)
    finally:
        native_build.CFLAGS = PLAIN


native_build.compile_runtime = native_stepper.compile_runtime = compile_runtime
native_stepper.CFLAGS = SANITIZED          # in the host library's content hash: a library of its own
