#!/usr/bin/env bash
# `mpirun -np N adaptiso extract` shares the iso-values out over the ranks (rank r takes r, r + N,
# …) and writes the meshes one process writes, byte for byte, for N = 2, 3, 4 (oversubscribed) on
# every route: a scan (a few values a rank), the sweeping index (more), a distance with and without
# collapses, a coarser error, and --simplify; a rank without an iso-value of its own; surfaces at
# a distance made by all ranks together (--rank-share surfaces, and auto's last n mod N values);
# --json in the values' order with what each rank did. A rank that cannot write its mesh names itself, exit
# 2, and no mesh of any rank reaches its name; nor when a rank is killed mid-run (issue 38); a
# rank that alone cannot open its grid, or whose memory limit alone refuses it, is heard.
# Usage: extract_over_ranks.sh ADAPTISO MPIEXEC
set -euo pipefail
# shellcheck source=ranks_common.sh
source "$(dirname "$0")/ranks_common.sh" "$@"

"$CLI" generate marschner-lobb --size 33 --quiet -o "$W/ml.nrrd"
"$CLI" prepare "$W/ml.nrrd" --quiet -o "$W/ml.adg"
# 23×17×9 uint8 noise, anisotropic spacing.
noise_raw 2468 $((23 * 17 * 9)) "$W/noise.raw"
"$CLI" prepare "$W/noise.raw" --dims 23,17,9 --type uint8 --spacing 1,0.7,2.5 --quiet -o "$W/noise.adg"
# Refined below the depth whose subtrees are dealt out when ranks make a surface together.
"$CLI" generate noise --size 64 --quiet -o "$W/n.nrrd"
"$CLI" prepare "$W/n.nrrd" --quiet -o "$W/n.adg"

check() {  # NAME GRID [extract options...]
  local name=$1 grid=$2
  shift 2
  mkdir -p "$W/$name-one"
  "$CLI" extract "$grid" "$@" --quiet -o "$W/$name-one/s.ply"
  local files
  files=$(cd "$W/$name-one" && ls)
  for np in 2 3 4; do
    mkdir -p "$W/$name-np$np"
    ranks $np "$CLI" extract "$grid" "$@" --threads 1 --quiet -o "$W/$name-np$np/s.ply"
    [ "$(cd "$W/$name-np$np" && ls)" = "$files" ] || { echo "FAIL: $name over $np ranks wrote other files"; exit 1; }
    for f in $files; do
      cmp "$W/$name-one/$f" "$W/$name-np$np/$f" || { echo "FAIL: $name over $np ranks: $f differs"; exit 1; }
    done
  done
  echo "ok: $name ($(echo $files | wc -w) meshes, the same bytes from 1, 2, 3 and 4 ranks)"
}
check scan "$W/ml.adg" --iso 0.2,0.45,0.7 --relative
check sweep "$W/ml.adg" --iso 0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,0.35,0.65 --relative
check one-value "$W/ml.adg" --iso 0.5 --relative
check distance "$W/ml.adg" --iso 0.3,0.5,0.7 --relative --distance 1
check distance-no-collapse "$W/noise.adg" --iso 60,128,200 --distance 0.5 --collapse 0
check distance-together "$W/n.adg" --iso 0.35,0.5 --relative --distance 0.5 --rank-share surfaces
check distance-together-no-collapse "$W/noise.adg" --iso 60,128 --distance 0.5 --collapse 0 --rank-share surfaces
check distance-in-turn "$W/noise.adg" --iso 60,128,200 --distance 1 --rank-share values
check coarser "$W/noise.adg" --iso 60,90,128,160,200 --max-error 40
check simplified "$W/noise.adg" --iso 90,128,160 --simplify 0.5

# --json: one object on rank 0, the surfaces in the order of the iso-values, what each rank did.
ranks 3 "$CLI" extract "$W/ml.adg" --iso 0.1,0.3,0.5,0.7 --relative --distance 1 --json -o "$W/j.ply" >"$W/j.json"
/usr/bin/env python3 -c "
import json, sys
j = json.load(open(sys.argv[1]))
isos = [s['iso'] for s in j['surfaces']]
assert isos == sorted(isos) and len(isos) == 4, isos
assert [s['output'].rsplit('-', 1)[1] for s in j['surfaces']] == ['0.1.ply', '0.3.ply', '0.5.ply', '0.7.ply'], j['surfaces']
r = j['ranks']
# auto: 0.1, 0.3, 0.5 dealt in turn, 0.7 made by the three together
assert r['ranks'] == 3 and r['iso_values_per_rank'] == [1, 1, 1] and r['iso_values_made_together'] == 1, r
assert len(r['peak_bytes_per_rank']) == 3 and all(p > 0 for p in r['peak_bytes_per_rank']), r
assert len(r['load_seconds_per_rank']) == 3 and r['bytes_exchanged'] > 0, r
print('ok: --json', r['iso_values_per_rank'])" "$W/j.json"

