#!/usr/bin/env bash
# `mpirun -np N adaptiso view GRID.adg` (issue 38): rank 0 serves, the other ranks make the
# surfaces within a distance. Checks, against one process serving the same grid:
# - the answers to /api/surface?distance= (plain and compact, with and without collapses, a 400)
#   are the same bytes, made by rank 1 when asked one at a time (X-Rank);
# - asked at once from 3 clients of a 3-rank job, the answers are one process's and come from
#   more than one rank (rank 0 takes what finds the others busy);
# - a page's next request cancels its previous one on the rank making it (409), and the next is
#   one process's;
# - an export with distance= is one process's; a volume (not a grid) and a Delaunay grid (no
#   hierarchy: nothing for the other ranks to make) are refused with exit 2 on every rank, and so
#   is a port in use (the other ranks stopped, not left waiting); a killed rank ends the job.
# - an allocation that fails on rank 0 while it takes a rank's answer (SHIM, fail_alloc_shim.cpp)
#   costs that surface a 503, and the answers after it are the ones asked for.
# Usage: view_over_ranks.sh ADAPTISO MPIEXEC [SHIM]
set -euo pipefail
# shellcheck source=ranks_common.sh
source "$(dirname "$0")/ranks_common.sh" "$@"
SHIM=${3:-}
WEB=$(cd "$(dirname "$0")/../../web" && pwd)

"$CLI" generate marschner-lobb --size 33 --quiet -o "$W/ml.nrrd"
"$CLI" prepare "$W/ml.nrrd" --quiet -o "$W/ml.adg"
# 80³ uint8 noise: queries long enough (a second or two) to overlap and to be cancelled.
noise_raw 1357 $((80 * 80 * 80)) "$W/noise.raw"
"$CLI" prepare "$W/noise.raw" --dims 80,80,80 --type uint8 --quiet -o "$W/noise.adg"

PIDS=()
cleanup_servers() { for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; }
trap 'cleanup_servers; rm -rf "$W"' EXIT

# serve NAME COMMAND...: starts a viewer in the background, waits for its address, sets URL_NAME.
serve() {
  local name=$1
  shift
  "$@" --port 0 --quiet --web "$WEB" >"$W/$name.out" 2>"$W/$name.err" &
  PIDS+=($!)
  for _ in $(seq 1 600); do
    grep -q "serving http" "$W/$name.out" 2>/dev/null && break
    sleep 0.1
  done
  local url
  url=$(grep -o 'http://[^ ]*/' "$W/$name.out" | head -1) || true
  [ -n "$url" ] || { echo "FAIL: $name never served"; cat "$W/$name.out" "$W/$name.err"; exit 1; }
  printf -v "URL_$name" '%s' "$url"
}

serve one "$CLI" view "$W/noise.adg"
serve two "$MPIEXEC" -np 2 "$CLI" view "$W/noise.adg"
serve three "$MPIEXEC" -np 3 "$CLI" view "$W/noise.adg"
serve mlone "$CLI" view "$W/ml.adg"
serve mltwo "$MPIEXEC" -np 2 "$CLI" view "$W/ml.adg"
grep -q "made by rank 1" "$W/two.out" || { echo "FAIL: no word of the ranks"; cat "$W/two.out"; exit 1; }

/usr/bin/env python3 - "$URL_one" "$URL_two" "$URL_three" "$URL_mlone" "$URL_mltwo" <<'EOF'
import sys, threading, time, urllib.error, urllib.request
one, two, three, mlone, mltwo = sys.argv[1:]

def get(base, query):
    try:
        with urllib.request.urlopen(base + query, timeout=300) as r:
            return r.status, r.read(), dict(r.headers)
    except urllib.error.HTTPError as e:
        return e.code, e.read(), dict(e.headers)

