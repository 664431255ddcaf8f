#!/usr/bin/env bash
# Builds every fuzz target of fuzz/ (clang's libFuzzer with AddressSanitizer and
# UndefinedBehaviorSanitizer) and runs each for SECONDS (default 60), two at a time. Exits non-zero
# on any crash, leak, timeout (a hang: 10 s on one input) or allocation above 1 GB; the input that
# found it is kept under build/fuzz/artifacts/. Corpora grow in build/fuzz/corpus/ across runs and
# start from fuzz/make_seeds.py's seeds (small crops of ../shared/data when present).
# Usage: scripts/fuzz.sh [SECONDS] [TARGET...]      (targets: nrrd nhdr nifti nifti_gz metaimage vti
# vtk dicom raw grid grid_structure ply request; default all)
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
SECS=${1:-60}
shift || true
TARGETS=("$@")
[ ${#TARGETS[@]} -gt 0 ] || TARGETS=(nrrd nhdr nifti nifti_gz metaimage vti vtk dicom raw grid grid_structure ply request)
./scripts/deps.sh clang libclang-rt-14-dev >/dev/null
BUILD=${ADAPTISO_FUZZ_BUILD:-$ROOT/build/fuzz}
echo "== fuzz build ($BUILD)"
CC=clang CXX=clang++ cmake -S fuzz -B "$BUILD" -G Ninja -DCMAKE_UNITY_BUILD=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG" >/dev/null
cmake --build "$BUILD" -j "$(nproc)"

echo "== seeds"
rm -rf "$BUILD/seeds"
python3 fuzz/make_seeds.py "$BUILD/seeds"
# Grid files come from adaptiso itself, when a build of the command line is at hand.
CLI=${ADAPTISO_CLI:-$ROOT/build/release/bin/adaptiso}
mkdir -p "$BUILD/seeds/grid"
if [ -x "$CLI" ]; then
  tmp=$(mktemp -d)
  "$CLI" generate sphere --size 6 --quiet -o "$tmp/s.nrrd"
  "$CLI" prepare "$tmp/s.nrrd" --quiet -o "$BUILD/seeds/grid/bisection.adg"
  "$CLI" prepare "$tmp/s.nrrd" --grid delaunay --quiet -o "$BUILD/seeds/grid/delaunay.adg"
  "$CLI" prepare "$tmp/s.nrrd" --max-displacement 0.5 --quiet -o "$BUILD/seeds/grid/displacement.adg"
  # Files with their index stored, as before version 6 (loading checks it instead of building it).
  "$CLI" prepare "$tmp/s.nrrd" --store-index --quiet -o "$BUILD/seeds/grid/bisection-indexed.adg"
  "$CLI" prepare "$tmp/s.nrrd" --grid delaunay --store-index --quiet -o "$BUILD/seeds/grid/delaunay-indexed.adg"
  "$CLI" mc "$tmp/s.nrrd" --iso 500 --quiet -o "$BUILD/seeds/ply/sphere.ply"
  # The structure-aware target mutates whole grid files (fuzz_grid_structure.cpp): these, and grids
  # whose box is no power-of-two cube (diamonds across its far faces) or that keep every voxel.
  mkdir -p "$BUILD/seeds/grid_structure"
  cp "$BUILD"/seeds/grid/*.adg "$BUILD/seeds/grid_structure/"
  "$CLI" generate marschner-lobb --size 7 --quiet -o "$tmp/m.nrrd"
  "$CLI" prepare "$tmp/m.nrrd" --max-error 0 --quiet -o "$BUILD/seeds/grid_structure/lossless.adg"
  "$CLI" generate noise --size 5 --quiet -o "$tmp/n.nrrd"
  "$CLI" prepare "$tmp/n.nrrd" --relative --max-error 0.1 --max-displacement 1 --quiet -o "$BUILD/seeds/grid_structure/noise.adg"
  rm -rf "$tmp"
else
  echo "fuzz: $CLI not built; the grid targets start from empty corpora"
  mkdir -p "$BUILD/seeds/grid_structure"
fi

dict_for() {
  case $1 in
    nhdr) echo nrrd ;; nifti_gz) echo nifti ;; raw | grid | grid_structure) echo "" ;; *) echo "$1" ;;
  esac
}
export ASAN_OPTIONS=detect_leaks=1:allocator_may_return_null=0 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export LSAN_OPTIONS=suppressions=$ROOT/tests/lsan.supp:print_suppressions=0
mkdir -p "$BUILD/artifacts" "$BUILD/logs"
run_one() {
  local t=$1 d
  d=$(dict_for "$t")
  mkdir -p "$BUILD/corpus/$t"
  local args=("$BUILD/corpus/$t" "$BUILD/seeds/$t" -max_total_time="$SECS" -timeout=10 -rss_limit_mb=2560 -malloc_limit_mb=1024
              -artifact_prefix="$BUILD/artifacts/$t-" -print_final_stats=1)
  # A fixed seed (ADAPTISO_FUZZ_SEED) makes a short run repeat the same inputs, as CI needs.
  [ -z "${ADAPTISO_FUZZ_SEED:-}" ] || args+=(-seed="$ADAPTISO_FUZZ_SEED")
  [ -z "$d" ] || args+=(-dict="$ROOT/fuzz/dict/$d.dict")
  # Each run in its own folder: the targets write their inputs to temporary files there.
  local work rc=0
  work=$(mktemp -d)
  (cd "$work" && TMPDIR=$work "$BUILD/fuzz_$t" "${args[@]}") >"$BUILD/logs/$t.log" 2>&1 || rc=$?
  rm -rf "$work"
  if [ $rc -eq 0 ]; then
    echo "fuzz_$t: ok, $(grep -o 'stat::number_of_executed_units: *[0-9]*' "$BUILD/logs/$t.log" | grep -o '[0-9]*$') runs in ${SECS} s"
  else
    echo "fuzz_$t: FAILED (log $BUILD/logs/$t.log)"
    grep -E "ERROR|SUMMARY|Test unit written" "$BUILD/logs/$t.log" | head -5
    return 1
  fi
}
export -f run_one dict_for
export BUILD ROOT SECS
echo "== fuzzing ${#TARGETS[@]} targets for ${SECS} s each"
printf '%s\n' "${TARGETS[@]}" | xargs -P "$(nproc)" -I{} bash -c 'run_one {}'
