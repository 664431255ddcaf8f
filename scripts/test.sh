#!/usr/bin/env bash
# Builds and runs the whole test suite: a Release build (with the Python module, whose pytest
# suite runs against pip's install, and the installed CMake package's consumer test), then an
# AddressSanitizer + UndefinedBehaviorSanitizer build of the unit and command-line tests (clang),
# then a short run of every fuzz target. Uses ../shared/data when present (ADAPTISO_DATA
# overrides); data tests skip with a message otherwise.
# Every option the suite depends on is set explicitly (a build folder configured by demo.sh has
# the tests off), and ctest fails when it finds no test.
set -euo pipefail
cd "$(dirname "$0")/.."
# VTK's Python module: a reference for the marching-cubes tests and Mesh.to_vtk's target; never linked.
# clang and its sanitizer runtimes: the ASan + UBSan build and the fuzz targets.
./scripts/deps.sh python3-vtk9 clang libclang-rt-14-dev
JOBS=$(nproc)
# The tests' scratch files in memory when a tmpfs with room is at hand (4 GiB free; a container's
# /dev/shm is often 64 MB): one test writes and loads a grid file truncated at each of its 53 k
# lengths, 15.5 s on this machine's disk against 3.5 s in /dev/shm. TMPDIR set by the caller wins.
if [ -z "${TMPDIR:-}" ] && [ -d /dev/shm ] && [ -w /dev/shm ] && [ "$(df -Pk /dev/shm | awk 'NR == 2 { print $4 }')" -gt 4194304 ]; then
  export TMPDIR=/dev/shm
fi
# Unity builds (batches of sources compiled as one): a fresh tree compiles in about half the time
# (Release: 224 s against 418 s on 2 cores); incremental work in a tree of your own need not use them.
COMMON=(-G Ninja -DCMAKE_UNITY_BUILD=ON -DADAPTISO_BUILD_TESTS=ON -DADAPTISO_BUILD_APPS=ON -DADAPTISO_BUILD_PEERS=OFF)
# Each stage says when it starts (seconds since this script did): where the suite's time goes.
stage() { echo "== $1 (at $SECONDS s)"; }
stage "Release build"
cmake -S . -B build/release "${COMMON[@]}" -DCMAKE_BUILD_TYPE=Release -DADAPTISO_SANITIZE=OFF -DADAPTISO_BUILD_BENCH=ON -DADAPTISO_BUILD_PYTHON=ON >/dev/null
cmake --build build/release -j "$JOBS"
# python_module (the Python tests against the staging install) is left out: the next stage runs
# the same tests against pip's install, which is what a Python user gets.
stage "Release tests"
(cd build/release && ctest --output-on-failure --no-tests=error -j "$JOBS" --timeout 900 -E '^python_module$')
stage "Python package through pip"
# As a Python user installs it (README "Python"): a venv that sees Debian's numpy, scikit-image and
# VTK, `pip install --no-build-isolation .` (setup.py builds the adaptiso_python target of the
# Release tree above, so nothing is compiled again), the Python tests against that installed copy,
# then the wheel installed into a fresh venv, and `pip uninstall` leaving nothing behind.
PIPTEST=$(pwd)/build/release/pip-test
rm -rf "$PIPTEST" && mkdir -p "$PIPTEST"
/usr/bin/python3 -m venv --system-site-packages "$PIPTEST/venv"
export ADAPTISO_CMAKE_BUILD_DIR=build/release
"$PIPTEST/venv/bin/pip" install -q --no-build-isolation --no-index .
(cd "$PIPTEST" && env -u PYTHONPATH ADAPTISO_EXPECT_PIP=1 ADAPTISO_CLI="$(pwd)/../bin/adaptiso" \
   venv/bin/python -m pytest -q -p no:cacheprovider "$OLDPWD/python/tests")
"$PIPTEST/venv/bin/python" -m build --no-isolation --wheel --outdir "$PIPTEST/dist" . >"$PIPTEST/build.log" 2>&1 ||
  { cat "$PIPTEST/build.log"; exit 1; }
/usr/bin/python3 -m venv --system-site-packages "$PIPTEST/fresh"
"$PIPTEST/fresh/bin/pip" install -q --no-index "$PIPTEST"/dist/adaptiso-*.whl
(cd "$PIPTEST" && env -u PYTHONPATH fresh/bin/python -c "import adaptiso, numpy as np, sys
assert adaptiso.__file__.startswith(sys.prefix), adaptiso.__file__
print('wheel:', adaptiso.__version__, adaptiso.marching_cubes(np.random.rand(8, 8, 8), 0.5))")
"$PIPTEST/fresh/bin/pip" uninstall -q -y adaptiso
left=$(find "$PIPTEST/fresh/lib" -iname '*adaptiso*')
[ -z "$left" ] || { echo "pip uninstall left: $left"; exit 1; }
unset ADAPTISO_CMAKE_BUILD_DIR
stage "ASan + UBSan build"
# The compile, not the tests, is most of this stage. -O1 -g1: GCC took 2.8x as long to compile
# with ASan at -O2 -g (delaunay.cpp: 264 s against 94 s). clang: the tree in 0.77x GCC's CPU time
# (bisection_bricks.cpp 59 s against 95 s), and a second compiler's warnings and UBSan checks; the
# Release tree above stays GCC's. (A folder of its own: CMake keeps the compiler an older
# build/asan was configured with.)
CC=clang CXX=clang++ cmake -S . -B build/asan-clang "${COMMON[@]}" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG" \
  -DADAPTISO_SANITIZE=ON -DADAPTISO_BUILD_BENCH=OFF -DADAPTISO_BUILD_PYTHON=OFF >/dev/null
cmake --build build/asan-clang -j "$JOBS"
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export LSAN_OPTIONS=suppressions=$(pwd)/tests/lsan.supp:print_suppressions=0
stage "ASan + UBSan tests"
(cd build/asan-clang && ctest --output-on-failure --no-tests=error -j "$JOBS" --timeout 1800)
stage "fuzzing (a short run of every target; scripts/fuzz.sh SECONDS for a longer one)"
ADAPTISO_FUZZ_SEED=${ADAPTISO_FUZZ_SEED:-1} ./scripts/fuzz.sh "${ADAPTISO_FUZZ_SECONDS:-15}"
echo "== done in $SECONDS s"
