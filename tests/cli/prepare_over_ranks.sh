#!/usr/bin/env bash
# `mpirun -np N adaptiso prepare` writes the file one process writes, byte for byte, for N = 2, 3, 4
# (oversubscribed) and bricks down to 2 voxels a side, so several bricks per rank, the selection's
# walks shared out too (select_shares.hpp); --brick-side in
# one process does too. Volumes of odd and anisotropic sizes, a noisy one and an analytic one, with
# and without the displacement criterion. A rank killed mid-run leaves no grid file; a command
# other than prepare and extract under mpirun is refused (issue 38).
# Usage: prepare_over_ranks.sh ADAPTISO MPIEXEC
set -euo pipefail
# shellcheck source=ranks_common.sh
source "$(dirname "$0")/ranks_common.sh" "$@"

"$CLI" generate marschner-lobb --size 33 --quiet -o "$W/ml.nrrd"
# 37×20×13 uint8 noise.
noise_raw 12345 $((37 * 20 * 13)) "$W/noise.raw"
RAW=(--dims 37,20,13 --type uint8 --spacing 1,0.7,2.5)

check() {  # NAME INPUT [prepare options...]
  local name=$1 input=$2
  shift 2
  "$CLI" prepare "$input" "$@" --quiet -o "$W/$name-one.adg"
  for side in 2 8; do
    "$CLI" prepare "$input" "$@" --brick-side $side --quiet -o "$W/$name-b$side.adg"
    cmp "$W/$name-one.adg" "$W/$name-b$side.adg" || { echo "FAIL: $name, bricks of $side in one process differ"; exit 1; }
  done
  for np in 2 3 4; do
    for side in 2 4 16; do
      ranks $np "$CLI" prepare "$input" "$@" --brick-side $side --threads 1 --quiet -o "$W/$name-np$np-b$side.adg"
      cmp "$W/$name-one.adg" "$W/$name-np$np-b$side.adg" || { echo "FAIL: $name, $np ranks, bricks of $side differ"; exit 1; }
    done
  done
  echo "ok: $name (one process = bricks of 2, 8 = 2, 3, 4 ranks with bricks of 2, 4, 16)"
}
check ml "$W/ml.nrrd"
check ml-displacement "$W/ml.nrrd" --max-displacement 0.5
check noise "$W/noise.raw" "${RAW[@]}"
check noise-displacement "$W/noise.raw" "${RAW[@]}" --max-displacement 1 --max-error 0.1 --relative
# The ranks other than 0 read their bricks straight from the file (volume_regions.hpp): a detached
# header, big-endian 16-bit samples after a byte skip, a MetaImage with a header size, a scaled
# NIfTI; from gzip and bzip2 files, which a rank could only read by decoding the stream up to its
# bricks, rank 0 sends them their regions slab by slab (distributed.hpp, scattered_route).
/usr/bin/env python3 -c "
import bz2, gzip, struct, sys
w = sys.argv[1]
noise = open(w + '/noise.raw', 'rb').read()
data = b''.join(struct.pack('>h', 40 * b - 3000) for b in noise)
open(w + '/n16.raw', 'wb').write(b'skipped!' + data)
head = 'NRRD0004\ntype: short\ndimension: 3\nsizes: 37 20 13\nspacings: 1 0.7 2.5\nendian: big\n'
open(w + '/n16.nhdr', 'w').write(head + 'encoding: raw\nbyte skip: 8\ndata file: n16.raw\n')
open(w + '/n16gz.raw.gz', 'wb').write(gzip.compress(data))
open(w + '/n16gz.nhdr', 'w').write(head + 'encoding: gzip\ndata file: n16gz.raw.gz\n')
open(w + '/n16bz.raw.bz2', 'wb').write(bz2.compress(data))
open(w + '/n16bz.nhdr', 'w').write(head + 'encoding: bzip2\ndata file: n16bz.raw.bz2\n')
# MetaImage: the same big-endian samples after a 5-byte header of their own.
open(w + '/m16.mha', 'wb').write(b'NDims = 3\nDimSize = 37 20 13\nElementType = MET_SHORT\nElementSpacing = 1 0.7 2.5\n'
  b'ElementByteOrderMSB = True\nHeaderSize = 5\nElementDataFile = LOCAL\n' + b'12345' + data)
