// A grid file written as its grid is made (prepare_to_file.cpp): the head and the vertices, the
// tetrahedra in pieces as they come, then the hierarchy and the checksum, the bytes save_grid
// writes for the same grid without its index (grid_file.hpp). Internal.
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <ostream>
#include <span>

#include "adaptiso/bisection.hpp"
#include "adaptiso/prepared_grid.hpp"

namespace adaptiso::detail {

class GridFileStream {
public:
  explicit GridFileStream(std::ostream& out);
  ~GridFileStream();
  // The header and metadata (stats.tetrahedra tetrahedra to come, an index to build at
  // stats.tree_depth) and the vertices: ijk, values and gradients.
  void head(const PrepareStats& stats, const TetGrid& vertices, const BisectionHierarchy& hierarchy);
  void tetrahedra(std::span<const std::array<std::uint32_t, 4>> tets);
  // After the last tetrahedra: the hierarchy (its spans complete) and the checksum.
  void finish(const BisectionHierarchy& hierarchy);

private:
  struct Writer;
  std::unique_ptr<Writer> writer_;
};

}  // namespace adaptiso::detail
