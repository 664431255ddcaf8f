// adaptiso/grid_file.hpp — the preprocessed grid on disk (.adg), so preprocessing is paid once.
//
// Layout (little-endian):
//   0   char[16]  magic "ADAPTISO-GRID\0\0\0"
//   16  u32       version (6; versions 1 to 5 are still read. 4 to 6 have 3's layout; their
//                 index lists may hold equal keys in any order, where older ones sorted them by
//                 id; up to 4 the checksum restarted after every empty array; from 6 a file
//                 without its index gives the depth to build it at, up to 24)
//   20  u32       flags (bit 0: the extraction index follows the tetrahedra; bit 1: the bisection
//                 hierarchy follows [version 3]; bit 2: with the displacement criterion)
//   24  u64       M, bytes of metadata
//   32  u64       N, vertices
//   40  u64       T, tetrahedra
//   48  u64       E, index entries (non-constant tetrahedra)       [version 2]
//   56  u32       D, index depth (without the index: 0, or from version 6 the depth it is
//                 built at when loaded, reduced there as prepare's build reduces the depth
//                 asked for; since 2026-11-30 that depth itself); u32 reserved   [version 2]
//   64  char[M]   metadata: UTF-8 JSON: "source" (GridSource: dims, spacing, origin, direction,
//                 value range, reduction settings) and "prepare" (PrepareStats, prepared_grid.hpp,
//                 without its times and peaks; since 2026-11-30 without the index's depth and
//                 size, which loading takes from the index, and are not known when the header is
//                 written as prepare_to_file makes the grid)
//       u32[N][3] ijk;  f64[N] values;  f32[N][3] gradients;  u32[T][4] tets
//       index: (f64 split, u64 begin, u64 end)[2^(D+1) - 1];  u32[E] by_min;  u32[E] by_max
//       hierarchy: i32 root size; u8 error threshold; u8 displacement threshold; u16 0;
//                  f64 error scale, zero; f64 displacement scale, zero; u8[N] error codes;
//                  [u8[N] displacement codes]; f32[N][2] value spans     (bisection.hpp)
//       u32       CRC-32 (zlib) of every preceding byte
// Loading checks the magic, version, that the file size is exactly what the counts imply (so no
// allocation exceeds the file), the checksum and the reserved fields, then everything the
// extraction, the hierarchy's walks and the viewer rely on, in time linear in the file: the
// metadata's fields and geometry (check_geometry), vertices in ascending voxel order with finite
// values in the value range, tetrahedra tiling the box, and a bisection hierarchy that is the one
// its own codes select (its corner and centre vertices present, codes saturated, thresholds and
// scales from the metadata, the walk's leaves and value spans those of the file), and the index
// against the grid (validate_interval_tree; GridParts below says which are kept and checked). A
// file that fails any of them is refused with InputError naming it: checksums catch damage, these
// catch a file that was written to lie.
//
// The index is written only when asked (save_grid's with_index): built when the file is loaded, it
// costs less than checking a stored one (the CT bunny's default grid: its load 4.0-4.3 s against
// 4.9-5.3), the file is a quarter smaller, and prepare does not build it at all.
#pragma once
#include <cstdint>
#include <memory>
#include <string>

#include "adaptiso/interval_tree.hpp"
#include "adaptiso/prepared_grid.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

// Writes the grid and its statistics, atomically; its index only with with_index (loading builds it
// otherwise, at the depth asked for, stats.tree_depth, when that is what the grid's index was
// reduced from; at the index's own depth when it was built at another).
void save_grid(const PreparedGrid& grid, const std::string& path, bool with_index = false);
// What load_grid keeps of a file.
enum class GridParts {
  all,        // the grid, its index (built now when the file has none) and its statistics
  hierarchy,  // a bisection grid's vertices, hierarchy and statistics, without its tetrahedra or index
  // The grid, its hierarchy and statistics without the index (not built, a stored one checksummed
  // only): what writing the grid elsewhere reads (export to .vtu). Not for an Extractor.
  tetrahedra,
  // As hierarchy where the file has a bisection hierarchy, else as all (a Delaunay grid, an older
  // file): for a caller that reads the rest later when a route needs it (Python's adaptiso.load).
  hierarchy_or_all,
};
// The grid as `parts` says. With GridParts::hierarchy (what HierarchyQuery walks, at a distance or
// at another error) the tetrahedra and the index are read for the checksum but neither kept nor
// checked (nothing will read them): of the CT bunny's default grid (1.8 GB) that keeps about
// 0.45 GB in memory and skips the index's check, the longest (load 6.5-7.4 s -> 2.7 s). The
// returned grid has no tetrahedra (its statistics still count them) and an empty index: give it to
// HierarchyQuery, not to an Extractor. Throws InputError for a file without a bisection hierarchy
// (GridParts::hierarchy; hierarchy_or_all loads it whole instead).
// Progress: "read grid" (by bytes), "check grid" (the vertices and the hierarchy's walk), then
// "build index" (0 and 1), or "check index" (its entries) for a file that holds one.
PreparedGrid load_grid(const std::string& path, GridParts parts = GridParts::all, const Progress& progress = {});

