#!/usr/bin/env bash
# Installs the build into a staging prefix (as `cmake --install BUILD --prefix P` would anywhere),
# then builds the consumer project against the installed CMake package and runs it, and checks
# the pkg-config file. Usage: check_install.sh BUILD_DIR STAGE_DIR VERSION
set -euo pipefail
build=$1 stage=$2 version=$3
here=$(cd "$(dirname "$0")" && pwd)
rm -rf "$stage" "$stage-consumer"
cmake --install "$build" --prefix "$stage" >/dev/null
cmake -S "$here/consumer" -B "$stage-consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$stage" >/dev/null
cmake --build "$stage-consumer" >/dev/null
out=$(LD_LIBRARY_PATH="$stage/lib:$stage/lib/$(gcc -print-multiarch 2>/dev/null || true)" "$stage-consumer/consumer")
echo "$out"
[[ $out == "adaptiso $version: "* ]] || { echo "the consumer did not report version $version"; exit 1; }
pc=$(find "$stage" -name adaptiso.pc | head -1)
[ -n "$pc" ] || { echo "no adaptiso.pc installed"; exit 1; }
[ "$(PKG_CONFIG_PATH=$(dirname "$pc") pkg-config --modversion adaptiso)" = "$version" ] || { echo "pkg-config reports another version"; exit 1; }
# The pkg-config flags build and link the same program.
flags=$(PKG_CONFIG_PATH=$(dirname "$pc") pkg-config --cflags --libs adaptiso)
# shellcheck disable=SC2086
c++ "$here/consumer/main.cpp" $flags -o "$stage-consumer/consumer-pc"
LD_LIBRARY_PATH=$(dirname "$(dirname "$pc")") "$stage-consumer/consumer-pc" >/dev/null
echo "installed package: CMake and pkg-config consumers built and ran"
