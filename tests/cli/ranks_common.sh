# Sourced by the tests run under mpirun (prepare_over_ranks.sh, extract_over_ranks.sh) with their
# arguments ADAPTISO MPIEXEC: sets CLI and MPIEXEC, a work folder W removed at exit, and OpenMPI as
# root, oversubscribed, over shared memory only (no network interface is needed on a CI runner).
CLI=$1
MPIEXEC=$2
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export OMPI_MCA_btl=self,vader OMPI_MCA_btl_vader_single_copy_mechanism=none
ranks() { "$MPIEXEC" -np "$1" "${@:2}"; }

# kill_a_rank AFTER_SECONDS COMMAND...: runs `mpirun -np 2 COMMAND` in the background, kills one
# rank with SIGKILL that long after it started, fails unless mpirun then exits non-zero; sets
# killed_code to mpirun's exit code.
kill_a_rank() {
  local after=$1
  shift
  "$MPIEXEC" -np 2 "$@" >/dev/null 2>&1 &
  local mpi=$! victim=""
  for _ in $(seq 1 200); do
    victim=$(pgrep -P "$mpi" -x adaptiso | tail -1 || true)
    [ -n "$victim" ] && break
    sleep 0.05
  done
  [ -n "$victim" ] || { echo "FAIL: no rank process found"; exit 1; }
  sleep "$after"
  kill -9 "$victim" 2>/dev/null || true
  set +e
  wait $mpi
  killed_code=$?
  set -e
  [ $killed_code -ne 0 ] || { echo "FAIL: mpirun exited 0 after a rank was killed (was the run over in $after s?)"; exit 1; }
}

# noise_raw SEED COUNT FILE: COUNT uint8 samples of a fixed generator (the same bytes on every
# machine).
noise_raw() {
  /usr/bin/env python3 -c "
import sys
x = int(sys.argv[1])
out = bytearray()
for _ in range(int(sys.argv[2])):
    x = (1103515245 * x + 12345) % 2**31
    out.append(x >> 23)
open(sys.argv[3], 'wb').write(out)" "$1" "$2" "$3"
}