class ShareTransport;  // select_shares.hpp
// load_grid on every process of a shared step at once (the command line's MPI ranks under mpirun
// extract), each loading the same file as one process would: each reads and checksums it, and the
// checks of a bisection hierarchy, most of a load, are shared out (process p of P checks the p-th
// P-th of the vertices and walks every P-th subtree of the hierarchy), their findings combined on
// every process. Every process returns the same grid or throws the same InputError, also when one
// read other bytes than process 0 or asked for other parts (sizes, headers, parts and checksums
// are compared before anything else is combined). Collective, with the same parts on every
// process. A process that cannot open its file, or not as a grid file (too short, its magic, its
// version), makes every process throw its message, naming it ("… (process 2)"). One whose memory
// or memory limit refuses the load fails alone and leaves the others waiting, for the caller to
// stop (the command line: MPI_Abort).
PreparedGrid load_grid_shared(const std::string& path, GridParts parts, ShareTransport& transport, const Progress& progress = {});

namespace detail {
struct HierarchyWalk;
}

// A grid file held open, so that what is loaded later is what was loaded first: the
// hierarchy's parts now (GridParts::hierarchy_or_all: what surfaces at a distance or at another
// error read), the whole grid when a route first needs its tetrahedra (Python's adaptiso.load,
// `adaptiso view GRID`). Renamed over or deleted meanwhile, the file is still the one opened
// (read again through /proc/self/fd: Linux). Messages name the path given. Throws InputError as
// load_grid does (no such file, a folder, a FIFO or device: opened without blocking, then refused).
class OpenGridFile {
public:
  // With `share` (several processes opening the same file at once, then loading it with the same
  // transport): collective; a process that cannot open its file makes every process throw its message.
  explicit OpenGridFile(std::string path, ShareTransport* share = nullptr);
  ~OpenGridFile();
  OpenGridFile(const OpenGridFile&) = delete;
  OpenGridFile& operator=(const OpenGridFile&) = delete;

  // load_grid of the open file. A whole load after a load in part skips the hierarchy's walk when
  // the file's bytes are the same (size and checksum): the tetrahedra are checked against what
  // the first walk saw. Not for two threads at once. With `share` (several processes, each with
  // the same file open): load_grid_shared instead, collective; each process then walked only its
  // share of the hierarchy, so none is remembered and a later whole load walks it all again.
  PreparedGrid load(GridParts parts, const Progress& progress = {}, ShareTransport* share = nullptr) const;
  const std::string& path() const { return path_; }

private:
  std::string path_;
  int fd_ = -1;
  mutable std::unique_ptr<detail::HierarchyWalk> walk_;  // of the last load in part
};

// Whether a grid was loaded without its tetrahedra (GridParts::hierarchy; its statistics count them).
inline bool loaded_in_part(const PreparedGrid& g) { return g.grid.tets.empty() && g.stats.tetrahedra > 0; }
// The grid's tetrahedra: those in memory, or those its file holds when loaded in part.
inline std::uint64_t tetrahedron_count(const PreparedGrid& g) { return loaded_in_part(g) ? g.stats.tetrahedra : g.grid.tet_count(); }

// VTK XML UnstructuredGrid (.vtu), appended raw binary: world-coordinate points, tetrahedra,
// point data "value" and "gradient" (world frame), and for a padded lattice "in_volume" (1 for the
// volume's voxels, 0 for the copies of its last slices past its far faces). Written atomically.
void write_vtu(const TetGrid& grid, const std::string& path);

}  // namespace adaptiso
