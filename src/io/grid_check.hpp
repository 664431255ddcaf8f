// What a grid read from a file must satisfy before anything uses it (grid_file.hpp). A grid file
// whose checksums match may still lie: every array the extraction, the hierarchy's walks
// (grid/traversal.hpp: they take a voxel's rank among the vertices for its vertex number) and the
// viewer trust is checked here, in time linear in the file. Internal.
#pragma once
#include <nlohmann/json.hpp>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "adaptiso/prepared_grid.hpp"
#include "adaptiso/progress.hpp"

namespace adaptiso {
class ShareTransport;
}

namespace adaptiso::detail {

// The metadata's "source" object: every field present with its type and count (dims: 3 whole
// numbers from 2 to 2^30 + 1; spacing, origin: 3 numbers; direction: 9), the geometry within
// check_geometry's limits, a value range min ≤ max of finite numbers, one of the element type
// names. Throws InputError naming `path`.
GridSource grid_source_from_json(const nlohmann::json& source, const std::string& path);

// What a check of a bisection grid's hierarchy walked (check_grid's `walked`): per subtree of the
// walk's frontier, its leaves (prefix counts) and a keyed hash of them in order (the key is drawn
// once per process). A later load of the same file in the same process checks its tetrahedra
// against it (check_tets_walked) instead of walking again.
struct HierarchyWalk {
  std::uint64_t file_bytes = 0;  // of the file walked, and its checksum, for the caller to match
  std::uint32_t checksum = 0;
  std::vector<std::uint64_t> leaves;
  std::vector<std::uint64_t> hashes;
};

// The grid against its own invariants (tet_grid.hpp, bisection.hpp), or InputError naming `path`:
// - vertices at distinct voxels inside the box, in ascending voxel order, with finite values
//   within [min, max] and gradients that are numbers;
// - at least one tetrahedron, every index a vertex, every vertex a corner of some tetrahedron;
// - without a hierarchy: every tetrahedron positively oriented, their volumes summing to the box's
//   (exact integer arithmetic in index space);
// - with one (bisection grids): code scales and thresholds those the metadata implies; the root
//   cube's corners inside the box are vertices; every other vertex is the centre of a diamond the
//   grid's thresholds split, whose parents inside the box are vertices with codes at least its own
//   (conformity, and the codes' saturation the coarser selections rely on), coded as always split
//   where it crosses the box, with a code at least its own midpoint's deviation from its refinement
//   edge; and the hierarchy's walk at the grid's thresholds gives exactly the file's tetrahedra in
//   their order, tiling the box, with the file's value spans.
// The index is checked apart (validate_interval_tree). With `leaves` (a bisection grid loaded
// without its tetrahedra, GridParts::hierarchy), the hierarchy's walk must have that many leaves,
// and nothing is checked of the tetrahedra themselves. With `walked`, a bisection grid's walk is
// kept there. With `share` (every process of a shared step checking the same file, collectively),
// the vertex-by-vertex check and the walk of a bisection hierarchy are shared out: each process
// checks a part and walks every P-th subtree, and the findings are combined on every process, so
// all pass or throw the same InputError (no `walked` then: no process walks all).
// Reports "check grid" progress.
void check_grid(const PreparedGrid& grid, const std::string& path, std::optional<std::uint64_t> leaves = std::nullopt,
                HierarchyWalk* walked = nullptr, const Progress& progress = {}, ShareTransport* share = nullptr);
// The tetrahedra of a grid whose vertices and hierarchy check_grid passed in an earlier load of the
// same bytes (`walked`): every index a vertex, and the walk's leaves in its order. The rest of
// check_grid's findings hold for the same bytes.
void check_tets_walked(const PreparedGrid& grid, const std::string& path, const HierarchyWalk& walked);

}  // namespace adaptiso::detail