# NIfTI-1 with scl_slope 0.25 and scl_inter 7 (the samples become float32), little-endian.
h = bytearray(352)
struct.pack_into('<i', h, 0, 348)
struct.pack_into('<8h', h, 40, 3, 37, 20, 13, 1, 1, 1, 1)
struct.pack_into('<hh', h, 70, 4, 16)  # DT_INT16, 16 bits
struct.pack_into('<8f', h, 76, 1, 1, 0.7, 2.5, 1, 1, 1, 1)
struct.pack_into('<fff', h, 108, 352, 0.25, 7)
h[344:348] = b'n+1\0'
open(w + '/s16.nii', 'wb').write(bytes(h) + b''.join(struct.pack('<h', 40 * b - 3000) for b in noise))" "$W"
check n16 "$W/n16.nhdr"
for input in n16gz.nhdr n16bz.nhdr m16.mha s16.nii; do "$CLI" prepare "$W/$input" --quiet -o "$W/${input%.*}-one.adg"; done
for input in n16.nhdr n16gz.nhdr n16bz.nhdr m16.mha s16.nii; do
  name=${input%.*}
  ranks 2 "$CLI" prepare "$W/$input" --brick-side 4 --threads 1 --json -o "$W/$name-np2.adg" >"$W/$name.json"
  cmp "$W/$name-one.adg" "$W/$name-np2.adg" || { echo "FAIL: $input over 2 ranks differs"; exit 1; }
done
/usr/bin/env python3 -c "
import json, sys
w = sys.argv[1]
read = {n: json.load(open(f'{w}/{n}.json'))['bricks']['ranks_read'] for n in ('n16', 'n16gz', 'n16bz', 'm16', 's16')}
sent = 'regions sent by rank 0'
assert read == {'n16': 'regions', 'n16gz': sent, 'n16bz': sent, 'm16': 'regions', 's16': 'regions'}, read
print('ok: rank 1 read its bricks from the raw NRRD, MetaImage and scaled NIfTI files; rank 0 sent them for the gzip and bzip2 ones')" "$W"
# A gzip stream over 3 and 4 ranks, bricks of 2 (many slabs sent in turn, each rank's bricks in every one).
for np in 3 4; do
  ranks $np "$CLI" prepare "$W/n16gz.nhdr" --brick-side 2 --threads 1 --quiet -o "$W/n16gz-np$np.adg"
  cmp "$W/n16gz-one.adg" "$W/n16gz-np$np.adg" || { echo "FAIL: the gzip file over $np ranks differs"; exit 1; }
done
echo "ok: the gzip file over 3 and 4 ranks, bricks of 2"

# A text NRRD, which only a whole read decodes ("whole volume"): rank 0 sends the regions. 5×5×40:
# one brick a slab at a side of 4, so some slabs hold no brick of rank 0 and it sends what it does
# not compute; over 3 ranks, bricks of 4 and 8.
/usr/bin/env python3 -c "
import sys
x = 4321
vals = []
for _ in range(5 * 5 * 40):
    x = (1103515245 * x + 12345) % 2**31
    vals.append(str((x >> 20) - 900))
open(sys.argv[1], 'w').write('NRRD0004\ntype: short\ndimension: 3\nsizes: 5 5 40\nencoding: text\n\n' + ' '.join(vals) + '\n')" "$W/thin.nrrd"
"$CLI" prepare "$W/thin.nrrd" --quiet -o "$W/thin-one.adg"
for np in 2 3; do
  for side in 4 8; do
    ranks $np "$CLI" prepare "$W/thin.nrrd" --brick-side $side --threads 1 --json -o "$W/thin-np$np-b$side.adg" >"$W/thin.json"
    cmp "$W/thin-one.adg" "$W/thin-np$np-b$side.adg" || { echo "FAIL: the text NRRD over $np ranks, bricks of $side, differs"; exit 1; }
  done
done
/usr/bin/env python3 -c "
import json, sys
b = json.load(open(sys.argv[1]))['bricks']
assert b['ranks_read'] == 'regions sent by rank 0' and b['regions_sent_bytes'] > 0, b" "$W/thin.json"
echo "ok: a text NRRD over 2 and 3 ranks, rank 0 sending the regions, slabs without a brick of its own"