import json
assert json.loads(get(mltwo, 'api/info')[1])['ranks'] == 2 and json.loads(get(mlone, 'api/info')[1])['ranks'] == 1
# One at a time: rank 1 makes each, the bytes one process's.
for a, b, q in [(mlone, mltwo, 'api/surface?iso=0.5&distance=1&format=plain'),
                (mlone, mltwo, 'api/surface?iso=0.3&distance=0.5&collapse=0&format=compact'),
                (mlone, mltwo, 'api/surface?iso=0.7&distance=2&collapse=3&format=plain'),
                (mlone, mltwo, 'api/surface?iso=0.5&distance=0&format=plain'),
                (mlone, mltwo, 'api/surface?iso=0.45&distance=2&min_piece=0&format=plain'),
                (mlone, mltwo, 'api/surface?iso=0.45&distance=2&min_piece=6&format=plain'),
                (one, two, 'api/surface?iso=100&distance=2&format=compact'),
                (one, two, 'api/export?iso=140&distance=2&format=ply')]:
    sa, ba, ha = get(a, q)
    sb, bb, hb = get(b, q)
    assert sa == sb == 200, (q, sa, sb, bb[:200])
    assert ba == bb, f'{q}: {len(ba)} bytes from one process, {len(bb)} over ranks'
    if 'surface' in q:
        assert hb['X-Rank'] == '1' and ha['X-Rank'] == '0', (q, ha.get('X-Rank'), hb.get('X-Rank'))
print('ok: one request at a time, the same bytes, made by rank 1')

sa, ba, _ = get(mlone, 'api/surface?iso=0.5&distance=-1')
sb, bb, _ = get(mltwo, 'api/surface?iso=0.5&distance=-1')
assert sa == sb == 400 and ba == bb, (sa, sb, ba, bb)
print('ok: a bad distance refused alike:', bb.decode().strip())

# Three clients at once on 3 ranks: each answer one process's, more than one rank at work (the
# march alone: 2 s a surface here, where eight rounds of collapses took 5 s).
isos = [90, 128, 166]
want = {i: get(one, f'api/surface?iso={i}&distance=0.5&collapse=0&format=compact')[1] for i in isos}
got = {}
def ask(i):
    got[i] = get(three, f'api/surface?iso={i}&distance=0.5&collapse=0&format=compact&client=c{i}')
threads = [threading.Thread(target=ask, args=(i,)) for i in isos]
for t in threads: t.start()
for t in threads: t.join()
for i in isos:
    s, body, h = got[i]
    assert s == 200 and body == want[i], (i, s, len(body), len(want[i]))
ranks = sorted(got[i][2]['X-Rank'] for i in isos)
assert len(set(ranks)) > 1, f'all three made by rank {ranks[0]}'
print('ok: three at once, the same bytes, made by ranks', ranks)

# A page's next request cancels its previous one where it runs.
first = {}
t = threading.Thread(target=lambda: first.update(r=get(two, 'api/surface?iso=128&distance=0.25&collapse=4&client=page')))
t.start()
time.sleep(0.3)
s2, b2, h2 = get(two, 'api/surface?iso=100&distance=4&client=page&format=plain')
t.join()
s1, b1, _ = first['r']
assert s1 == 409, f'the overtaken request answered {s1} (finished within 0.3 s?)'
assert s2 == 200 and b2 == get(one, 'api/surface?iso=100&distance=4&format=plain')[1], s2
print('ok: the overtaken request cancelled (409), the next one process\'s, from rank', h2['X-Rank'])
EOF

# An allocation that fails on rank 0 while it takes rank 1's answer: that surface 503, the next
# ones whole and the ones asked for (they once came one behind: 500s for ever after).
if [ -n "$SHIM" ]; then
  view_args=(view "$W/ml.adg" --port 0 --quiet --web "$WEB")
  "$MPIEXEC" -np 1 env LD_PRELOAD="$SHIM" ADAPTISO_TEST_FAIL_NEW_BYTES=100000 "$CLI" "${view_args[@]}" : -np 1 "$CLI" "${view_args[@]}" \
    >"$W/shim.out" 2>"$W/shim.err" &
  shim_mpi=$!
  PIDS+=($shim_mpi)
  for _ in $(seq 1 600); do
    grep -q "serving http" "$W/shim.out" 2>/dev/null && break
    sleep 0.1
  done
  url=$(grep -o 'http://[^ ]*/' "$W/shim.out" | head -1) || true
  [ -n "$url" ] || { echo "FAIL: the shimmed viewer never served"; cat "$W/shim.out" "$W/shim.err"; exit 1; }
  rank0=""
  for p in $(pgrep -P "$shim_mpi" -x adaptiso); do  # this job's ranks only
    grep -qz ADAPTISO_TEST_FAIL_NEW_BYTES "/proc/$p/environ" 2>/dev/null && rank0=$p
  done
  [ -n "$rank0" ] || { echo "FAIL: no shimmed rank 0"; exit 1; }
  kill -USR1 "$rank0"
  /usr/bin/env python3 - "$URL_mlone" "$url" <<'EOF'
