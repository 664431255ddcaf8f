#!/usr/bin/env bash
# Regenerates docs/figures/: the paper's figures (Lürig & Ertl 1998, Figures 1, 3, 5, 6, 8, 9 and
# 10) drawn by adaptiso's viewer page in Debian's headless chromium, and FIGURES.md with each
# figure's numbers. Needs the program built (./scripts/demo.sh does it) and, for the CT figures,
# ../shared/data (ADAPTISO_DATA). Usage: scripts/figures.sh [OUT_DIR]   (default docs/figures)
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/deps.sh >/dev/null
CLI=${ADAPTISO_CLI:-build/release/bin/adaptiso}
if [ ! -x "$CLI" ]; then
  echo "figures: $CLI is not built; run ./scripts/demo.sh first (or set ADAPTISO_CLI)" >&2
  exit 2
fi
command -v chromium >/dev/null || [ -x "${CHROMIUM:-}" ] || { echo "figures: no chromium (apt-get install chromium)" >&2; exit 2; }
node scripts/figures.mjs "$(realpath "$CLI")" "${1:-docs/figures}" "${ADAPTISO_DATA:-../shared/data}"
