#!/usr/bin/env bash
# Checks that every C++ file of the project follows .clang-format (exit 1 and the offending files
# otherwise). `scripts/check-format.sh --fix` formats them instead.
set -euo pipefail
cd "$(dirname "$0")/.."
CF=$(command -v clang-format-14 || command -v clang-format || true)
[ -n "$CF" ] || { echo "clang-format not found (Debian: clang-format)"; exit 77; }
mapfile -t files < <(git ls-files '*.cpp' '*.hpp' 2>/dev/null || find include src apps tests bench fuzz python -name '*.[ch]pp')
if [ "${1:-}" = "--fix" ]; then exec "$CF" -i "${files[@]}"; fi
bad=0
for f in "${files[@]}"; do
  [ -f "$f" ] || continue
  if ! "$CF" --dry-run -Werror "$f" >/dev/null 2>&1; then echo "not formatted: $f"; bad=1; fi
done
exit $bad
