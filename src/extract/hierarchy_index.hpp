// What the queries of a bisection grid need beside the grid (hierarchy_query.cpp,
// distance_query.cpp): the lattice, the voxel → vertex numbering, and the values beneath the
// diamonds that cross the box's far faces. Internal.
#pragma once
#include <array>
#include <cstdint>
#include <vector>

#include "adaptiso/prepare.hpp"
#include "grid/traversal.hpp"

namespace adaptiso::detail {

// The grid keeps the span of the values beneath each split diamond from its tetrahedra inside the
// box; a diamond across the box's far faces is always split and its tetrahedra there have none.
// Without them a query walks the whole lining of the far faces (on the CT bunny most of the
// tetrahedra a query met). Kept per diamond centre (a lattice point, in or beyond the box), in an
// open-addressing table.
class LiningSpans {
public:
  void build(const Lattice& lat, const VertexNumbers& numbers, const TetGrid& grid, const BisectionHierarchy& h);
  // Could a tetrahedron across the box, of the diamond centred at m, hold a cut of iso beneath it?
  // (True for a diamond not in the table.)
  bool may_cut(const Lattice& lat, const Coord& m, double iso) const;
  std::size_t size() const { return count_; }

private:
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};
  struct Slot {
    std::uint64_t key = kEmpty;
    float lo = 0, hi = 0;
  };
  std::vector<Slot> slots_;
  std::size_t count_ = 0;
  int shift_ = 64;
  static std::uint64_t key(const Lattice& lat, const Coord& m) {
    const auto side = static_cast<std::uint64_t>(lat.S) + 1;
    return static_cast<std::uint64_t>(m[0]) + side * (static_cast<std::uint64_t>(m[1]) + side * static_cast<std::uint64_t>(m[2]));
  }
  std::size_t home(std::uint64_t k) const { return static_cast<std::size_t>((k * 0x9E3779B97F4A7C15ull) >> shift_); }
};

struct HierarchyIndex {
  Lattice lat;
  VertexNumbers numbers;
  LiningSpans lining;
};

}  // namespace adaptiso::detail