# A DICOM series (11×7 uint16, 9 slices rescaled slice by slice, files named against their order):
# the other ranks read only the slice files of their slabs.
mkdir -p "$W/series"
/usr/bin/env python3 -c "
import struct, sys
def el(g, e, vr, v):
    v += b'\0' * (len(v) % 2)
    size = b'\0\0' + struct.pack('<I', len(v)) if vr in (b'OB', b'OW') else struct.pack('<H', len(v))
    return struct.pack('<HH', g, e) + vr + size + v
us = lambda x: struct.pack('<H', x)
meta = el(2, 1, b'OB', b'\0\1') + el(2, 2, b'UI', b'1.2.840.10008.5.1.4.1.1.4') + el(2, 3, b'UI', b'1.2.3.4') + el(2, 0x10, b'UI', b'1.2.840.10008.1.2.1')
x = 777
for z in range(9):
    px = b''
    for _ in range(77):
        x = (1103515245 * x + 12345) % 2**31
        px += us(x >> 20)
    ds = (el(0x20, 0xE, b'UI', b'1.2.3.5') + el(0x20, 0x32, b'DS', b'0\\\\0\\\\%g' % (1.25 * z)) + el(0x20, 0x37, b'DS', b'1\\\\0\\\\0\\\\0\\\\1\\\\0')
          + el(0x28, 2, b'US', us(1)) + el(0x28, 4, b'CS', b'MONOCHROME2') + el(0x28, 0x10, b'US', us(7)) + el(0x28, 0x11, b'US', us(11))
          + el(0x28, 0x30, b'DS', b'0.5\\\\0.75') + el(0x28, 0x100, b'US', us(16)) + el(0x28, 0x101, b'US', us(12)) + el(0x28, 0x102, b'US', us(11))
          + el(0x28, 0x103, b'US', us(0)) + el(0x28, 0x1052, b'DS', b'%d' % (z % 3 - 1)) + el(0x28, 0x1053, b'DS', b'2' if z % 2 else b'1')
          + el(0x7fe0, 0x10, b'OW', px))
    open(f'{sys.argv[1]}/f{8 - z}.dcm', 'wb').write(b'\0' * 128 + b'DICM' + el(2, 0, b'UL', struct.pack('<I', len(meta))) + meta + ds)" "$W/series"
"$CLI" prepare "$W/series" --quiet -o "$W/series-one.adg"
for np in 2 3; do
  ranks $np "$CLI" prepare "$W/series" --brick-side 2 --threads 1 --json -o "$W/series-np$np.adg" >"$W/series.json"
  cmp "$W/series-one.adg" "$W/series-np$np.adg" || { echo "FAIL: the DICOM series over $np ranks differs"; exit 1; }
done
/usr/bin/env python3 -c "
import json, sys
read = json.load(open(sys.argv[1]))['bricks']['ranks_read']
assert read == 'slabs of the slice files', read" "$W/series.json"
echo "ok: a DICOM series over 2 and 3 ranks, the other ranks reading the slice files of their slabs"

# --json tells what the ranks did.
ranks 2 "$CLI" prepare "$W/ml.nrrd" --brick-side 8 --json -o "$W/j.adg" >"$W/j.json"
/usr/bin/env python3 -c "
import json, sys
b = json.load(open(sys.argv[1]))['bricks']
assert b['ranks'] == 2 and b['bricks'] == 64 and sum(b['bricks_per_rank']) == 64 and min(b['bricks_per_rank']) > 0, b
assert b['bytes_exchanged'] > 0 and all(p > 0 for p in b['peak_bytes_per_rank']), b
# The selection's share: the codes (a byte a voxel of the 33³ volume) went to rank 1, its run came back.
assert b['select_bytes_exchanged'] > 33 ** 3, b
# Each rank's brick time, so a slow reader shows (rank 1 reads its bricks from the file).
assert len(b['seconds']['bricks_per_rank']) == 2 and all(t > 0 for t in b['seconds']['bricks_per_rank']), b
print('ok: --json', {k: b[k] for k in ('ranks', 'bricks', 'bricks_per_rank', 'bytes_exchanged', 'select_bytes_exchanged')})" "$W/j.json"

