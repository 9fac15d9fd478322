#!/usr/bin/env bash
# Build OMSimulator (OpenModelica's FMI and SSP host) from source, for tests/test_omsimulator.py.
#
#   benchmarks/omsimulator_build.sh SRC [PREFIX]
#
# SRC: an OMSimulator source tree with its 3rdParty submodule checked out at the commit that
# OMSimulator pins (git submodule update --init). Tested: OMSimulator acb56d9d (v3.0.0, Nov
# 2025) with 3rdParty 1168b8e, its pin; newer OMSimulator pins a 3rdParty with SUNDIALS 7, and
# does not configure with the older 3rdParty (target oms::3rd::sundials::kinsol not found).
# Needs cmake >= 3.14 and a C++17 compiler, nothing else (the third-party libraries are
# built from SRC/3rdParty). About 5 CPU minutes at -j2.
#
# PREFIX (default SRC/install) gets bin/OMSimulator. Then:
#   OMSIMULATOR=PREFIX/bin/OMSimulator python -m pytest tests/test_omsimulator.py
set -euo pipefail
src=$(cd "${1:?usage: $0 SRC [PREFIX]}" && pwd)
prefix=$(mkdir -p "${2:-$src/install}" && cd "${2:-$src/install}" && pwd)
build="$src/build"
[ -f "$src/3rdParty/CMakeLists.txt" ] || { echo "$src/3rdParty is empty: check out the submodule" >&2; exit 1; }
# without a git history and tags OMSimulator's version would read "unknown"
[ -d "$src/.git" ] || [ -f "$src/version.txt" ] || echo "v3.0.0-source" > "$src/version.txt"

nice -n 19 cmake -S "$src" -B "$build" -DCMAKE_BUILD_TYPE=Release -DCMAKE_INSTALL_PREFIX="$prefix"
nice -n 19 cmake --build "$build" --target install -j2

# The install puts the SSP schemas under lib/<arch>/OMSimulator/schema, where the Python package
# reads them; the executable looks for share/OMSimulator/schema (without them it imports an SSP
# with the warning "could not load the ssd schema file ... validation of ssd file will not be
# perfomed").
schema=$(find "$prefix/lib" -path "*/OMSimulator/schema" -type d | head -n 1)
if [ -n "$schema" ] && [ ! -d "$prefix/share/OMSimulator/schema" ]; then
    mkdir -p "$prefix/share/OMSimulator"
    cp -r "$schema" "$prefix/share/OMSimulator/schema"
fi
"$prefix/bin/OMSimulator" --version
