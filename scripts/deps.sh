#!/usr/bin/env bash
# Installs everything adaptiso needs to build and test on Debian 12 (idempotent; run as root).
set -euo pipefail
PKGS=(build-essential cmake ninja-build pkg-config
      libcgal-dev libgmp-dev libmpfr-dev libboost-dev libeigen3-dev libtbb-dev
      libcli11-dev nlohmann-json3-dev libfmt-dev libteem-dev libnifti2-dev libgdcm-dev
      libcpp-httplib-dev libtinygltf-dev zlib1g-dev libgtest-dev libgmock-dev libbenchmark-dev)
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
