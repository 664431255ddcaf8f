// The grid file written while the index is built (prepare_to_file.hpp): the grid's
// positions and gradients are on disk and freed before the index takes its memory, so the peak
// holds the grid file's parts one after another rather than all at once.
#pragma once
#include <cstdint>
#include <functional>
#include <string>

#include "adaptiso/interval_tree.hpp"
#include "adaptiso/prepared_grid.hpp"

namespace adaptiso::detail {

// Writes what save_grid(p with its index) writes, byte for byte, atomically: the header (with the
// index's shape, known before the index), the metadata and the vertices; frees p's positions and
// gradients; asks scratch_left(bytes the whole file will have) what the index may hold beyond its
// lists with everything now resident counted; writes the tetrahedra, while the index is built
// when that leaves the index at least 9 times the writer's buffers (kAtomicFileBufferBytes),
// before otherwise; calls build_index(grid, scratch); then frees the grid and writes the index and
// the hierarchy. p's grid is empty afterwards. Throws what build_index throws, and
// std::logic_error if the index does not have the shape promised.
void save_grid_building_index(PreparedGrid& p, const std::string& path, const IntervalTreeShape& shape,
                              const std::function<std::size_t(std::uint64_t file_bytes)>& scratch_left,
                              const std::function<IntervalTree(const TetGrid& grid, std::size_t scratch)>& build_index);

}  // namespace adaptiso::detail