# A rank that cannot write its own mesh (rank 1's is a folder) names itself, exit 2; rank 0's
# mesh, staged, never reaches its name.
mkdir -p "$W/bad" "$W/bad/s-0.5.ply"
set +e
ranks 2 "$CLI" extract "$W/ml.adg" --iso 0.3,0.5 --relative --quiet -o "$W/bad/s.ply" >"$W/bad.out" 2>&1
code=$?
set -e
[ $code -eq 2 ] || { echo "FAIL: an unwritable mesh under mpirun exited $code"; cat "$W/bad.out"; exit 1; }
grep -q "adaptiso (rank 1): .*s-0.5.ply" "$W/bad.out" || { echo "FAIL: the failing rank did not name itself"; cat "$W/bad.out"; exit 1; }
[ ! -e "$W/bad/s-0.3.ply" ] || { echo "FAIL: rank 0's mesh reached its name though rank 1 failed"; exit 1; }
[ -z "$(ls -A "$W/bad" | grep -v '^s-0.5.ply$')" ] || { echo "FAIL: files left behind"; ls -la "$W/bad"; exit 1; }
echo "ok: a rank's own failure is told by that rank, exit 2, and no mesh reaches its name"

# lone_failure PATTERN WHAT GRID [OPTIONS...]: rank 0 extracts ml.adg, rank 1 (mpirun's colon)
# GRID with OPTIONS; fails unless the job exits 2 with PATTERN in its output and leaves no file.
mkdir -p "$W/lone"
lone_failure() {
  local pattern=$1 what=$2 code
  shift 2
  set +e
  "$MPIEXEC" -np 1 "$CLI" extract "$W/ml.adg" --iso 0.3,0.5 --relative --quiet -o "$W/lone/s.ply" : \
    -np 1 "$CLI" extract "$@" --iso 0.3,0.5 --relative --quiet -o "$W/lone/s.ply" >"$W/lone.out" 2>&1
  code=$?
  set -e
  [ $code -eq 2 ] || { echo "FAIL: $what exited $code"; cat "$W/lone.out"; exit 1; }
  grep -q "$pattern" "$W/lone.out" || { echo "FAIL: $what: the lone failing rank's message was lost"; cat "$W/lone.out"; exit 1; }
  [ -z "$(ls -A "$W/lone")" ] || { echo "FAIL: $what: files left behind"; ls -la "$W/lone"; exit 1; }
  echo "ok: $what: told, exit 2"
}
# A rank that alone cannot open its grid: the shared load's first step makes every rank refuse
# with its message, naming it (regression: rank 0 waited for it, and its message was lost when
# the job stopped).
lone_failure "adaptiso: .*absent.adg: no such file (process 1)" "a rank alone unable to open its grid" "$W/absent.adg"
# A failure no other rank meets or hears of (rank 1's memory limit refuses the load): that rank
# tells it, with its number, before the job stops (regression: it left the message to rank 0).
lone_failure "adaptiso (rank 1): .*ml.adg: loading a grid of" "a rank whose own memory limit refuses the load" "$W/ml.adg" --memory-limit 1M

# A rank killed mid-run: mpirun fails and no mesh appears under its name.
mkdir -p "$W/killed"
kill_a_rank 1 "$CLI" extract "$W/n.adg" --iso 0.3,0.4,0.5,0.6 --relative --distance 0.5 --threads 1 --quiet -o "$W/killed/s.ply"
[ -z "$(ls -A "$W/killed")" ] || { echo "FAIL: a killed run left files"; ls -la "$W/killed"; exit 1; }
echo "ok: a killed rank leaves no mesh (mpirun exit $killed_code)"
# The same while the ranks make each surface together (a rank waits in the exchange for the dead one).
mkdir -p "$W/killed-together"
kill_a_rank 1 "$CLI" extract "$W/n.adg" --iso 0.3,0.4,0.5,0.6 --relative --distance 0.5 --threads 1 --rank-share surfaces --quiet \
  -o "$W/killed-together/s.ply"
[ -z "$(ls -A "$W/killed-together")" ] || { echo "FAIL: a killed run left files"; ls -la "$W/killed-together"; exit 1; }
echo "ok: a rank killed while the ranks make surfaces together leaves no mesh (mpirun exit $killed_code)"