# Without --brick-side the ranks agree on the default side for the lattice and their number
# (brick_shares.hpp: the largest up to 256 leaving 4 bricks a rank; 33³: 16 for 2 ranks, 8 for 4),
# rank 1 choosing it from the file's header, rank 0 from the volume.
for np in 2 4; do
  ranks $np "$CLI" prepare "$W/ml.nrrd" --threads 1 --json -o "$W/default-np$np.adg" >"$W/default-np$np.json"
  cmp "$W/ml-one.adg" "$W/default-np$np.adg" || { echo "FAIL: $np ranks at the default brick side differ"; exit 1; }
done
/usr/bin/env python3 -c "
import json, sys
sides = [json.load(open(f'{sys.argv[1]}/default-np{n}.json'))['bricks']['brick_side'] for n in (2, 4)]
assert sides == [16, 8], sides
print('ok: the default brick side', sides, 'for 2 and 4 ranks')" "$W"

# Only prepare and extract are shared out; the others refuse with one line and exit 2.
set +e
ranks 2 "$CLI" info "$W/ml.nrrd" >"$W/info.out" 2>&1
code=$?
set -e
[ $code -eq 2 ] || { echo "FAIL: info under mpirun exited $code"; cat "$W/info.out"; exit 1; }
grep -q "only 'adaptiso prepare', 'adaptiso extract' and 'adaptiso view' run over MPI ranks" "$W/info.out" || { echo "FAIL: no clear refusal"; cat "$W/info.out"; exit 1; }
echo "ok: other commands refused under mpirun"

# An input error every rank meets is told once, by rank 0 (the first rank to abort ends the others:
# a message left to rank 0 was once lost when rank 1 aborted first), with exit 2.
head -c 100 /dev/zero >"$W/flat.raw"
set +e
ranks 2 "$CLI" prepare "$W/flat.raw" --dims 10,10,1 --type uint8 --quiet -o "$W/flat.adg" >"$W/flat.out" 2>&1
code=$?
set -e
[ $code -eq 2 ] || { echo "FAIL: a flat volume under mpirun exited $code"; cat "$W/flat.out"; exit 1; }
[ "$(grep -c 'is flat' "$W/flat.out")" -eq 1 ] || { echo "FAIL: the flat volume's message is not told once"; cat "$W/flat.out"; exit 1; }
echo "ok: an input error under mpirun is told once, exit 2"

# A memory limit below what each rank's bricks need is refused before the bricks are read, told
# once with the size needed; one they fit under gives the one-process file.
set +e
ranks 2 "$CLI" prepare "$W/ml.nrrd" --brick-side 8 --threads 1 --memory-limit 1M --quiet -o "$W/limited.adg" >"$W/limited.out" 2>&1
code=$?
set -e
[ $code -eq 2 ] || { echo "FAIL: --memory-limit 1M under mpirun exited $code"; cat "$W/limited.out"; exit 1; }
[ "$(grep -c "bricks of side 8 .*needs about .*the memory limit of 1 MB" "$W/limited.out")" -eq 1 ] ||
  { echo "FAIL: the memory refusal is not told once with its size"; cat "$W/limited.out"; exit 1; }
[ ! -e "$W/limited.adg" ] || { echo "FAIL: a refused run left a grid"; exit 1; }
ranks 2 "$CLI" prepare "$W/ml.nrrd" --brick-side 8 --threads 1 --memory-limit 4G --quiet -o "$W/limited.adg"
cmp "$W/ml-one.adg" "$W/limited.adg" || { echo "FAIL: a memory limit changed the grid"; exit 1; }
echo "ok: --memory-limit under mpirun"

# A rank killed mid-run: mpirun fails and no grid file appears under its name.
"$CLI" generate sphere --size 160 --quiet -o "$W/big.nrrd"
kill_a_rank 0.3 "$CLI" prepare "$W/big.nrrd" --brick-side 16 --threads 1 --quiet -o "$W/killed.adg"
[ ! -e "$W/killed.adg" ] || { echo "FAIL: a grid file was left after a rank was killed"; exit 1; }
echo "ok: a killed rank leaves no output (mpirun exit $killed_code)"
