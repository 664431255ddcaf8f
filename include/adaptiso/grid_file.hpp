// adaptiso/grid_file.hpp — the preprocessed grid on disk (.adg), so preprocessing is paid once.
//
// Layout (little-endian):
//   0   char[16]  magic "ADAPTISO-GRID\0\0\0"
//   16  u32       version (4; versions 1 to 3 are still read. 4 has 3's layout; its index lists
//                 may hold equal keys in any order, where older ones sorted them by id)
//   20  u32       flags (bit 0: the extraction index follows the tetrahedra; bit 1: the bisection
//                 hierarchy follows [version 3]; bit 2: with the displacement criterion)
//   24  u64       M, bytes of metadata
//   32  u64       N, vertices
//   40  u64       T, tetrahedra
//   48  u64       E, index entries (non-constant tetrahedra)       [version 2]
//   56  u32       D, index depth; u32 reserved                      [version 2]
//   64  char[M]   metadata: UTF-8 JSON: "source" (GridSource: dims, spacing, origin, direction,
//                 value range, reduction settings) and "prepare" (PrepareStats, prepared_grid.hpp)
//       u32[N][3] ijk;  f64[N] values;  f32[N][3] gradients;  u32[T][4] tets
//       index: (f64 split, u64 begin, u64 end)[2^(D+1) - 1];  u32[E] by_min;  u32[E] by_max
//       hierarchy: i32 root size; u8 error threshold; u8 displacement threshold; u16 0;
//                  f64 error scale, zero; f64 displacement scale, zero; u8[N] error codes;
//                  [u8[N] displacement codes]; f32[N][2] value spans     (bisection.hpp)
//       u32       CRC-32 (zlib) of every preceding byte
// Loading checks the magic, version, that the file size is exactly what the counts imply (so no
// allocation exceeds the file), the checksum, tetrahedron indices and finite values, and refuses
// anything else with InputError naming the file; the index is checked against the grid
// (validate_interval_tree).
#pragma once
#include <string>

#include "adaptiso/interval_tree.hpp"
#include "adaptiso/prepared_grid.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

// Writes the grid, its index (unless with_index is false: loading then builds it) and its
// statistics, atomically.
void save_grid(const PreparedGrid& grid, const std::string& path, bool with_index = true);
// The grid, its index (built now when the file has none) and its statistics.
PreparedGrid load_grid(const std::string& path);

// VTK XML UnstructuredGrid (.vtu), appended raw binary: world-coordinate points, tetrahedra,
// point data "value" and "gradient" (world frame). Written atomically.
void write_vtu(const TetGrid& grid, const std::string& path);

}  // namespace adaptiso
