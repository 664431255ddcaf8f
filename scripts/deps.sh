#!/usr/bin/env bash
# Installs everything adaptiso needs to build and test on Debian 12 (idempotent; run as root).
# Usage: scripts/deps.sh [EXTRA_PACKAGE...]   (extra Debian packages, e.g. the benchmark's peers)
set -euo pipefail
cd "$(dirname "$0")/.."
PKGS=(build-essential cmake ninja-build pkg-config
      libcgal-dev libgmp-dev libmpfr-dev libboost-dev libeigen3-dev libtbb-dev
      libcli11-dev nlohmann-json3-dev libfmt-dev libteem-dev libbz2-dev libnifti2-dev libgdcm-dev
      libcpp-httplib-dev libtinygltf-dev zlib1g-dev libdeflate-dev libgtest-dev libgmock-dev libbenchmark-dev
      libmeshoptimizer-dev pybind11-dev python3-dev python3-numpy python3-pytest python3-skimage
      python3-matplotlib chromium "$@")
# The distributed engine (mpirun -np N adaptiso prepare): OpenMPI's headers and launcher. A build
# without them still works and says so when started under mpirun. mpi4py: the Python module's
# transport under mpirun (adaptiso.prepare(..., comm=MPI.COMM_WORLD)); the module itself needs none.
PKGS+=(libopenmpi-dev openmpi-bin python3-mpi4py)
# The Python package's pip route (pyproject.toml → setuptools → setup.py → CMake) in a venv, the
# wheel route (python3 -m build), and the hand-offs its tests exercise (Mesh.to_meshio, nibabel
# images as volumes; Mesh.to_vtk takes python3-vtk9, which scripts/test.sh asks for).
PKGS+=(python3-venv python3-pip python3-setuptools python3-wheel python3-build python3-meshio python3-nibabel)
# The viewer page and its browser test need node and npm; a node install that already brings npm
# (e.g. NodeSource's) is kept, Debian's packages are added otherwise.
command -v npm >/dev/null 2>&1 || PKGS+=(nodejs npm)
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "installing: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq "${missing[@]}" >/dev/null
fi
# three.js and the meshoptimizer decoder for the viewer page and playwright-core for its test,
# pinned by web/package-lock.json.
if [ ! -f web/node_modules/three/build/three.module.js ] || [ ! -f web/node_modules/playwright-core/package.json ] ||
   [ ! -f web/node_modules/meshoptimizer/meshopt_decoder.module.js ] ||
   [ web/package-lock.json -nt web/node_modules/.package-lock.json ]; then
  echo "installing the viewer's npm packages (web/)"
  (cd web && npm ci --no-audit --no-fund --loglevel=error)
fi
