#!/usr/bin/env bash
# The side-by-side benchmark against the peers (VTK, OpenVDB, scikit-image, meshoptimizer), all from
# Debian's packages. Usage: ./scripts/bench.sh [DATASET...]   (default: the sphere, every volume in
# ../shared/data, and a synthetic 512³ volume). Writes bench/results/<date>.json, .md and two plots.
# Options through the environment: BENCH_ERRORS (relative errors, default 0.05), BENCH_REPEAT (3).
set -euo pipefail
cd "$(dirname "$0")/.."
PEERS=(libvtk9-dev python3-vtk9 libopenvdb-dev libboost-iostreams-dev python3-skimage libmeshoptimizer-dev python3-matplotlib)
./scripts/deps.sh "${PEERS[@]}"
cmake -S . -B build/peers -G Ninja -DCMAKE_BUILD_TYPE=Release -DADAPTISO_BUILD_TESTS=OFF -DADAPTISO_BUILD_APPS=ON \
  -DADAPTISO_BUILD_BENCH=ON -DADAPTISO_BUILD_PEERS=ON -DADAPTISO_SANITIZE=OFF >/dev/null
cmake --build build/peers --target adaptiso_cli bench_extract bench_simplify peer_bench
exec /usr/bin/python3 bench/run_bench.py --build build/peers --data "${ADAPTISO_DATA:-../shared/data}" --out bench/results \
  --work build/bench-work --errors "${BENCH_ERRORS:-0.05}" --repeat "${BENCH_REPEAT:-3}" "$@"
