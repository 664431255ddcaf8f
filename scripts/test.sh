#!/usr/bin/env bash
# Builds and runs the whole test suite: a Release build (with the Python module, whose pytest
# suite runs against a staging install, and the installed CMake package's consumer test), then an
# AddressSanitizer + UndefinedBehaviorSanitizer build of the unit tests. Uses ../shared/data when present
# (ADAPTISO_DATA overrides); data tests skip with a message otherwise. Every option the suite
# depends on is set explicitly (a build folder configured by demo.sh has the tests off), and
# ctest fails when it finds no test.
set -euo pipefail
cd "$(dirname "$0")/.."
# VTK's Python module is a reference for the marching-cubes tests only, never linked.
./scripts/deps.sh python3-vtk9
JOBS=$(nproc)
COMMON=(-G Ninja -DADAPTISO_BUILD_TESTS=ON -DADAPTISO_BUILD_APPS=ON -DADAPTISO_BUILD_PEERS=OFF)
echo "== Release build"
cmake -S . -B build/release "${COMMON[@]}" -DCMAKE_BUILD_TYPE=Release -DADAPTISO_SANITIZE=OFF -DADAPTISO_BUILD_BENCH=ON -DADAPTISO_BUILD_PYTHON=ON >/dev/null
cmake --build build/release -j "$JOBS"
(cd build/release && ctest --output-on-failure --no-tests=error -j "$JOBS" --timeout 900)
echo "== ASan + UBSan build"
cmake -S . -B build/asan "${COMMON[@]}" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DADAPTISO_SANITIZE=ON -DADAPTISO_BUILD_BENCH=OFF -DADAPTISO_BUILD_PYTHON=OFF >/dev/null
cmake --build build/asan -j "$JOBS"
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export LSAN_OPTIONS=suppressions=$(pwd)/tests/lsan.supp:print_suppressions=0
(cd build/asan && ctest --output-on-failure --no-tests=error -j "$JOBS" --timeout 1800)
echo "== fuzzing (a short run of every target; scripts/fuzz.sh SECONDS for a longer one)"
ADAPTISO_FUZZ_SEED=${ADAPTISO_FUZZ_SEED:-1} ./scripts/fuzz.sh "${ADAPTISO_FUZZ_SECONDS:-15}"