import sys, urllib.error, urllib.request
one, shimmed = sys.argv[1:]
def get(base, query):
    try:
        with urllib.request.urlopen(base + query, timeout=60) as r:
            return r.status, r.read(), dict(r.headers)
    except urllib.error.HTTPError as e:
        return e.code, e.read(), dict(e.headers)
s, body, _ = get(shimmed, 'api/surface?iso=0.5&distance=0&format=plain')
assert s == 503, f'the failed allocation answered {s}: {body[:200]}'
for q in ['api/surface?iso=0.3&distance=1&format=plain', 'api/surface?iso=0.6&distance=0.5&format=plain',
          'api/surface?iso=0.5&distance=0&format=plain']:
    s, body, h = get(shimmed, q)
    assert s == 200, f'{q}: {s} {body[:200]} (one behind?)'
    assert body == get(one, q)[1] and h['X-Rank'] == '1', q
print('ok: a failed allocation on rank 0 cost one surface (503); the next three are the ones asked for')
EOF
  grep -q "fail_alloc_shim: failed an allocation" "$W/shim.err" || { echo "FAIL: the shim never fired"; cat "$W/shim.err"; exit 1; }
fi

# A volume is not served over ranks: one line, exit 2.
set +e
ranks 2 "$CLI" view "$W/ml.nrrd" --port 0 --quiet >"$W/vol.out" 2>&1
code=$?
set -e
[ $code -eq 2 ] || { echo "FAIL: view of a volume under mpirun exited $code"; cat "$W/vol.out"; exit 1; }
grep -q "serves a grid file (.adg)" "$W/vol.out" || { echo "FAIL: no clear refusal"; cat "$W/vol.out"; exit 1; }
echo "ok: a volume refused over ranks"

# A Delaunay grid (no hierarchy: nothing for the other ranks to make) is refused on every rank,
# exit 2, rather than leaving them idle (they once polled for ever).
"$CLI" prepare "$W/ml.nrrd" --grid delaunay --quiet -o "$W/mld.adg"
set +e
timeout 120 "$MPIEXEC" -np 2 "$CLI" view "$W/mld.adg" --port 0 --quiet --web "$WEB" >"$W/d.out" 2>&1
code=$?
set -e
[ $code -eq 2 ] || { echo "FAIL: view of a Delaunay grid under mpirun exited $code"; cat "$W/d.out"; exit 1; }
grep -q "serves a bisection grid" "$W/d.out" || { echo "FAIL: no clear refusal"; cat "$W/d.out"; exit 1; }
echo "ok: a Delaunay grid refused over ranks"

# A port rank 0 cannot bind: exit 2, the other ranks stopped, not left waiting.
port=$(echo "$URL_one" | sed 's|.*:\([0-9]*\)/$|\1|')
set +e
timeout 120 "$MPIEXEC" -np 2 "$CLI" view "$W/ml.adg" --port "$port" --quiet --web "$WEB" >"$W/p.out" 2>&1
code=$?
set -e
[ $code -eq 2 ] || { echo "FAIL: a busy port under mpirun exited $code (124: hung)"; cat "$W/p.out"; exit 1; }
echo "ok: a busy port refused over ranks: $(grep -m1 adaptiso "$W/p.out")"

# A killed rank ends the job.
kill_a_rank 2 "$CLI" view "$W/ml.adg" --port 0 --quiet --web "$WEB"
echo "ok: a killed rank ended the viewer (mpirun exit $killed_code)"
